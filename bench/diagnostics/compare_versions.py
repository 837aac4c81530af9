"""Issue 30's acceptance table: the -style baselines before and after issue 30 (components that define them, one
equal training budget) on the same test data, from two bench work folders of ``scapo bench table1`` (e.g.
``bench_work/table1_two_categories`` at 66524f5 and ``bench_work/baselines_equal_budget``), every cell as the bench
scored it (``<category>_*/cells/<cell>.scapo.{json,parquet}``; the same evaluator, protocol and dataset hashes are
checked). Per method and category, means over training seeds (with their spread) of: mean and median S, median D,
median strict R and median symmetry-aware R (over all parts), flip rates (R > 90 deg) strict and symmetry-aware,
training minutes; then a paired bootstrap over test instances of before vs after
(:func:`scapo.eval.tables.pairwise_bootstrap`, seeds pooled).

Under the ``scapo`` protocol S and D need no symmetric variant: parts are matched to the ground truth per sample by
point IoU (so exchanging the labels of a symmetric object changes nothing) and D ignores the axis sign (the laptop's
declared half turn maps its hinge line onto itself); only the part rotations differ between a view's two ground
truths, hence R strict and R sym.

    python bench/diagnostics/compare_versions.py --before bench_work/table1_two_categories \
        --after bench_work/baselines_equal_budget --out results/baselines_equal_budget/versions
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from scapo.eval.evaluator import EvalResult  # noqa: E402
from scapo.eval.tables import pairwise_bootstrap  # noqa: E402
from scapo.files import atomic_write_text  # noqa: E402
from scapo.provenance import provenance  # noqa: E402

DISPLAY = {"npcs": "NPCS-style", "eap": "EAP-style", "eap+refine": "EAP-style + refine", "op-align": "OP-Align-style",
           "op-align+refine": "OP-Align-style + refine"}


def load_cells(work: Path, category: str, method: str, version: str) -> list[tuple[EvalResult, dict]]:
    """Every finished cell of ``method`` (any seed) for ``category`` in ``work``, as an EvalResult named
    ``method@version`` and its cell record."""
    out = []
    for d in sorted(work.glob(f"{category}_*")):
        for js in sorted((d / "cells").glob(f"{method}_cpu_s*.scapo.json")):
            rec = json.loads(js.read_text())
            if rec.get("label") != method:
                continue
            ps = pd.read_parquet(js.with_suffix("").with_suffix(".scapo.parquet"))
            out.append((EvalResult(f"{method}@{version}", category, "test", ps, rec["summary"]), rec))
    return out


def stats(res: EvalResult) -> dict:
    """The cell statistics of one training seed."""
    ps = res.per_sample

    def parts(prefix):
        cols = [c for c in ps.columns if c.startswith(prefix) and c[len(prefix):].isdigit()]
        return ps[cols].to_numpy(np.float64).ravel()

    R, Rs, D = parts("R_p"), parts("R_sym_p"), parts("D_j")
    return {"S mean": float(ps["S"].mean()), "S med": float(ps["S"].median()), "D med": float(np.nanmedian(D)),
            "R med": float(np.median(R)), "R sym med": float(np.median(Rs)), "R>90 %": 100 * float((R > 90).mean()),
            "R sym>90 %": 100 * float((Rs > 90).mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True)
    ap.add_argument("--after", type=Path, required=True)
    ap.add_argument("--methods", default="npcs,eap,eap+refine,op-align,op-align+refine")
    ap.add_argument("--categories", default="laptop,eyeglasses")
    ap.add_argument("--out", type=Path, required=True, help="output stem: writes STEM.md and STEM.json")
    a = ap.parse_args()
    rows, boots, cells, commits, hashes, evaluators = [], {}, [], {"before": set(), "after": set()}, {}, set()
    for m in a.methods.split(","):
        results = []
        for c in a.categories.split(","):
            for version, work in (("before", a.before), ("after", a.after)):
                got = load_cells(work, c, m, version)
                for res, rec in got:
                    results.append(res)
                    commits[version].add(rec["computed_commit"])
                    hashes.setdefault(c, set()).add(rec["dataset_hash"])
                    evaluators.add((rec["evaluator"], rec["protocol"]))
                    train_min = (rec.get("wall") or {}).get("train_s")
                    cells.append({"version": version, "category": c, "cell": rec["key"],
                                  "commit": rec["computed_commit"][:12],
                                  "train_min": round(train_min / 60, 1) if train_min else None})
                if not got:
                    continue
                st = pd.DataFrame([stats(r) for r, _ in got])
                train = [(rec.get("wall") or {}).get("train_s") for _, rec in got]
                row = {"method": DISPLAY.get(m, m), "version": version, "category": c, "seeds": len(got)}
                for k in st.columns:
                    row[k] = f"{st[k].mean():.1f} ± {st[k].std(ddof=0):.1f}" if len(got) > 1 else f"{st[k].mean():.1f}"
                tm = [t / 60 for t in train if t]
                row["train min"] = f"{np.mean(tm):.1f}" if tm else "-"
                rows.append(row)
        if any(r.method.endswith("@before") for r in results) and any(r.method.endswith("@after") for r in results):
            boots[m] = pairwise_bootstrap(results)
    for c, h in hashes.items():
        if len(h) != 1:
            raise SystemExit(f"{c}: the two folders scored different datasets ({sorted(h)}); compare the same data")
    if len({e for e, _ in evaluators}) > 1 or len({p for _, p in evaluators}) > 1:
        print(f"note: cells scored by evaluators/protocols {sorted(evaluators)}", file=sys.stderr)
    df = pd.DataFrame(rows)
    lines = ["# The -style baselines before and after issue 30, on the same test data", "",
             df.to_markdown(index=False) if len(df) else "(no cells)", "",
             "Means over training seeds ± their spread (population std); S per sample, medians over all parts (R) "
             "or joints (D) of all test samples; flips: share of part rotations off by more than 90 deg. "
             "S and D need no symmetric variant under the scapo protocol (see the script's docstring).", "",
             "## Before vs after (paired bootstrap over test instances, seeds pooled)", ""]
    for m, b in boots.items():
        for metric, pairs in b["metrics"].items():
            for p in pairs:
                if {p["a"].split("@")[0], p["b"].split("@")[0]} != {m}:
                    continue
                after_first = p["a"].endswith("@after")
                diff = p["diff"] if after_first else -p["diff"]
                lo, hi = p["interval"] if after_first else (-p["interval"][1], -p["interval"][0])
                verdict = ("after better" if p["better"] and p["better"].endswith("@after") else
                           "before better" if p["better"] else "no supported difference")
                lines.append(f"- {DISPLAY.get(m, m)}, {metric} ({', '.join(p['categories'])}): after - before = "
                             f"{diff:+.3g} [{lo:+.3g}, {hi:+.3g}]: {verdict}")
    prov = provenance(before=str(a.before), after=str(a.after), before_commits=sorted(commits["before"]),
                      after_commits=sorted(commits["after"]),
                      dataset_hashes={c: sorted(h)[0][:16] for c, h in hashes.items()},
                      evaluators=sorted(map(list, evaluators)))
    lines += ["", "Provenance: " + ", ".join(f"{k}={v}" for k, v in prov.items()), "",
              "## Cells", "", pd.DataFrame(cells).to_markdown(index=False) if cells else "(none)", ""]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out.with_suffix(".md"), "\n".join(lines))
    atomic_write_text(a.out.with_suffix(".json"), json.dumps(
        {"rows": rows, "bootstrap": {m: b for m, b in boots.items()}, "cells": cells, "provenance": prov},
        indent=1, default=lambda x: None if isinstance(x, float) and math.isnan(x) else str(x)) + "\n")
    print(f"wrote {a.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
