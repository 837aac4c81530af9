"""Result tables in the paper's layouts, with the paper's numbers beside ours and provenance.

Table 1 (synthetic): blocks S, D, C, R, t; one row per method with its supervision marks;
columns per category and their mean. Our rows come from :class:`~scapo.eval.evaluator.EvalResult`;
the paper's rows come from ``scapo/eval/reference/paper_table1.csv`` (transcribed from the paper's
LaTeX, checked by a test) and are labelled "(paper)". Means are over the categories shown for
our rows and the paper's own five-category mean for the paper's rows.

Several results of one method on one category (training seeds) make one cell: the mean over seeds,
with the standard deviation across seeds beside it (``82.1 ± 3.4``); the CSV keeps ``std`` and
``seeds`` columns and the JSON every per-seed result.

Below the paper-layout table (means), a second table gives the robust statistics of each method and
category (:data:`ROBUST_METRICS`: medians of R, t, D, C; the rates of part rotations under 5 and 10
deg and over 90 deg; joint-state errors), because means of bimodal errors (flipped parts) rank
methods by their flip rate alone. A third section checks whether one self-supervised method is best
on mean S, D, C, mean symmetry-aware R and median R (:func:`self_supervised_ordering`: a paired bootstrap
over test instances and a comparison of training seeds), the one-pass rows and the "+ refine" rows apart;
then every pair of methods gets a paired bootstrap line (:func:`pairwise_bootstrap`).

Each writer produces ``<name>.csv`` (long format: one value per row), ``<name>.md``,
``<name>.tex`` (booktabs) and ``<name>.json`` (values + provenance).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from scapo.eval.evaluator import EvalResult
from scapo.eval.metrics import TABLE1_METRICS, MetricInfo
from scapo.files import atomic_write_text, check_output_dir, output_mark
from scapo.report import latex_escape, markdown_table

#: Category column order of Table 1 in the paper, then the other categories.
CATEGORY_ORDER = ("laptop", "safe", "eyeglasses", "oven", "washer", "basket", "drawer", "scissors", "suitcase")
#: Table 1's blocks: the paper's S, D, C, R, t, with the symmetry-aware R sym (:data:`ROBUST_METRICS`) beside the
#: strict R (both in the paper layout, so that a symmetric category's flips are seen; the paper has no R sym row).
TABLE1_BLOCKS = ("S", "D", "C", "R", "R_sym", "t")

#: ``describe(label) -> (display name, supervision marks) | None``: how a table names a method's row
#: (``scapo.methods.describe`` reads the method registry; the tables stage cannot import it).
Describe = Callable[[str], "tuple[str, dict] | None"]


#: The robust-statistics table (keys of the evaluator's summary).
ROBUST_METRICS: dict[str, MetricInfo] = {
    "R_median": MetricInfo("R med", "median part rotation error", "deg", False, 2),
    "R_under5": MetricInfo("R<5", "part rotations under 5 deg", "%", True, 1),
    "R_under10": MetricInfo("R<10", "part rotations under 10 deg", "%", True, 1),
    "R_over90": MetricInfo("R>90", "part rotations over 90 deg (flips)", "%", False, 1),
    "R_sym": MetricInfo("R sym", "mean part rotation error against the best declared symmetric ground truth", "deg",
                        False, 2),
    "R_sym_median": MetricInfo("R sym med", "median symmetry-aware part rotation error", "deg", False, 2),
    "R_sym_over90": MetricInfo("R sym>90", "symmetry-aware part rotations over 90 deg", "%", False, 1),
    "t_median": MetricInfo("t med", "median part translation error", "protocol unit", False, 3),
    "D_median": MetricInfo("D med", "median joint direction error", "deg", False, 2),
    "C_median": MetricInfo("C med", "median joint pivot error", "protocol unit", False, 3),
    "state_deg": MetricInfo("state", "mean revolute state error", "deg", False, 2),
    "state_deg_median": MetricInfo("state med", "median revolute state error", "deg", False, 2),
    "state_cm": MetricInfo("state cm", "mean prismatic state error", "cm", False, 2),
    "frame_consistency": MetricInfo("frame", "object-frame consistency: share of the split's views in the one "
                                    "canonical frame most share (scapo.eval.frames)", "share", True, 2),
    "frame_consistency_sym": MetricInfo("frame sym", "object-frame consistency against the declared symmetric "
                                        "ground truths too", "share", True, 2),
}


def _cells(results: Sequence[EvalResult], metrics) -> dict[tuple[str, str, str], tuple[float, float, int]]:
    """(method, category, metric) -> (mean over seeds, std over seeds (NaN for one), number of seeds)."""
    groups: dict[tuple[str, str], list[EvalResult]] = {}
    for r in results:
        groups.setdefault((r.method, r.category), []).append(r)
    out = {}
    for (method, cat), rs in groups.items():
        for m in metrics:
            v = np.array([r.summary.get(m, math.nan) for r in rs], dtype=np.float64)
            v = v[np.isfinite(v)]
            mean = float(v.mean()) if v.size else math.nan
            std = float(v.std(ddof=1)) if v.size > 1 else math.nan
            out[(method, cat, m)] = (mean, std, int(v.size))
    return out


def is_refined(label: str) -> bool:
    """Whether a row is a method's "+ refine" row (label ``<method>+refine``, :mod:`scapo.steps.refine`): the
    tables put these after the one-pass rows and order the self-supervised rows of each kind apart (a test-time
    search is never mixed with one-pass rows)."""
    return label.endswith("+refine")


def paper_table(name: str) -> pd.DataFrame:
    """The paper's numbers for ``name`` in ("table1", "table2", "table3")."""
    with resources.files("scapo.eval").joinpath(f"reference/paper_{name}.csv").open() as f:
        return pd.read_csv(f)


def paper_values(table: str, rows: Mapping[str, str], categories: Sequence[str]) -> dict:
    """The paper's values of our rows, for the tables' at-a-glance figure (:func:`scapo.bench.viz.summary_figure`).

    Args:
        table: "table1" (per category S, D, C, R, t: ``paper_table1.csv``) or "table3" (the five categories' mean of
            S, D, C only: ``paper_table3.csv``).
        rows: our row label -> the paper's row (Table 1: its ``method`` column, e.g. ``"SCAPO"``; Table 3: its
            ``variant``, e.g. ``"no_shape_var"``); a label mapped to a row the paper lacks gets nothing.
        categories: our categories. Table 1: the values of those the paper reports, and under ``"mean"`` their mean
            (the mean over the same categories as ours, not the paper's five); Table 3: the paper's mean under
            ``"mean"`` only where ``categories`` are its five (those of its Table 1).

    Returns:
        row label -> the paper's metric -> category (or ``"mean"``) -> value (float).

    Raises:
        ValueError: another ``table``."""
    out: dict = {}
    if table == "table1":
        paper = paper_table("table1")
        for label, name in rows.items():
            for _, r in paper[paper["method"] == name].iterrows():
                vals = {c: float(r[c]) for c in categories if c in paper.columns and not pd.isna(r[c])}
                if len(vals) == len(categories) and vals:
                    vals["mean"] = float(np.mean(list(vals.values())))
                if vals:
                    out.setdefault(label, {})[str(r["metric"])] = vals
    elif table == "table3":
        five = [c for c in paper_table("table1").columns if c not in ("metric", "method", "pose", "segmentation",
                                                                       "joint", "mean")]
        if sorted(categories) == sorted(five):
            paper = paper_table("table3")
            for label, variant in rows.items():
                for _, r in paper[paper["variant"] == variant].iterrows():
                    out[label] = {m: {"mean": float(r[m])} for m in ("S", "D", "C")}
    else:
        raise ValueError(f"the paper's values exist for table1 and table3, not {table!r}")
    return out


def table1_long(results: Sequence[EvalResult], include_paper: bool = True, describe: Describe | None = None
                ) -> pd.DataFrame:
    """Long-format Table 1: columns table ("table1" or "robust"), metric, method, source, pose,
    segmentation, joint, category, value (mean over seeds), std (over seeds; NaN for one), seeds.

    Row names and supervision marks come from ``describe`` (the method registry); a label it does not
    know keeps its name and the supervision its predictions file declares."""
    rows = []
    cats = sorted({r.category for r in results}, key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    methods = sorted(dict.fromkeys(r.method for r in results), key=is_refined)  # one-pass rows, then "+ refine"
    cells = _cells(results, [*TABLE1_BLOCKS, *ROBUST_METRICS])
    for method in methods:
        known = describe(method) if describe is not None else None
        display, sup = known if known else (method, next(r for r in results if r.method == method).info.get(
            "supervision", {}))
        marks = dict(pose=bool(sup.get("pose")), segmentation=bool(sup.get("segmentation")),
                     joint=bool(sup.get("joint")))
        for table, metrics in (("table1", TABLE1_BLOCKS), ("robust", tuple(ROBUST_METRICS))):
            for metric in metrics:
                vals = []
                for c in cats:
                    v, sd, n = cells.get((method, c, metric), (math.nan, math.nan, 0))
                    vals.append(v)
                    rows.append(dict(table=table, metric=metric, method=display,
                                     source="ours", **marks, category=c, value=v, std=sd, seeds=n))
                finite = [v for v in vals if not math.isnan(v)]
                rows.append(dict(table=table, metric=metric, method=display, source="ours",
                                 **marks, category="mean", value=sum(finite) / len(finite) if finite else math.nan,
                                 std=math.nan, seeds=min((cells.get((method, c, metric), (0, 0, 0))[2] for c in cats),
                                                         default=0)))
    if include_paper:
        paper = paper_table("table1")
        for _, r in paper.iterrows():
            for c in [*cats, "mean"]:
                if c in paper.columns:
                    rows.append(dict(table="table1", metric=r["metric"], method=f"{r['method']} (paper)",
                                     source="paper", pose=bool(r["pose"]), segmentation=bool(r["segmentation"]),
                                     joint=bool(r["joint"]), category=c, value=float(r[c]), std=math.nan, seeds=0))
    return pd.DataFrame(rows)


def _fmt(v: float, decimals: int, std: float = math.nan) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.{decimals}f}" if math.isnan(std) else f"{v:.{decimals}f} ± {std:.{decimals}f}"


def _block_info(metric: str) -> MetricInfo:
    """The :class:`MetricInfo` of a Table 1 block (the paper's metrics, or R sym from :data:`ROBUST_METRICS`)."""
    return TABLE1_METRICS[metric] if metric in TABLE1_METRICS else ROBUST_METRICS[metric]


def _wide(long: pd.DataFrame) -> tuple[list[str], list[tuple[str, str, list[str], list[str]]]]:
    long = long[long["table"] == "table1"]
    cats = [c for c in dict.fromkeys(long["category"]) if c != "mean"] + ["mean"]
    blocks = []
    for metric in TABLE1_BLOCKS:
        info = _block_info(metric)
        sub = long[long["metric"] == metric]
        for method in dict.fromkeys(sub["method"]):
            m = sub[sub["method"] == method]
            vals = {r["category"]: (r["value"], r["std"]) for _, r in m.iterrows()}
            marks = ["x" if bool(m.iloc[0][k]) else "" for k in ("pose", "segmentation", "joint")]
            cells = [_fmt(vals.get(c, (math.nan, math.nan))[0], info.decimals, vals.get(c, (math.nan, math.nan))[1])
                     for c in cats]
            blocks.append((metric, method, marks, cells))
    return cats, blocks


def _robust_rows(long: pd.DataFrame) -> list[list[str]]:
    """Rows (method, category, one cell per robust metric) of the second table (our rows only)."""
    sub = long[(long["table"] == "robust") & (long["category"] != "mean")]
    rows = []
    for method in dict.fromkeys(sub["method"]):
        for cat in dict.fromkeys(sub["category"]):
            m = sub[(sub["method"] == method) & (sub["category"] == cat)].set_index("metric")
            if m.empty:
                continue
            rows.append([method, cat, *[_fmt(m.loc[k, "value"], ROBUST_METRICS[k].decimals, m.loc[k, "std"])
                                        for k in ROBUST_METRICS]])
    return rows


def _partial_note(provenance: dict) -> list[str]:
    """Markdown lines saying that a bench's table lacks cells (``missing_cells``; ``--finished-only``)."""
    missing = provenance.get("missing_cells") or []
    if not missing:
        return []
    return [f"**Partial table:** {len(missing)} cells of this bench are not done yet ({', '.join(missing)}); rerun "
            "the bench to complete it.", ""]


def cells_markdown(cells: Sequence[dict] | None) -> list[str]:
    """Markdown lines of a bench's per-cell provenance (``scapo.bench``: category, cell, commit that
    computed it (and the evaluation's, when the evaluation was redone later), device, training /
    prediction / evaluation wall time, the charged core-minutes of its training and its inference milliseconds per
    test cloud); nothing when there is none. A cell computed on another CPU kind's
    regeneration of its dataset and adopted by this one (``adopted_from``: :func:`scapo.bench.archive.adopt_dataset`)
    says so beside its device."""
    if not cells:
        return []

    def minutes(c, k):
        return "-" if c.get(k) is None else f"{c[k] / 60:.1f}"

    def short(sha) -> str:
        sha = str(sha)
        return sha[:12] + ("-dirty" if sha.endswith("-dirty") else "")

    def commit(c):  # the code that trained and predicted it; a later evaluation's commit beside it
        return short(c["commit"]) + (f" (evaluated {short(c['evaluated_at'])})" if c.get("evaluated_at") else "")

    def device(c):
        return c["device"] + (f" (dataset {c['adopted_from'][:12]}, adopted)" if c.get("adopted_from") else "")

    rows = [[c["category"], c["cell"], commit(c), device(c), minutes(c, "train_s"),
             "-" if c.get("train_steps") is None else str(c["train_steps"]), minutes(c, "charged_s"),
             minutes(c, "predict_s"), "-" if c.get("infer_ms_per_cloud") is None else f"{c['infer_ms_per_cloud']:.1f}",
             minutes(c, "evaluate_s")] for c in cells]
    note = (["Cells marked adopted were computed on another CPU kind's regeneration of their dataset (the hash "
             "named) and adopted by this table's dataset after scoring the same on it "
             "(`results/tables_cells/README.md`, `scapo.bench.archive.adopt_dataset`).", ""]
            if any(c.get("adopted_from") for c in cells) else [])
    return ["## Cells (wall time, minutes; training steps; charged compute, core-minutes; inference, ms per test "
            "cloud)", "",
            markdown_table(["Category", "Cell", "Commit", "Device", "Train", "Steps", "Charged", "Predict",
                            "Infer ms", "Evaluate"], rows, ["l", "l", "l", "l", "r", "r", "r", "r", "r", "r"]), "",
            "Charged: the run's compute ledger (`scapo.engine.ledger`), every core-second spent before it can predict "
            "(its one-time work included); '-' for a fitted method or a run trained before the ledger.", "", *note]


#: The ordering check of the self-supervised rows: metric -> (the statistic of a cell, higher is better).
ORDERING_METRICS = {"S": ("mean S", True), "D": ("mean D", False), "C": ("mean C", False),
                    "R_sym": ("mean R sym", False), "R_median": ("median R", False)}


def _weighted_stat(values: np.ndarray, weights: np.ndarray, median: bool) -> np.ndarray:
    """Per bootstrap draw: weighted mean or (lower) weighted median of ``values (n,)`` under
    ``weights (B, n)`` (NaN values ignored) -> ``(B,)``."""
    ok = np.isfinite(values)
    v, w = values[ok], weights[:, ok]
    if v.size == 0:
        return np.full(weights.shape[0], math.nan)
    if not median:
        with np.errstate(invalid="ignore", divide="ignore"):
            return (w @ v) / w.sum(1)
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[:, order], axis=1)
    k = np.argmax(cw >= 0.5 * cw[:, -1:], axis=1)
    return v[order][k]


def _instance_weights(results: Sequence[EvalResult], cats: Sequence[str], draws: int, seed: int) -> dict:
    """The hierarchical bootstrap's resampling counts: per category its test instances (sorted) and ``draws``
    multinomial resampling counts of them, shared by every method (the pairing of a paired bootstrap); under the key
    ``"seeds"``, per ``(method, category)`` ``draws`` multinomial counts over that method's training seeds there
    (each method's own: seed 0 of one method has nothing to do with seed 0 of another), drawn from a generator keyed
    by ``seed``, the method and the category, so a method's seed draws do not depend on the other methods."""
    import zlib

    rng = np.random.default_rng(seed)
    weights: dict = {"seeds": {}}
    for c in cats:
        inst = np.unique(np.concatenate([r.per_sample["instance_id"].to_numpy() for r in results if r.category == c]))
        weights[c] = (inst, rng.multinomial(len(inst), np.full(len(inst), 1.0 / len(inst)), size=draws))
    for m, c in dict.fromkeys((r.method, r.category) for r in results if r.category in cats):
        n = sum(1 for r in results if r.method == m and r.category == c)
        g = np.random.default_rng([seed, zlib.crc32(f"{m}|{c}".encode())])
        weights["seeds"][(m, c)] = g.multinomial(n, np.full(n, 1.0 / n), size=draws)
    return weights


def _method_bootstrap(results: Sequence[EvalResult], method: str, cats: Sequence[str], metric: str, weights: dict
                      ) -> tuple[np.ndarray, float, dict[str, list[float]]]:
    """One method's value on ``metric`` as the table's Mean column has it (per category the mean over training seeds
    of the cell statistic, then the mean over ``cats``) under each hierarchical resample of ``weights`` (the
    method's training seeds, then the category's test instances: a draw's value is the mean over the drawn seeds,
    with multiplicity, of each seed's statistic on the drawn instances): ``(draws (B,), value, {category: per-seed
    values})``. A ``*_median`` metric is the median over all parts of the per-part columns (``R_median``: ``R_p*``;
    ``R_sym_median``: ``R_sym_p*``); others the per-sample column's mean."""
    draws = weights[cats[0]][1].shape[0]
    boot = np.zeros(draws)
    cat_vals, per_seed = [], {}
    for c in cats:
        inst, counts = weights[c]
        seeds_b, seeds_v = [], []
        for r in (r for r in results if r.method == method and r.category == c):
            ps = r.per_sample
            if metric.endswith("_median"):
                prefix = metric[: -len("_median")] + "_p"
                cols = [k for k in ps.columns if k.startswith(prefix) and k[len(prefix):].isdigit()]
                vals = ps[cols].to_numpy(np.float64).ravel()
                rows = np.repeat(ps["instance_id"].to_numpy(), len(cols))
            else:
                vals, rows = ps[metric].to_numpy(np.float64), ps["instance_id"].to_numpy()
            w = counts[:, np.searchsorted(inst, rows)].astype(np.float64)
            seeds_b.append(_weighted_stat(vals, w, metric.endswith("_median")))
            seeds_v.append(float(r.summary.get(metric, math.nan)))
        per = np.stack(seeds_b)  # (seeds, draws)
        sc = weights["seeds"][(method, c)].T.astype(np.float64)  # (seeds, draws): how often each seed is drawn
        ok = np.isfinite(per)
        with np.errstate(invalid="ignore", divide="ignore"):
            boot += (np.where(ok, per, 0.0) * sc).sum(0) / (ok * sc).sum(0) / len(cats)
        cat_vals.append(float(np.nanmean(seeds_v)))
        per_seed[c] = [v for v in seeds_v if math.isfinite(v)]
    return boot, float(np.mean(cat_vals)), per_seed


def _has_metric(result: EvalResult, metric: str) -> bool:
    """Whether ``result`` has what :func:`_method_bootstrap` reads for ``metric`` (its summary value and per-sample
    column, or the per-part columns of a median)."""
    if metric not in result.summary:
        return False
    if metric.endswith("_median"):
        prefix = metric[: -len("_median")] + "_p"
        return any(k.startswith(prefix) and k[len(prefix):].isdigit() for k in result.per_sample.columns)
    return metric in result.per_sample.columns


#: The metrics of the pairwise bootstrap (:func:`pairwise_bootstrap`): metric -> (name, higher is better).
PAIRWISE_METRICS = {"S": ("mean S", True), "D": ("mean D", False), "C": ("mean C", False),
                    "R": ("mean R", False), "R_sym": ("mean R sym", False), "R_median": ("median R", False),
                    "R_sym_median": ("median R sym", False)}


def pairwise_bootstrap(results: Sequence[EvalResult], draws: int = 1000, seed: int = 0, level: float = 0.95) -> dict:
    """Which differences between methods the training seeds and test instances support: for every pair of methods
    and every metric of :data:`PAIRWISE_METRICS`, a hierarchical bootstrap (``draws`` resamples: each method's
    training seeds with replacement, then each category's test instances, shared by both methods) of the difference
    of their table values on the categories both have (Efron and Tibshirani, "An Introduction to the Bootstrap",
    1993, ch. 13: percentile intervals; Davison and Hinkley, "Bootstrap Methods and their Application", 1997,
    section 3.8: resampling at both levels of a two-level design). A difference that one training seed alone shows is
    not supported: the draws without that seed have none.

    Returns ``{"draws", "level", "metrics": {metric: [{"a", "b", "categories", "a_value", "b_value", "diff" (a - b),
    "interval" [lo, hi] of the difference, "p_a_better" (share of resamples in which a is better), "supported"
    (the interval excludes 0), "better" (the better method when supported, else None)}]}}``; pairs without a
    shared category, or a metric a method lacks, are left out. Deterministic.
    """
    methods = list(dict.fromkeys(r.method for r in results))
    cats_of = {m: {r.category for r in results if r.method == m} for m in methods}
    all_cats = sorted({r.category for r in results},
                      key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    weights = _instance_weights(results, all_cats, draws, seed) if results else {}
    lo_q, hi_q = 100 * (1 - level) / 2, 100 * (1 + level) / 2
    out = {"draws": draws, "level": level, "metrics": {}}
    for metric, (_, higher) in PAIRWISE_METRICS.items():
        if not all(_has_metric(r, metric) for r in results):  # e.g. results scored before R_sym existed
            continue
        pairs = []
        for i, a in enumerate(methods):
            for b in methods[i + 1:]:
                cats = [c for c in all_cats if c in cats_of[a] and c in cats_of[b]]
                if not cats:
                    continue
                ba, va, _ = _method_bootstrap(results, a, cats, metric, weights)
                bb, vb, _ = _method_bootstrap(results, b, cats, metric, weights)
                d = ba - bb
                if not np.isfinite(d).any():
                    continue
                lo, hi = (float(x) for x in np.nanpercentile(d, [lo_q, hi_q]))
                supported = lo > 0 or hi < 0
                a_better = np.mean(d > 0) if higher else np.mean(d < 0)
                better = None if not supported else (a if (lo > 0) == higher else b)
                pairs.append({"a": a, "b": b, "categories": cats, "a_value": va, "b_value": vb, "diff": va - vb,
                              "interval": [lo, hi], "p_a_better": float(a_better), "supported": bool(supported),
                              "better": better})
        out["metrics"][metric] = pairs
    return out


def pairwise_markdown(boot: dict, display: Callable[[str], str] = str) -> list[str]:
    """The "Differences the training seeds and test instances support" lines under a table
    (:func:`pairwise_bootstrap`)."""
    if not boot.get("metrics") or not any(boot["metrics"].values()):
        return []
    lines = ["## Differences the training seeds and test instances support", ""]
    for metric, pairs in boot["metrics"].items():
        if not pairs:
            continue
        name = PAIRWISE_METRICS[metric][0]
        yes = []
        for p in pairs:
            if not p["supported"]:
                continue
            # the difference printed as the better method's value minus the other's (the pair's own order is
            # a - b, which read backwards whenever b is the better one)
            sign = 1 if p["better"] == p["a"] else -1
            lo, hi = sorted(sign * v for v in p["interval"])
            other = p["b"] if sign == 1 else p["a"]
            yes.append(f"{display(p['better'])} better than {display(other)} ({sign * p['diff']:+.3g} "
                       f"[{lo:+.3g}, {hi:+.3g}])")
        no = [f"{display(p['a'])} vs {display(p['b'])}" for p in pairs if not p["supported"]]
        lines.append(f"- {name}: " + ("; ".join(yes) if yes else "no supported difference")
                     + (f". Not supported: {', '.join(no)}" if no else "") + ".")
    lines += ["", f"A difference is supported when the {100 * boot['level']:.0f} % interval of the difference of the "
              f"two methods' table values (printed as the better one's minus the other's, over {boot['draws']} "
              "hierarchical resamples: each method's training seeds, then the test instances of the categories both "
              "have, shared by the pair) excludes 0.", ""]
    return lines


def self_supervised_ordering(results: Sequence[EvalResult], describe: Describe | None = None, draws: int = 1000,
                             seed: int = 0) -> dict:
    """Is one self-supervised method best on mean S, D, C, mean R sym and median R, averaged over the categories?

    The rows compared are the methods without any supervision mark (``describe``; else the marks their
    predictions declare), on the categories every one of them has. A method's value on a metric is the
    table's: per category the mean over training seeds of the cell statistic (mean S, D, C, R sym; median R
    over all parts), then the mean over categories; a metric some result lacks is left out. Two checks of the
    best method against each other:

    - seeds and test samples: the hierarchical bootstrap of :func:`pairwise_bootstrap` (``draws`` resamples of
      each method's training seeds, then of each category's instances, shared by all methods), giving the share of
      resamples in which the best stays better (``p_better``);
    - training seeds: on the categories where both methods have several seeds, whether the best
      method's worst seed beats the other's best seed on every such category (``seeds_separate``;
      None without such categories).

    Returns ``{"methods": [...], "categories": [...], "metrics": {metric: {"values": {method: v},
    "best": method, "against": {method: {"p_better": float, "seeds_separate": bool | None}}}}}``;
    empty ``methods`` when fewer than two self-supervised methods share a category. Deterministic.
    """
    def unsupervised(label: str) -> bool:
        known = describe(label) if describe is not None else None
        sup = known[1] if known else next(r for r in results if r.method == label).info.get("supervision", {})
        return not any(bool(sup.get(k)) for k in ("pose", "segmentation", "joint"))

    methods = [m for m in dict.fromkeys(r.method for r in results) if unsupervised(m)]
    cats = [c for c in sorted({r.category for r in results},
                              key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
            if all(any(r.method == m and r.category == c for r in results) for m in methods)]
    out = {"methods": methods, "categories": cats, "draws": draws, "metrics": {}}
    if len(methods) < 2 or not cats:
        return {**out, "methods": []}
    weights = _instance_weights(results, cats, draws, seed)
    for metric, (_, higher) in ORDERING_METRICS.items():
        if not all(_has_metric(r, metric) for r in results if r.method in methods):
            continue  # e.g. results scored before R_sym existed
        boot, value, per_seed = {}, {}, {}
        for m in methods:
            boot[m], value[m], seeds = _method_bootstrap(results, m, cats, metric, weights)
            per_seed.update({(m, c): v for c, v in seeds.items()})
        finite = [m for m in methods if math.isfinite(value[m])]
        if not finite:
            continue
        best = (max if higher else min)(finite, key=lambda m: value[m])
        against = {}
        for m in methods:
            if m == best:
                continue
            diff = boot[best] - boot[m] if higher else boot[m] - boot[best]
            sep = None
            for c in cats:
                a, b = per_seed[(best, c)], per_seed[(m, c)]
                if len(a) > 1 and len(b) > 1:
                    ok = (min(a) > max(b)) if higher else (max(a) < min(b))
                    sep = ok if sep is None else (sep and ok)
            against[m] = {"p_better": float(np.mean(diff > 0)), "seeds_separate": sep}
        out["metrics"][metric] = {"values": value, "best": best, "against": against}
    return out


def ordering_markdown(order: dict, display: Callable[[str], str] = str, rows_kind: str = "") -> list[str]:
    """The "Self-supervised ordering" section of a table (:func:`self_supervised_ordering`); ``rows_kind`` names
    the rows compared in its title (e.g. "one-pass rows")."""
    if not order.get("methods"):
        return []
    rows = []
    for metric, res in order["metrics"].items():
        name = ORDERING_METRICS[metric][0]
        vals = ", ".join(f"{display(m)} {v:.3g}" for m, v in res["values"].items())
        checks = "; ".join(
            f"vs {display(m)}: better in {100 * a['p_better']:.1f} % of resamples"
            + ("" if a["seeds_separate"] is None else
               f", seeds {'separate' if a['seeds_separate'] else 'overlap'}") for m, a in res["against"].items())
        rows.append([name, display(res["best"]), vals, checks])
    legend = (f"Self-supervised rows on the categories all of them have ({', '.join(order['categories'])}); values "
              "as in the table's Mean column. Resamples: a hierarchical bootstrap over each method's training "
              f"seeds, then the test instances ({order['draws']} draws); seeds separate: on every category where "
              "both have several training seeds, the best method's worst seed beats the other's best seed.")
    return [f"## Self-supervised ordering{f' ({rows_kind})' if rows_kind else ''}", "",
            markdown_table(["Metric", "Best", "Values (mean over categories)", "Checks of the best"], rows,
                           ["l", "l", "l", "l"]), "", legend, ""]


def orderings(results: Sequence[EvalResult], describe: Describe | None = None,
              display: Callable[[str], str] = str) -> tuple[dict, dict, list[str]]:
    """The self-supervised orderings of a table's one-pass rows and of its "+ refine" rows, each among its own kind
    (:func:`self_supervised_ordering`; ``{"methods": []}`` without "+ refine" rows), and their Markdown sections."""
    refined = [r for r in results if is_refined(r.method)]
    order = self_supervised_ordering([r for r in results if not is_refined(r.method)], describe)
    order_refined = self_supervised_ordering(refined, describe) if refined else {"methods": []}
    md = [*ordering_markdown(order, display, "one-pass rows" if refined else ""),
          *ordering_markdown(order_refined, display, '"+ refine" rows')]
    return order, order_refined, md


def table1_markdown(results: Sequence[EvalResult], protocol: str = "scapo", include_paper: bool = True,
                    describe: Describe | None = None) -> str:
    """The Markdown of Table 1 (paper layout, means) and of the medians-and-rates table below it."""
    return write_table1(results, None, {"protocol": protocol}, include_paper=include_paper, markdown_only=True,
                        describe=describe)


def chance_rotation_error_deg(folded: bool = False) -> float:
    """Mean rotation error (deg) of a prediction independent of a ground truth drawn uniformly from SO(3): the
    angle of a uniform random rotation has density ``(1 - cos a) / pi`` on ``[0, pi]``, so its mean is
    ``pi / 2 + 2 / pi`` rad (126.48 deg); folded to ``min(a, pi - a)`` (the ``eap`` protocol) it is ``pi / 4``
    (45 deg)."""
    return math.degrees(math.pi / 4 if folded else math.pi / 2 + 2 / math.pi)


def _chance_note(protocol: str, provenance: dict) -> str:
    """The chance level of R under this protocol, for a table whose objects were rotated uniformly."""
    if provenance.get("data", {}).get("random_rotation") is not True:
        return ""
    from scapo.eval.protocols import get_protocol

    folded = get_protocol(protocol).fold_rotation
    return (f" Chance: the objects are rotated uniformly over SO(3), so a rotation independent of the view scores R "
            f"{chance_rotation_error_deg(folded):.1f} deg on average under this protocol"
            f"{' (errors folded at 90 deg)' if folded else ''}.")


def viewpoints_title(provenance: dict) -> str:
    """The viewpoint setting of a table's data as its title says it (``", whole sphere: ..."``), from the provenance's
    ``data.viewpoints`` (:data:`scapo.bench.experiments.VIEWPOINT_LABELS`), or for a table written before the setting
    existed from ``data.random_rotation`` (True: whole sphere; False: upright), and ``data.parts_alone`` (every part
    rendered alone); "" when the provenance says neither."""
    data = provenance.get("data", {}) if isinstance(provenance, dict) else {}
    vp = data.get("viewpoints")
    if vp is None and isinstance(data.get("random_rotation"), bool):
        vp = "sphere" if data["random_rotation"] else "upright"
    return {"paper": ", the paper's viewpoints",
            "sphere": ", whole sphere: objects under uniform SO(3) rotations, harder than the paper",
            "upright": ", objects upright: the rotation diagnostic, not the paper's setting"}.get(vp, "") + (
        ", every part rendered alone (EAP's data regime: no part hides another)" if data.get("parts_alone") else "")


def budget_note(provenance: dict) -> list[str]:
    """The markdown lines that state a table's equal training budget (``scapo bench table1 --budget-minutes``: the
    provenance's ``training_budget``), or none."""
    tb = provenance.get("training_budget") if isinstance(provenance, dict) else None
    if not tb:
        return []
    per = "; ".join(f"{cat}: " + ", ".join(f"{k} {v}" for k, v in sched.items())
                    for cat, sched in tb.get("schedules", {}).items())
    return [f"Equal training budget: {tb.get('core_minutes_per_run')} core-minutes of one CPU core of optimisation "
            "per training run for every trained method (epochs from each method's clouds/s measured on the dataset; "
            f"one-time costs after training, such as EAP-style's joint estimation, not charged; schedules: {per}).",
            ""]


def write_table1(results: Sequence[EvalResult], out_dir: str | Path | None, provenance: dict, name: str = "table1",
                 include_paper: bool = True, markdown_only: bool = False, describe: Describe | None = None):
    """Write Table 1 (CSV, Markdown, LaTeX, JSON) into ``out_dir``; returns the paths (with
    ``markdown_only``, returns the Markdown text and writes nothing). ``describe``: see :func:`table1_long`."""
    out_dir = Path(".") if markdown_only else check_output_dir(out_dir, "table folder")
    long = table1_long(results, include_paper, describe)
    cats, blocks = _wide(long)
    paths = {k: out_dir / f"{name}.{k}" for k in ("csv", "md", "tex", "json")}
    if not markdown_only:
        atomic_write_text(paths["csv"], long.to_csv(index=False))
    arrows = {m: ("\u2191" if _block_info(m).higher_is_better else "\u2193") for m in TABLE1_BLOCKS}
    header = ["Metric", "Method", "Pose", "Seg.", "Joint", *[c.capitalize() for c in cats[:-1]], "Mean"]
    md_rows = [[f"**{_block_info(m).symbol}** {arrows[m]}", meth, *marks, *vals] for m, meth, marks, vals in blocks]
    protocol = provenance.get("protocol", "scapo")
    seeds = sorted({int(r["seeds"]) for _, r in long[(long.source == "ours")].iterrows() if r["seeds"] > 1})
    seed_note = (f" Cells of trained methods with several training seeds are mean ± standard deviation over "
                 f"{'/'.join(map(str, seeds))} seeds." if seeds else "")
    legend = (f"Protocol: {protocol}. S: part segmentation IoU (%); D: joint direction error (deg); C: joint pivot "
              "error (scapo/eap protocols: x bbox diagonal, revolute joints; op-align: in units of a cloud scaled to "
              "mean centroid distance 0.25, every joint); R: mean part rotation error (deg), strict; R sym: the same "
              "against the declared symmetric ground truth that fits each sample best (equal to R where the category "
              "declares no symmetry; the paper has no such row); t: mean part translation error (same unit as C). "
              "Rows \"+ refine\" are the method-independent test-time refinement of that method's predictions "
              "(`scapo predict --refine`), listed after the one-pass rows. Rows marked (paper) are the SCAPO "
              "paper's Table 1 (their datasets and protocol, not ours); their Mean is over the paper's five "
              f"categories, ours over the columns shown.{seed_note}{_chance_note(protocol, provenance)}")
    rob_header = ["Method", "Category", *[f"{i.symbol} ({i.unit})" for i in ROBUST_METRICS.values()]]
    rob_rows = _robust_rows(long)
    rob_legend = ("Robust statistics (ours): medians over all parts / joints of all test samples, % of part "
                  "rotations under 5 and 10 deg and over 90 deg (flips), revolute joint-state error. A mean "
                  "far above its median means a few large errors (usually flipped parts). R sym: the part rotation "
                  "error against the declared symmetric ground truth that fits each sample best (the dataset card's "
                  "symmetry; equal to R where none is declared), mean, median and share over 90 deg.")
    prov = "; ".join(f"{k}: {v}" for k, v in provenance.items() if k != "cells")
    partial = _partial_note(provenance)
    pairs = pairwise_bootstrap(results)
    display = _display(describe)
    order, order_refined, order_md = orderings(results, describe, display)

    title = f"Table 1 (synthetic{viewpoints_title(provenance)})"
    md = [f"# {title}: {', '.join(cats[:-1])}", "", *partial, *budget_note(provenance),
          markdown_table(header, md_rows, ["l", "l", "c", "c", "c", *["r"] * len(cats)]), "", legend, "",
          "## Medians and rates", "", markdown_table(rob_header, rob_rows, ["l", "l", *["r"] * len(ROBUST_METRICS)]),
          "", rob_legend, "", *order_md, *pairwise_markdown(pairs, display),
          f"Provenance: {prov}", "",
          *cells_markdown(provenance.get("cells"))]
    if markdown_only:
        return "\n".join(md[:md.index(f"Provenance: {prov}")])
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
        arrow = r"$\uparrow$" if _block_info(m).higher_is_better else r"$\downarrow$"
        first = rf"\textbf{{{latex_escape(_block_info(m).symbol)}}} {arrow}" if m != last else ""
        cells = [first, latex_escape(meth), *[r"\checkmark" if x else "" for x in marks],
                 *[v.replace("±", r"$\pm$") for v in vals]]
        tex.append(" & ".join(cells) + r" \\")
        last = m
    tex += [r"\bottomrule", r"\end{tabular}", f"% {ncol} columns; protocol {latex_escape(protocol)}", "",
            "% medians and rates", r"\begin{tabular}{ll" + "r" * len(ROBUST_METRICS) + "}", r"\toprule",
            " & ".join(latex_escape(h) for h in rob_header) + r" \\", r"\midrule",
            *[" & ".join(latex_escape(c).replace("±", r"$\pm$") for c in r) + r" \\" for r in rob_rows],
            r"\bottomrule", r"\end{tabular}", ""]
    atomic_write_text(paths["tex"], "\n".join(tex))
    payload = {**output_mark("scapo table"), "provenance": provenance, "self_supervised_ordering": order,
               "self_supervised_ordering_refined": order_refined, "pairwise_bootstrap": pairs,
               "results": [{"method": r.method, "category": r.category, "split": r.split,
                            "seed": r.info.get("seed"), "summary": r.summary, "info": r.info} for r in results]}
    atomic_write_text(paths["json"], json.dumps(payload, indent=1, default=str) + "\n")
    return list(paths.values())


#: Table 3's rows: label of the predictions -> (variant key of paper_table3.csv, display name).
TABLE3_VARIANTS = {
    "scapo": ("full", "Full"),
    "scapo-no-shape_var": ("no_shape_var", "w/o L_shape-var"),
    "scapo-no-dir_align": ("no_dir_align", "w/o L_dir-align"),
    "scapo-no-joint_prox": ("no_joint_prox", "w/o L_joint-prox"),
    "scapo-no-joint_boundary": ("no_joint_boundary", "w/o L_joint-boundary"),
}
#: Table 3's metrics: the paper's three, then the rotation error it does not report (mean, median, flip rate) and
#: the symmetry-aware one beside it (mean, flip rate).
TABLE3_METRICS = ("S", "D", "C", "R", "R_median", "R_over90", "R_sym", "R_sym_over90")


def table3_long(results: Sequence[EvalResult], include_paper: bool = True) -> pd.DataFrame:
    """Long-format Table 3: columns variant, display, source, metric, category (or "mean"), value
    (mean over seeds), std (over seeds; NaN for one), seeds. ``results``: the SCAPO ablation's cells,
    labelled as in :data:`TABLE3_VARIANTS`; the paper's rows (their five-category mean) are labelled
    "(paper)"."""
    unknown = sorted({r.method for r in results} - set(TABLE3_VARIANTS))
    if unknown:
        raise ValueError(f"Table 3 rows must be SCAPO ablation labels ({', '.join(TABLE3_VARIANTS)}); got {unknown}")
    cats = sorted({r.category for r in results}, key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    cells = _cells(results, TABLE3_METRICS)
    rows = []
    for label, (variant, display) in TABLE3_VARIANTS.items():
        if not any(r.method == label for r in results):
            continue
        for metric in TABLE3_METRICS:
            vals = []
            for c in cats:
                v, sd, n = cells.get((label, c, metric), (math.nan, math.nan, 0))
                vals.append(v)
                rows.append(dict(variant=variant, display=display, source="ours", metric=metric, category=c,
                                 value=v, std=sd, seeds=n))
            finite = [v for v in vals if not math.isnan(v)]
            rows.append(dict(variant=variant, display=display, source="ours", metric=metric, category="mean",
                             value=sum(finite) / len(finite) if finite else math.nan, std=math.nan,
                             seeds=min((cells.get((label, c, metric), (0, 0, 0))[2] for c in cats), default=0)))
    if include_paper:
        names = {v: d for v, d in TABLE3_VARIANTS.values()}
        for _, r in paper_table("table3").iterrows():
            for metric in ("S", "D", "C"):
                rows.append(dict(variant=r["variant"], display=f"{names.get(r['variant'], r['variant'])} (paper)",
                                 source="paper", metric=metric, category="mean", value=float(r[metric]), std=math.nan,
                                 seeds=0))
    return pd.DataFrame(rows)


def write_table3(results: Sequence[EvalResult], out_dir: str | Path, provenance: dict,
                 name: str = "table3_ablation", include_paper: bool = True) -> list[Path]:
    """Write Table 3 (the SCAPO ablation) as ``<name>.{csv,md,tex,json}``: one row per variant (ours,
    then the paper's), per metric a column per category and their mean (mean ± std over seeds)."""
    out_dir = check_output_dir(out_dir, "table folder")
    long = table3_long(results, include_paper)
    ours = long[long.source == "ours"]
    cats = [c for c in dict.fromkeys(ours["category"]) if c != "mean"] + ["mean"]
    info = {**{k: TABLE1_METRICS[k] for k in ("S", "D", "C", "R")},
            **{k: ROBUST_METRICS[k] for k in ("R_median", "R_over90", "R_sym", "R_sym_over90")}}
    header = ["Variant", *[f"{m} {c}" if c != "mean" else f"{m} mean" for m in TABLE3_METRICS for c in cats]]
    rows = []
    for display in dict.fromkeys(long["display"]):
        sub = long[long.display == display]
        cells = []
        for m in TABLE3_METRICS:
            for c in cats:
                hit = sub[(sub.metric == m) & (sub.category == c)]
                cells.append("-" if hit.empty else _fmt(float(hit.iloc[0]["value"]), info[m].decimals,
                                                        float(hit.iloc[0]["std"])))
        rows.append([display, *cells])
    protocol = provenance.get("protocol", "scapo")
    legend = (f"Protocol: {protocol}. S: part segmentation IoU (%, higher is better); D: joint direction error "
              "(deg); C: joint pivot error (x bbox diagonal); R: mean part rotation error (deg); R_median: its "
              "median; R_over90: % of part rotations off by more than 90 deg (flips); R_sym, R_sym_over90: the same "
              "against the best of the declared symmetric ground truths (the paper reports S, D, C only). Ours: "
              "mean ± std over training seeds per category; mean: over the categories shown. Rows marked (paper): "
              "the SCAPO paper's Table 3 (its five synthetic categories, its data and protocol).")
    title = f"Table 3 (ablation of SCAPO's regularisers{viewpoints_title(provenance)}): {', '.join(cats[:-1])}"
    return _write_table_files(out_dir, name, title,
                              long, header, rows, ["l", *["r"] * (len(header) - 1)], legend, provenance, results,
                              describe=lambda label: (TABLE3_VARIANTS[label][1], {}) if label in TABLE3_VARIANTS
                              else None)


def _display(describe: Describe | None) -> Callable[[str], str]:
    """A row label's display name (``describe``'s, else the label)."""
    def display(label: str) -> str:
        known = describe(label) if describe is not None else None
        return known[0] if known else label
    return display


def robust_markdown(results: Sequence[EvalResult], display: Callable[[str], str] = str) -> list[str]:
    """A "Medians and rates" section for a table whose main layout has no rotation column (Table 2): per method and
    category, the strict mean part rotation error and every :data:`ROBUST_METRICS` entry (the symmetry-aware R sym
    beside R's median and flip rate), mean ± std over training seeds."""
    if not results:
        return []
    keys = ["R", *ROBUST_METRICS]
    cells = _cells(results, keys)
    info = {"R": TABLE1_METRICS["R"], **ROBUST_METRICS}
    cats = sorted({r.category for r in results}, key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    rows = []
    for method in dict.fromkeys(r.method for r in results):
        for c in cats:
            if (method, c, "R") not in cells:
                continue
            rows.append([display(method), c, *[_fmt(cells[(method, c, k)][0], info[k].decimals,
                                                    cells[(method, c, k)][1]) for k in keys]])
    header = ["Method", "Category", *[f"{info[k].symbol} ({info[k].unit})" for k in keys]]
    return ["## Medians and rates", "", markdown_table(header, rows, ["l", "l", *["r"] * len(keys)]), "",
            "R: mean part rotation error (strict); R sym: against the declared symmetric ground truth that fits each "
            "sample best (equal to R where none is declared); medians and rates over all parts of all test samples.",
            ""]


def _write_table_files(out_dir, name: str, title: str, long: pd.DataFrame, header: list[str], rows: list[list[str]],
                       align: list[str], legend: str, provenance: dict, results: Sequence[EvalResult],
                       with_info: bool = False, extra_md: Sequence[str] = (), describe: Describe | None = None
                       ) -> list[Path]:
    """``<name>.csv`` (the long table), ``.md`` (title, partial-bench note, table, legend, the self-supervised
    orderings of the one-pass and of the "+ refine" rows, the bootstrap lines, provenance, per-cell times), ``.tex``
    (the table, provenance as a comment) and ``.json`` (provenance, orderings, bootstrap, every result's summary)."""
    prov = "; ".join(f"{k}: {v}" for k, v in provenance.items() if k != "cells")
    paths = {k: Path(out_dir) / f"{name}.{k}" for k in ("csv", "md", "tex", "json")}
    atomic_write_text(paths["csv"], long.to_csv(index=False))
    pairs = pairwise_bootstrap(results)
    display = _display(describe)
    order, order_refined, order_md = orderings(results, describe, display)
    md = [f"# {title}", "", *_partial_note(provenance), markdown_table(header, rows, align), "", legend, "",
          *extra_md, *order_md, *pairwise_markdown(pairs, display),
          f"Provenance: {prov}", "", *cells_markdown(provenance.get("cells"))]
    atomic_write_text(paths["md"], "\n".join(md))
    cols = "".join("r" if a == "r" else ("c" if a == "c" else "l") for a in align)
    tex = ["% generated by scapo; " + latex_escape(prov), r"\begin{tabular}{" + cols + "}",
           r"\toprule", " & ".join(latex_escape(h) for h in header) + r" \\", r"\midrule",
           *[" & ".join(latex_escape(c).replace("±", r"$\pm$") for c in r) + r" \\" for r in rows],
           r"\bottomrule", r"\end{tabular}", ""]
    atomic_write_text(paths["tex"], "\n".join(tex))
    payload = {**output_mark("scapo table"), "provenance": provenance, "self_supervised_ordering": order,
               "self_supervised_ordering_refined": order_refined, "pairwise_bootstrap": pairs,
               "results": [{"method": r.method, "category": r.category, "split": r.split, "seed": r.info.get("seed"),
                            "summary": r.summary, **({"info": r.info} if with_info else {})} for r in results]}
    atomic_write_text(paths["json"], json.dumps(payload, indent=1, default=str) + "\n")
    return list(paths.values())


#: Table 2's columns (keys of the evaluator's summary, in %): segmentation precision at IoU > 75 / 50 %,
#: joint and part AP at 5 deg 5 cm, 10 deg 10 cm, 15 deg 15 cm (averaged over joints / parts: "mean mAP").
TABLE2_METRICS = ("seg_75", "seg_50", "ap_joint_5", "ap_joint_10", "ap_joint_15", "ap_part_5", "ap_part_10",
                  "ap_part_15")
#: OP-Align's "min mAP" (a sample counts only if all its parts / joints pass), in the CSV and JSON only.
TABLE2_MIN_METRICS = ("min_seg_75", "min_seg_50", "min_ap_joint_5", "min_ap_joint_10", "min_ap_part_5",
                      "min_ap_part_10")
TABLE2_HEADER = ("Seg 75%", "Seg 50%", "Joint 5/5", "Joint 10/10", "Joint 15/15", "Part 5/5", "Part 10/10",
                 "Part 15/15")


def table2_long(results: Sequence[EvalResult], include_paper: bool = True,
                describe: Describe | None = None) -> pd.DataFrame:
    """Long-format Table 2: columns method, display, source, pose, segmentation, joint (supervision marks),
    metric, category (or "mean"), value (mean over seeds, %), std, seeds. The paper's rows (its real data)
    are labelled "(paper)"."""
    cats = sorted({r.category for r in results}, key=lambda c: CATEGORY_ORDER.index(c) if c in CATEGORY_ORDER else 99)
    metrics = TABLE2_METRICS + TABLE2_MIN_METRICS
    cells = _cells(results, metrics)
    rows = []
    for label in sorted(dict.fromkeys(r.method for r in results), key=is_refined):  # one-pass rows, then "+ refine"
        known = describe(label) if describe is not None else None
        display, sup = known if known else (label, next(r for r in results if r.method == label).info.get(
            "supervision", {}))
        marks = {k: bool(sup.get(k)) for k in ("pose", "segmentation", "joint")}
        for metric in metrics:
            vals = []
            for c in cats:
                v, sd, n = cells.get((label, c, metric), (math.nan, math.nan, 0))
                vals.append(v)
                rows.append(dict(method=label, display=display, source="ours", **marks, metric=metric, category=c,
                                 value=v, std=sd, seeds=n))
            finite = [v for v in vals if not math.isnan(v)]
            rows.append(dict(method=label, display=display, source="ours", **marks, metric=metric, category="mean",
                             value=sum(finite) / len(finite) if finite else math.nan, std=math.nan,
                             seeds=min((cells.get((label, c, metric), (0, 0, 0))[2] for c in cats), default=0)))
    if include_paper:
        paper = paper_table("table2")
        for method in dict.fromkeys(paper["method"]):
            sub = paper[paper.method == method]
            marks = {k: bool(sub.iloc[0][k]) for k in ("pose", "segmentation", "joint")}
            for metric in TABLE2_METRICS:
                for _, r in sub.iterrows():
                    rows.append(dict(method=method, display=f"{method} (paper)", source="paper", **marks,
                                     metric=metric, category=r["category"], value=float(r[metric]), std=math.nan,
                                     seeds=0))
                rows.append(dict(method=method, display=f"{method} (paper)", source="paper", **marks, metric=metric,
                                 category="mean", value=float(sub[metric].mean()), std=math.nan, seeds=0))
    return pd.DataFrame(rows)


def write_table2(results: Sequence[EvalResult], out_dir: str | Path, provenance: dict,
                 name: str = "table2_real_style", include_paper: bool = True,
                 describe: Describe | None = None) -> list[Path]:
    """Write Table 2 (real-world style, AP) as ``<name>.{csv,md,tex,json}`` in the paper's layout: per
    category (then their mean) one row per method with its supervision marks, segmentation precision at
    75 / 50 % IoU, joint and part mAP at 5/10/15 deg and cm (mean over parts / joints; ours: mean ± std
    over training seeds), the paper's rows beside ours (labelled, on its real scans). The CSV and JSON also
    hold OP-Align's min-mAP variants."""
    out_dir = check_output_dir(out_dir, "table folder")
    long = table2_long(results, include_paper, describe)
    ours = long[long.source == "ours"]
    cats = [c for c in dict.fromkeys(ours["category"]) if c != "mean"]
    header = ["Category", "Method", "Pose", "Seg.", "Joint", *TABLE2_HEADER]
    rows = []
    for cat in [*cats, "mean"]:
        for display in dict.fromkeys(long["display"]):
            sub = long[(long.display == display) & (long.category == cat)]
            if sub.empty or sub["value"].isna().all():
                continue
            first = sub.iloc[0]
            vals = []
            for m in TABLE2_METRICS:
                hit = sub[sub.metric == m]
                vals.append("-" if hit.empty else _fmt(float(hit.iloc[0]["value"]), 2, float(hit.iloc[0]["std"])))
            rows.append([cat.capitalize() if cat != "mean" else "Mean", display,
                         *["x" if first[k] else "" for k in ("pose", "segmentation", "joint")], *vals])
    protocol = provenance.get("protocol", "op-align")
    from scapo.eval.protocols import get_protocol

    proto = get_protocol(protocol)
    background = (" (background points, label -1, left out, as OP-Align's code scores real scans)"
                  if proto.seg_background == "ignored" else " (background points predicted as a part count against it)")
    pivots = "every joint, prismatic ones included" if proto.pivot_prismatic else "prismatic joints: direction only"
    twins = (" Basket (symmetric: a half turn exchanges its handles): parts labelled by view, the handle on the "
             "camera's side is handle_a; a sample predicted in the exchanged part order is scored against that other "
             "ground truth (share: twin_rate in the JSON)." if proto.symmetric_gt and "basket" in cats else "")
    legend = (f"Protocol: {protocol}. Seg 75% / 50%: share of test samples (%) whose part IoU{background} exceeds "
              "75 / 50 %, averaged over parts; Joint a/d: share of joints whose direction error is under a deg and "
              f"pivot error under d cm ({pivots}); Part a/d: share of parts whose rotation "
              "error is under a deg and translation error under d cm; both averaged over joints / parts ('mean "
              "mAP'; OP-Align's 'min mAP', where a sample counts only if all pass, is in the CSV / JSON). Pose / "
              "Seg. / Joint: the labels a method trains with ((SJ): the semi-supervised setting of the paper's "
              "Table 2). Ours: our procedural objects under --sensor realistic (depth noise, flying pixels, "
              "detector-style mask), mean ± std over training seeds; Mean: over the categories shown. Rows "
              "marked (paper): the SCAPO paper's Table 2, on OP-Align's real RGB-D scans, not our data." + twins)
    return _write_table_files(out_dir, name, f"Table 2 (real-world style): {', '.join(cats)}", long, header, rows,
                              ["l", "l", "c", "c", "c", *["r"] * len(TABLE2_METRICS)], legend, provenance, results,
                              with_info=True, extra_md=robust_markdown(results, _display(describe)), describe=describe)
