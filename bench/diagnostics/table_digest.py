"""The numbers a status paragraph quotes, read from the table JSONs that ``scapo bench table1|table2|table3`` wrote,
so that the prose in ``README.md`` and ``results/README.md`` comes from the tables only (issue 31, point 3):

    python bench/diagnostics/table_digest.py results/table1_synthetic_sphere.json results/table3_ablation_sphere.json \\
        results/table2_real_style.json --pair scapo-sj,op-align-sj --mean seg_50,ap_joint_10,ap_part_10

Per table: its provenance (cells, commits, devices, recorded compute hours, training seeds per category); the
self-supervised orderings the table computed (one-pass and "+ refine" rows: each metric's best row, the others'
values, and the paired-bootstrap interval of best minus each other, with whether it excludes 0 and whether the
training seeds separate); the interval of every metric of each ``--pair A,B`` (A minus B, from the table's
``pairwise_bootstrap``); and with ``--mean``, the mean over the table's categories of each method's mean over training
seeds of those summary fields (the "Mean" rows of the Markdown). Last, the compute of all the given tables together
with the cells that several tables share (the same dataset hash and cell key, as Table 3's "Full" rows are Table 1's
SCAPO cells) counted once: training, prediction and evaluation seconds as each cell's record measured them, each
training once (a "+ refine" cell's record repeats the training time of the run it predicts from).

Values are printed as the tables hold them: S and the Seg/Joint/Part rates in %, D and R in degrees, C in the
protocol's unit. Nothing is recomputed: the intervals are the table's own (1000 paired resamples over test
instances, training seeds pooled; :func:`scapo.eval.tables.pairwise_bootstrap`).

Errors: a missing or unreadable JSON, a JSON without the fields of a bench table, or a ``--pair`` / ``--mean`` name
that the table does not hold end with a ``scapo:`` message and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path

ORDER_LABELS = {"S": "mean S", "D": "mean D", "C": "mean C", "R": "mean R", "R_sym": "mean R sym",
                "R_median": "median R", "R_sym_median": "median R sym"}


class DigestError(Exception):
    """A table that cannot be digested; the message says which file and what is missing."""


def load_table(path: Path) -> dict:
    """One bench table's JSON (``provenance``, ``results``, ``pairwise_bootstrap``); DigestError otherwise."""
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise DigestError(f"cannot read {path} ({e}); give a table JSON written by scapo bench") from e
    if not isinstance(d, dict):
        raise DigestError(f"{path} holds a {type(d).__name__}, not a table written by scapo bench table1|2|3")
    missing = [k for k in ("provenance", "results", "pairwise_bootstrap") if k not in d]
    if missing:
        raise DigestError(f"{path} has no {', '.join(missing)}: not a table written by scapo bench table1|2|3")
    if (not isinstance(d["provenance"], dict) or not isinstance(d["results"], list)
            or not isinstance(d["pairwise_bootstrap"], dict)
            or not all(isinstance(r, dict) and isinstance(r.get("summary"), dict) and "method" in r
                       and "category" in r for r in d["results"])):
        raise DigestError(f"{path}: its provenance, results or pairwise_bootstrap are not shaped as scapo bench writes "
                          "them; give a table JSON written by scapo bench")
    if not d["results"]:
        raise DigestError(f"{path} holds no cell (an empty table): nothing to digest")
    return d


def pair_interval(table: dict, metric: str, a: str, b: str) -> tuple[float, float, float, bool] | None:
    """(A minus B, interval low, high, supported) of one metric from the table's paired bootstrap, or None when the
    table has no such pair."""
    for q in table["pairwise_bootstrap"]["metrics"].get(metric, []):
        if {q["a"], q["b"]} == {a, b}:
            s = 1.0 if q["a"] == a else -1.0
            lo, hi = sorted((s * q["interval"][0], s * q["interval"][1]))
            return s * q["diff"], lo, hi, bool(q["supported"])
    return None


def category_means(table: dict, field: str) -> dict[str, float]:
    """Per method: the mean over the table's categories of its mean over training seeds of ``summary[field]``
    (the Markdown's "Mean" row). Methods lacking a category are left out; DigestError when no cell has ``field``."""
    per = defaultdict(lambda: defaultdict(list))
    for r in table["results"]:
        v = r.get("summary", {}).get(field)
        if v is not None:
            per[r["method"]][r["category"]].append(float(v))
    if not per:
        raise DigestError(f"no cell of this table has the summary field {field!r}")
    cats = set.union(*(set(c) for c in per.values()))
    return {m: statistics.fmean(statistics.fmean(v) for v in c.values()) for m, c in per.items() if set(c) == cats}


def unique_compute(tables: list[dict]) -> tuple[int, float]:
    """(cells, hours) of the given tables together: a cell shared by several (same dataset hash and cell key)
    counted once, and each training once (a "+ refine" cell predicts from its one-pass cell's run:
    :func:`scapo.bench.experiments.compute_seconds`)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from anywhere in the checkout
    from scapo.bench.experiments import compute_seconds

    seen: set = set()
    try:
        seconds = sum(compute_seconds(t["provenance"].get("cells", []), t["provenance"].get("datasets", {}), seen)
                      for t in tables)
    except (KeyError, TypeError, ValueError) as e:
        raise DigestError(f"a cell of the tables' provenance lacks its category, key or times ({e!r}): "
                          "give table JSONs written by scapo bench") from e
    return sum(1 for k in seen if k[0] == "cell"), seconds / 3600.0


def ordering_lines(table: dict, key: str) -> list[str]:
    """One line per metric of a self-supervised ordering the table holds (``self_supervised_ordering`` or
    ``..._refined``): best row and value, the others' values, best minus each other with the interval."""
    o = table.get(key) or {}
    lines = []
    for metric, v in (o.get("metrics") or {}).items():
        best = v["best"]
        parts = []
        for other in (m for m in v["values"] if m != best):
            iv = pair_interval(table, metric, best, other)
            sep = ", seeds separate" if v["against"].get(other, {}).get("seeds_separate") else ""
            if iv is None:
                parts.append(f"{other} {v['values'][other]:.4g}")
            else:
                d, lo, hi, sup = iv
                parts.append(f"{other} {v['values'][other]:.4g} (diff {d:+.3g} [{lo:+.3g}, {hi:+.3g}]"
                             f"{'' if sup else ', not supported'}{sep})")
        lines.append(f"  {ORDER_LABELS.get(metric, metric)}: best {best} {v['values'][best]:.4g}; " + "; ".join(parts))
    return lines


def digest(paths: list[Path], pairs: list[tuple[str, str]], means: list[str]) -> str:
    """The whole digest as text (see the module docstring); DigestError on a bad table or name."""
    tables = [load_table(p) for p in paths]
    methods_all = {r["method"] for t in tables for r in t["results"]}
    unknown = sorted({m for a, b in pairs for m in (a, b)} - methods_all)
    if unknown:
        raise DigestError(f"--pair names {', '.join(unknown)}, which no given table holds; its methods: "
                          f"{', '.join(sorted(methods_all))}")
    fields_all = {k for t in tables for r in t["results"] for k in r["summary"]}
    unknown = sorted(set(means) - fields_all)
    if unknown:
        raise DigestError(f"--mean names {', '.join(unknown)}, which no given table's cells hold; e.g. "
                          f"{', '.join(sorted(fields_all)[:12])}")
    out = []
    for path, t in zip(paths, tables):
        p = t["provenance"]
        out.append(f"## {path}: {len(p.get('cells', []))} cells, commits {p.get('commits')}, devices "
                   f"{p.get('devices')}, {p.get('compute_hours')} h recorded, seeds {p.get('training_seeds')}")
        for key, label in (("self_supervised_ordering", "one-pass"), ("self_supervised_ordering_refined", "+ refine")):
            lines = ordering_lines(t, key)
            if lines:
                out.append(f" self-supervised ordering ({label}) over {t[key].get('categories')}:")
                out += lines
        methods = {r["method"] for r in t["results"]}
        for a, b in pairs:
            if a not in methods or b not in methods:
                continue
            out.append(f" {a} minus {b}:")
            for metric in t["pairwise_bootstrap"]["metrics"]:
                iv = pair_interval(t, metric, a, b)
                if iv is not None:
                    d, lo, hi, sup = iv
                    out.append(f"  {ORDER_LABELS.get(metric, metric)}: {d:+.4g} [{lo:+.4g}, {hi:+.4g}]"
                               f"{'' if sup else ' not supported'}")
        for field in means:
            if not any(field in r.get("summary", {}) for r in t["results"]):
                continue
            vals = category_means(t, field)
            out.append(f" mean over categories of {field}: " + ", ".join(f"{m} {v:.2f}" for m, v in vals.items()))
    n, hours = unique_compute(tables)
    out.append(f"## together: {n} distinct cells, {hours:.1f} core-hours recorded "
               "(each shared cell and each training once)")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tables", nargs="+", type=Path, help="table JSONs written by scapo bench table1|table2|table3")
    ap.add_argument("--pair", action="append", default=[], help="A,B: every metric's interval of A minus B")
    ap.add_argument("--mean", default="", help="comma-separated summary fields to average over categories")
    args = ap.parse_args(argv)
    pairs = []
    for p in args.pair:
        a, sep, b = p.partition(",")
        if not sep or not a or not b:
            print(f"scapo: --pair {p!r}: give two method keys separated by a comma (e.g. scapo,op-align)",
                  file=sys.stderr)
            return 2
        pairs.append((a, b))
    try:
        print(digest(args.tables, pairs, [f for f in args.mean.split(",") if f]))
    except (KeyError, TypeError, ValueError) as e:  # a field of the expected name with a value of another shape
        print(f"scapo: a table's fields are not shaped as scapo bench writes them ({type(e).__name__}: {e}); give "
              "table JSONs written by scapo bench", file=sys.stderr)
        return 2
    except DigestError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
