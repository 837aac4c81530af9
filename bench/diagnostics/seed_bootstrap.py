"""Which differences between rows of predictions the training seeds and the split's instances support: several
predictions files per row (one per training seed, e.g. a fair-race cell's three seeds), each scored on one split of
one dataset (val by default: the fair race, ``results/fair_race/``, never reads test), then the hierarchical bootstrap
of the tables (:func:`scapo.eval.tables.pairwise_bootstrap`: each row's training seeds resampled, then the split's
instances, shared by the pair) for every pair of rows.

The table gives, per row, the number of seeds and the mean over them with their standard deviation of S, median D,
median R sym and the frame consistency (strict and symmetry-aware), then the supported differences.

    python bench/diagnostics/seed_bootstrap.py --data <work>/ladder/data/laptop_paper_i150_v8_t64_s1 \\
        --pred "op-align=<cells>/op-align_s0_predictions.npz" --pred "op-align=<cells>/op-align_s1_predictions.npz" \\
        --pred "scapo=<cells>/scapo_s0_predictions.npz" ... [--split val] [--draws 1000] --out NAME

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

#: The row table's columns: an :class:`~scapo.eval.EvalResult` summary key and its heading.
COLUMNS = (("S", "S %"), ("D_median", "median D deg"), ("R_sym_median", "median R sym deg"),
           ("frame_consistency", "frame consistency"), ("frame_consistency_sym", "frame consistency sym"))


def score(data, preds, split: str):
    """``(label, predictions file)`` pairs scored on ``split`` of ``data``: a list of EvalResults whose ``method``
    is the label and ``info["seed"]`` the predictions' training seed (their order within a label when not recorded).

    Raises:
        ScapoError: a file that cannot be scored (another dataset, missing samples, damaged)."""
    from scapo.eval import Predictions, evaluate

    out, count = [], {}
    for label, _, fn in preds:
        p = Predictions.load(fn)
        r = evaluate(data, p, split=split)
        seed = p.info.get("seed")
        count[label] = count.get(label, 0) + 1
        out.append(dataclasses.replace(r, method=label, info={**r.info, "seed": count[label] - 1 if seed is None
                                                                 else seed}))
    return out


def rows(results) -> dict:
    """Per label: ``{"seeds": [...], metric: {"mean", "std", "values"}}`` over its results (``std`` with ``ddof=1``,
    NaN for one seed)."""
    import numpy as np

    out = {}
    for label in dict.fromkeys(r.method for r in results):
        mine = [r for r in results if r.method == label]
        row = {"seeds": [r.info.get("seed") for r in mine]}
        for key, _ in COLUMNS:
            v = np.array([float(r.summary.get(key, math.nan)) for r in mine])
            row[key] = {"mean": float(np.nanmean(v)) if np.isfinite(v).any() else math.nan,
                        "std": float(np.nanstd(v, ddof=1)) if np.isfinite(v).sum() > 1 else math.nan,
                        "values": [float(x) for x in v]}
        out[label] = row
    return out


def render(table: dict, boot: dict, split: str, dataset: str) -> list[str]:
    from scapo.eval.tables import pairwise_markdown

    def cell(m: dict) -> str:
        if not math.isfinite(m["mean"]):
            return "-"
        return f"{m['mean']:.2f}" + ("" if not math.isfinite(m["std"]) else f" ± {m['std']:.2f}")

    lines = [f"# Rows of predictions with their seeds' spread ({dataset}, {split})", "",
             "Per row the mean over its training seeds ± their standard deviation; then the differences the seeds "
             f"and the {split} split's instances support (the hierarchical bootstrap of the tables).", "",
             "| row | seeds | " + " | ".join(h for _, h in COLUMNS) + " |", "|---|---" + "|---" * len(COLUMNS) + "|"]
    for label, row in table.items():
        lines.append(f"| {label} | {', '.join(map(str, row['seeds']))} | "
                     + " | ".join(cell(row[k]) for k, _ in COLUMNS) + " |")
    lines += ["", *[ln.replace("test instances", f"{split} instances") for ln in pairwise_markdown(boot)]]
    return lines


def main(argv=None) -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from scapo.bench.diagnosis import diagnosis_args, write_diagnosis
    from scapo.errors import ScapoError
    from scapo.eval.tables import pairwise_bootstrap

    parsed = diagnosis_args(argv, __doc__.split("\n\n")[0], [("--draws", {"type": int, "default": 1000})])
    if parsed is None:
        return 2
    a, preds = parsed
    if a.draws < 100:
        print(f"scapo: --draws must be at least 100 (a 95 % interval from fewer is noise), got {a.draws}",
              file=sys.stderr)
        return 2
    try:
        results = score(a.data, preds, a.split)
        table = rows(results)
        boot = pairwise_bootstrap(results, draws=a.draws)
        command = "python bench/diagnostics/seed_bootstrap.py " + " ".join(sys.argv[1:] if argv is None else argv)
        lines = [*render(table, boot, a.split, Path(a.data).name), f"Written by `{command}`."]
        files = {}
        for i, (label, _, fn) in enumerate(preds):
            files[f"{label} [{i}]"] = fn
        write_diagnosis(a.out, lines, {"command": command, "dataset": str(a.data),
                                       "dataset_hash": results[0].info.get("dataset_hash"), "split": a.split,
                                       "rows": table, "bootstrap": boot}, files)
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
