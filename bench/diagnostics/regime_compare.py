"""The same methods on data of several viewpoint settings, side by side with the paper's rows, from the table JSONs that
``scapo bench table1`` wrote (nothing is recomputed):

    python bench/diagnostics/regime_compare.py --table paper=results/paper_regime/table1_paper_regime.json \\
        --table sphere=results/table1_synthetic.json --methods npcs,icp --categories laptop,eyeglasses \\
        --paper npcs=NPCS-EPN --paper icp=ICP --out results/paper_regime/regimes

Per category and method, per table: S (%), the strict R and the symmetry-aware R sym (deg; mean, median and the share
over 90 deg), D (deg) and C (bbox diagonals), each the mean over training seeds with the standard deviation where a
trained method has several, the seeds and the table's commits; then the paper's row for the method (its Table 1:
S, D, C, R, the rows it has) and, where ``--within`` is given, whether the first table's mean R sym of a method is
within that factor of the paper's R (the issue's sanity check: a supervised network within 2x of its paper row).

Errors: a missing or unreadable JSON, one without bench results, or a method or category the tables do not hold end
with a ``scapo:`` message and exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
from pathlib import Path

FIELDS = ("S", "R", "R_median", "R_over90", "R_sym", "R_sym_median", "R_sym_over90", "D", "C")
REFERENCE = Path(__file__).resolve().parents[2] / "scapo" / "eval" / "reference" / "paper_table1.csv"


class CompareError(Exception):
    """A table that cannot be compared; the message names the file and what is missing."""


def _load(path: Path) -> dict:
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise CompareError(f"{path}: cannot read a table JSON ({e})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("results"), list):
        raise CompareError(f"{path}: not a bench table (no 'results' list)")
    prov = doc.setdefault("provenance", {})
    if "commits" not in prov and prov.get("commit"):  # a table of scapo evaluate: one commit, one dataset
        prov["commits"] = [str(prov["commit"])]
        cats = {r.get("category") for r in doc["results"]}
        if prov.get("dataset_hash") and len(cats) == 1:
            prov["datasets"] = {cats.pop(): str(prov["dataset_hash"])}
    return doc


def cells(doc: dict, method: str, category: str) -> list[dict]:
    """The summaries of ``method`` (its label) on ``category``, one per training seed."""
    return [r for r in doc["results"] if r.get("method") == method and r.get("category") == category]


def _stat(values: list[float]) -> tuple[float, float]:
    vals = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    if not vals:
        return math.nan, math.nan
    return statistics.fmean(vals), (statistics.stdev(vals) if len(vals) > 1 else math.nan)


def paper_rows() -> dict[tuple[str, str], dict[str, float]]:
    """(paper method, category) -> {metric: value} from the paper's Table 1 (scapo/eval/reference)."""
    out: dict[tuple[str, str], dict[str, float]] = {}
    with open(REFERENCE) as f:
        for row in csv.DictReader(f):
            for cat in ("laptop", "safe", "eyeglasses", "oven", "washer"):
                out.setdefault((row["method"], cat), {})[row["metric"]] = float(row[cat])
    return out


def compare(tables: dict[str, dict], methods, categories, paper: dict[str, str], within: float | None) -> dict:
    ref = paper_rows()
    rows = []
    for cat in categories:
        for m in methods:
            for label, doc in tables.items():
                got = cells(doc, m, cat)
                if not got:
                    raise CompareError(f"table {label!r} holds no cell of method {m!r} on {cat!r}")
                row = {"category": cat, "method": m, "data": label, "seeds": sorted(
                    int(c["seed"]) for c in got if c.get("seed") is not None), "cells": len(got)}
                for k in FIELDS:
                    row[k], row[f"{k}_std"] = _stat([c["summary"].get(k) for c in got])
                rows.append(row)
            if m in paper:
                p = ref.get((paper[m], cat), {})
                rows.append({"category": cat, "method": m, "data": f"paper ({paper[m]})",
                             **{k: p.get(k, math.nan) for k in ("S", "R", "D", "C")}})
    checks = []
    if within:
        first = next(iter(tables))
        for cat in categories:
            for m in methods:
                if m not in paper:
                    continue
                ours = next(r for r in rows if r["category"] == cat and r["method"] == m and r["data"] == first)
                target = ref.get((paper[m], cat), {}).get("R", math.nan)
                checks.append({"category": cat, "method": m, "data": first, "R_sym": ours["R_sym"],
                               "paper_R": target, "factor": ours["R_sym"] / target if target else math.nan,
                               "within": bool(ours["R_sym"] <= within * target)})
    return {"rows": rows, "checks": checks, "within": within}


def _fmt(v, std=None, d=1) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    s = f"{v:.{d}f}"
    return s + (f" ± {std:.{d}f}" if std is not None and not math.isnan(std) else "")


def markdown(res: dict, tables: dict[str, dict], sources: dict[str, str]) -> str:
    head = ["category", "method", "data", "seeds", "S %", "R", "R median", "R >90 %", "R sym", "R sym median",
            "R sym >90 %", "D", "C"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in res["rows"]:
        c = 3 if r.get("C") is not None and not (isinstance(r.get("C"), float) and math.isnan(r["C"])) else 1
        lines.append("| " + " | ".join([
            r["category"], r["method"], r["data"], ",".join(map(str, r.get("seeds", []))) or "-",
            _fmt(r.get("S"), r.get("S_std")), _fmt(r.get("R"), r.get("R_std")), _fmt(r.get("R_median")),
            _fmt(r.get("R_over90")), _fmt(r.get("R_sym"), r.get("R_sym_std")), _fmt(r.get("R_sym_median")),
            _fmt(r.get("R_sym_over90")), _fmt(r.get("D"), r.get("D_std")), _fmt(r.get("C"), r.get("C_std"), c)])
            + " |")
    out = ["| table | file | commits | viewpoints | datasets |", "|---|---|---|---|---|"]
    for label, doc in tables.items():
        prov = doc.get("provenance", {})
        data = prov.get("data", {})
        vp = data.get("viewpoints") or ("sphere" if data.get("random_rotation") else "upright")
        out.append(f"| {label} | `{sources[label]}` | {', '.join(c[:7] for c in prov.get('commits', []))} | {vp} | "
                   + ", ".join(f"{k} {v[:12]}" for k, v in prov.get("datasets", {}).items()) + " |")
    md = ["Tables compared:", "", *out, "", *lines, ""]
    if res["checks"]:
        md += [f"Sanity check: mean R sym of the first table within {res['within']:g}x of the paper's R:", ""]
        md += [f"- {c['method']} {c['category']}: R sym {c['R_sym']:.1f} deg against the paper's {c['paper_R']:.2f} "
               f"({c['factor']:.1f}x): {'within' if c['within'] else 'NOT within'}" for c in res["checks"]]
        md.append("")
    return "\n".join(md)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--table", action="append", required=True, metavar="LABEL=PATH[,PATH...]",
                   help="a table JSON (several, comma-separated, are one table: e.g. one per category)")
    p.add_argument("--methods", required=True)
    p.add_argument("--categories", required=True)
    p.add_argument("--paper", action="append", default=[], metavar="METHOD=PAPER_ROW")
    p.add_argument("--within", type=float, default=None)
    p.add_argument("--out", type=Path, default=None, help="stem of the .md and .json written")
    args = p.parse_args(argv)
    try:
        sources, tables = {}, {}
        for t in args.table:
            label, eq, path = t.partition("=")
            if not eq or not label or not path:
                raise CompareError(f"--table {t!r} is not LABEL=PATH")
            docs = [_load(Path(x)) for x in path.split(",")]  # several JSONs of one setting (e.g. per category)
            merged = {**docs[0], "results": [r for d in docs for r in d["results"]]}
            provs = [d.get("provenance", {}) for d in docs]
            merged["provenance"] = {**provs[0], "commits": sorted({c for pr in provs for c in pr.get("commits", [])}),
                                    "datasets": {k: v for pr in provs for k, v in pr.get("datasets", {}).items()}}
            sources[label], tables[label] = path, merged
        paper = dict(x.split("=", 1) for x in args.paper if "=" in x)
        res = compare(tables, args.methods.split(","), args.categories.split(","), paper, args.within)
    except CompareError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    md = markdown(res, tables, sources)
    print(md)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".md").write_text(md)
        args.out.with_suffix(".json").write_text(json.dumps({**res, "tables": sources}, indent=1, default=str))
        print(f"wrote {args.out.with_suffix('.md')}, {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
