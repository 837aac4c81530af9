"""Several prediction files of one dataset's test split side by side, with a paired bootstrap over test instances
for every pair (e.g. one Table 1 cell against the same preset trained longer, or against a prediction step's row).

Each ``--pred LABEL=FILE`` is scored by :func:`scapo.eval.evaluate` under one protocol (default ``scapo``) and named
LABEL; the table gives the means (S, D, C, R strict, R sym), the medians (D, R strict, R sym) and the flip rates
(share of part rotations over 90 deg, strict and symmetry-aware) of each, then
:func:`scapo.eval.tables.pairwise_bootstrap`'s line for every pair and metric (1000 resamples of the test
instances, 95 % percentile intervals). Each file is listed with what its predictions record (method, preset, seed,
run, refinement steps), its run's training time and steps where the run folder is found (``timing.json``; its path
as recorded, relative to ``--root``), and the commit of the code that made it where ``--commit LABEL=SHA`` says
(predictions files do not record it; the scripts that call this one do).

    python bench/diagnostics/compare_predictions.py --data bench_work/table1_cpu/laptop_i150_v8_s1 \
        --pred "cpu=.../predictions_scapo_cpu_s0.npz" --pred "cpu x4=.../predictions.npz" \
        --out results/diagnostics/budget/laptop_x4_s0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from scapo.errors import ScapoError  # noqa: E402
from scapo.eval import evaluate  # noqa: E402
from scapo.eval.tables import pairwise_bootstrap  # noqa: E402
from scapo.files import atomic_write_text  # noqa: E402
from scapo.provenance import provenance  # noqa: E402

#: summary key -> column of the table
COLUMNS = {"S": "S", "D": "D", "C": "C", "R": "R", "R_sym": "R sym", "D_median": "D med", "R_median": "R med",
           "R_sym_median": "R sym med", "R_over90": "R>90 %", "R_sym_over90": "R sym>90 %"}


def parse_pred(text: str) -> tuple[str, Path]:
    """``LABEL=FILE`` -> (label, path); raises ScapoError for a malformed argument or a missing file."""
    label, sep, path = text.partition("=")
    if not sep or not label.strip() or not path:
        raise ScapoError(f"--pred {text!r}: give LABEL=FILE (e.g. 'cpu x4=run/predictions.npz')")
    if not Path(path).is_file():
        raise ScapoError(f"--pred {text!r}: {path} does not exist; predict first (scapo predict)")
    return label.strip(), Path(path)


def _mean_or_nan(values) -> float:
    """Mean of a list of numbers (the per-part alignment inlier ratios), NaN when there is none."""
    return float(np.mean(values)) if values else math.nan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the dataset whose test split every file predicts")
    ap.add_argument("--pred", action="append", required=True, help="LABEL=FILE (repeat; at least two)")
    ap.add_argument("--commit", action="append", default=[], help="LABEL=SHA: the commit that made LABEL's file")
    ap.add_argument("--root", type=Path, default=Path("."), help="where the predictions' relative run paths start")
    ap.add_argument("--protocol", default="scapo")
    ap.add_argument("--out", type=Path, required=True, help="output stem: writes STEM.md and STEM.json")
    a = ap.parse_args(argv)
    try:
        preds = [parse_pred(p) for p in a.pred]
        if len(preds) < 2 or len({lb for lb, _ in preds}) != len(preds):
            raise ScapoError("give at least two --pred with distinct labels")
        try:  # the output folder before the scoring, not after it
            a.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ScapoError(f"--out {a.out}: its folder cannot be made ({e.strerror}); choose a writable place") from e
        commits = dict(c.partition("=")[::2] for c in a.commit)
        stray = sorted(set(commits) - {lb for lb, _ in preds})
        if stray:
            raise ScapoError(f"--commit names labels without a --pred: {stray}")
        results, files = [], []
        for label, path in preds:
            res = evaluate(a.data, path, protocol=a.protocol)
            results.append(dataclasses.replace(res, method=label))
            info = res.info
            timing = a.root / str(info.get("run", "")) / "timing.json" if info.get("run") else None
            t = json.loads(timing.read_text()) if timing is not None and timing.is_file() else {}
            refine = (info.get("refine") or {}).get("steps", info.get("refine_steps"))
            files.append({"label": label, "file": str(path), "preset": info.get("preset"), "seed": info.get("seed"),
                          "run": info.get("run"), "refine_steps": refine,
                          "train_min": round(t["seconds"] / 60, 1) if "seconds" in t else None,
                          "train_steps": t.get("steps"), "commit": commits.get(label, "-")})
    except ScapoError as e:
        print(f"scapo: compare_predictions: {e}", file=sys.stderr)
        return 2
    rows = [{"label": r.method, "samples": int(r.summary.get("samples", len(r.per_sample))),
             **{col: r.summary.get(k, math.nan) for k, col in COLUMNS.items()},
             "align inliers": _mean_or_nan(r.info.get("alignment_inlier_ratio"))} for r in results]
    boot = pairwise_bootstrap(results)
    lines = [f"# {', '.join(r.method for r in results)} on {a.data.name} (test split, {a.protocol} protocol)", "",
             pd.DataFrame(rows).to_markdown(index=False, floatfmt=".3g"), "",
             "Means over the test samples (S in %, D and R in degrees, C in bounding-box diagonals), medians over "
             "all joints (D) or parts (R) of all test samples, flips: share of part rotations off by more than "
             "90 deg; align inliers: for a method in its own canonical frame, the share of training samples whose "
             "offset from predicted to true part rotation lies within the alignment's inlier angle of the one "
             "offset the evaluator applies (scapo.eval.alignment; mean over parts; 1 for a canonical frame that "
             "is the same in every instance and view).", "",
             f"## Paired bootstrap over test instances ({boot['draws']} resamples, "
             f"{100 * boot['level']:.0f} % intervals of a - b)", ""]
    for metric, pairs in boot["metrics"].items():
        for p in pairs:
            verdict = f"{p['better']} better" if p["better"] else "no supported difference"
            lo, hi = p["interval"]
            lines.append(f"- {metric}: {p['a']} - {p['b']} = {p['diff']:+.3g} [{lo:+.3g}, {hi:+.3g}] "
                         f"({100 * p['p_a_better']:.0f} % of resamples favour {p['a']}): {verdict}")
    prov = provenance(dataset=str(a.data), dataset_hash=results[0].info.get("dataset_hash"), protocol=a.protocol)
    lines += ["", "## Files", "", pd.DataFrame(files).to_markdown(index=False), "",
              "Provenance (this comparison): " + ", ".join(f"{k}={v}" for k, v in prov.items()), ""]
    atomic_write_text(a.out.with_suffix(".md"), "\n".join(lines))
    atomic_write_text(a.out.with_suffix(".json"), json.dumps(
        {"rows": rows, "bootstrap": boot, "files": files, "provenance": prov}, indent=1, default=str) + "\n")
    print(f"wrote {a.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
