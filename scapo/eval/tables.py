"""Result tables in the paper's layouts, with the paper's numbers beside ours and provenance.

Table 1 (synthetic): blocks S, D, C, R, t; one row per method with its supervision marks;
columns per category and their mean. Our rows come from :class:`~scapo.eval.evaluator.EvalResult`;
the paper's rows come from ``scapo/eval/reference/paper_table1.csv`` (transcribed from the paper's
LaTeX, checked by a test) and are labelled "(paper)". Means are over the categories shown for
our rows and the paper's own five-category mean for the paper's rows.

Each writer produces ``<name>.csv`` (long format: one value per row), ``<name>.md``,
``<name>.tex`` (booktabs) and ``<name>.json`` (values + provenance).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import pandas as pd

from scapo.eval.evaluator import EvalResult
from scapo.eval.metrics import TABLE1_METRICS
from scapo.files import atomic_write_text, check_output_dir
from scapo.report import latex_escape, markdown_table

#: Category column order of Table 1 in the paper, then the other categories.
CATEGORY_ORDER = ("laptop", "safe", "eyeglasses", "oven", "washer", "basket", "drawer", "scissors", "suitcase")
TABLE1_BLOCKS = ("S", "D", "C", "R", "t")

#: Display names of methods in tables (the paper's names for its own rows).
DISPLAY_NAMES = {"icp": "ICP", "scapo": "SCAPO (ours)", "scapo-no-refine": "SCAPO (ours, no refinement)",
                 "opalign": "OP-Align-style", "eap": "EAP-style",
                 "npcs": "NPCS-style (supervised)"}


def paper_table(name: str) -> pd.DataFrame:
    """The paper's numbers for ``name`` in ("table1", "table2", "table3")."""
    with resources.files("scapo.eval").joinpath(f"reference/paper_{name}.csv").open() as f:
        return pd.read_csv(f)


def table1_long(results: Sequence[EvalResult], include_paper: bool = True) -> pd.DataFrame:
    """Long-format Table 1: columns metric, method, source, pose, segmentation, joint, category, value."""
    rows = []
    cats = sorted({r.category for r in results}, key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    methods = list(dict.fromkeys(r.method for r in results))
    for method in methods:
        res = {r.category: r for r in results if r.method == method}
        sup = next(iter(res.values())).info.get("supervision", {})
        for metric in TABLE1_BLOCKS:
            vals = []
            for c in cats:
                v = res[c].summary.get(metric, math.nan) if c in res else math.nan
                vals.append(v)
                rows.append(dict(metric=metric, method=DISPLAY_NAMES.get(method, method), source="ours",
                                 pose=bool(sup.get("pose")), segmentation=bool(sup.get("segmentation")),
                                 joint=bool(sup.get("joint")), category=c, value=v))
            finite = [v for v in vals if not math.isnan(v)]
            rows.append(dict(metric=metric, method=DISPLAY_NAMES.get(method, method), source="ours",
                             pose=bool(sup.get("pose")), segmentation=bool(sup.get("segmentation")),
                             joint=bool(sup.get("joint")), category="mean",
                             value=sum(finite) / len(finite) if finite else math.nan))
    if include_paper:
        paper = paper_table("table1")
        for _, r in paper.iterrows():
            for c in [*cats, "mean"]:
                if c in paper.columns:
                    rows.append(dict(metric=r["metric"], method=f"{r['method']} (paper)", source="paper",
                                     pose=bool(r["pose"]), segmentation=bool(r["segmentation"]),
                                     joint=bool(r["joint"]), category=c, value=float(r[c])))
    return pd.DataFrame(rows)


def _fmt(v: float, decimals: int) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{decimals}f}"


def _wide(long: pd.DataFrame) -> tuple[list[str], list[tuple[str, str, list[str], list[str]]]]:
    cats = [c for c in dict.fromkeys(long["category"]) if c != "mean"] + ["mean"]
    blocks = []
    for metric in TABLE1_BLOCKS:
        info = TABLE1_METRICS[metric]
        sub = long[long["metric"] == metric]
        for method in dict.fromkeys(sub["method"]):
            m = sub[sub["method"] == method]
            vals = {r["category"]: r["value"] for _, r in m.iterrows()}
            marks = ["x" if bool(m.iloc[0][k]) else "" for k in ("pose", "segmentation", "joint")]
            blocks.append((metric, method, marks, [_fmt(vals.get(c, math.nan), info.decimals) for c in cats]))
    return cats, blocks


def write_table1(results: Sequence[EvalResult], out_dir: str | Path, provenance: dict, name: str = "table1",
                 include_paper: bool = True) -> list[Path]:
    """Write Table 1 (CSV, Markdown, LaTeX, JSON) into ``out_dir``; returns the paths."""
    out_dir = check_output_dir(out_dir, "table folder")
    long = table1_long(results, include_paper)
    cats, blocks = _wide(long)
    paths = {k: out_dir / f"{name}.{k}" for k in ("csv", "md", "tex", "json")}
    atomic_write_text(paths["csv"], long.to_csv(index=False))
    arrows = {m: ("\u2191" if TABLE1_METRICS[m].higher_is_better else "\u2193") for m in TABLE1_BLOCKS}
    header = ["Metric", "Method", "Pose", "Seg.", "Joint", *[c.capitalize() for c in cats[:-1]], "Mean"]
    md_rows = [[f"**{m}** {arrows[m]}", meth, *marks, *vals] for m, meth, marks, vals in blocks]
    legend = ("S: part segmentation IoU (%); D: joint direction error (deg); C: joint pivot error (x bbox "
              "diagonal, revolute joints); R: mean part rotation error (deg); t: mean part translation error "
              "(x bbox diagonal). Rows marked (paper) are the SCAPO paper's Table 1 (their datasets, not ours); "
              "their Mean is over the paper's five categories, ours over the columns shown.")
    prov = "; ".join(f"{k}: {v}" for k, v in provenance.items())
    md = [f"# Table 1 (synthetic): {', '.join(cats[:-1])}", "",
          markdown_table(header, md_rows, ["l", "l", "c", "c", "c", *["r"] * len(cats)]), "", legend, "",
          f"Provenance: {prov}", ""]
    atomic_write_text(paths["md"], "\n".join(md))
    ncol = 5 + len(cats)
    tex = ["% generated by scapo; " + latex_escape(prov), r"\begin{tabular}{ll" + "c" * 3 + "r" * len(cats) + "}",
           r"\toprule",
           " & ".join(["Metric", "Method", "Pose", "Seg.", "Joint", *[c.capitalize() for c in cats[:-1]], "Mean"])
           + r" \\", r"\midrule"]
    last = None
    for m, meth, marks, vals in blocks:
        if last is not None and m != last:
            tex.append(r"\midrule")
        arrow = r"$\uparrow$" if TABLE1_METRICS[m].higher_is_better else r"$\downarrow$"
        first = rf"\textbf{{{m}}} {arrow}" if m != last else ""
        cells = [first, latex_escape(meth), *[r"\checkmark" if x else "" for x in marks], *vals]
        tex.append(" & ".join(cells) + r" \\")
        last = m
    tex += [r"\bottomrule", r"\end{tabular}", f"% {ncol} columns", ""]
    atomic_write_text(paths["tex"], "\n".join(tex))
    payload = {"provenance": provenance,
               "results": [{"method": r.method, "category": r.category, "summary": r.summary, "info": r.info}
                           for r in results]}
    atomic_write_text(paths["json"], json.dumps(payload, indent=1, default=str) + "\n")
    return list(paths.values())
