"""Figures of datasets and predictions (matplotlib), built on :mod:`scapo.sim.preview`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scapo.data.config import GenerateConfig
from scapo.data.dataset import load
from scapo.data.generate import instance_asset_path, load_instance, sample_seed_key
from scapo.errors import DatasetError
from scapo.eval.predictions import Predictions
from scapo.files import atomic_savefig, check_output_file, read_json
from scapo.sim.preview import (
    PART_COLORS,
    axis_anchor,
    draw_sample,
    frame_cloud_axes,
    palette,
    part_colors,
    part_legend,
)
from scapo.sim.render import Renderer, render_with_retries


def render_dataset_samples(data: str | Path, split: str = "test", count: int = 4, cache_dir=None, indices=None):
    """Re-render ``count`` stored samples of a dataset with their images (generation is deterministic);
    a dataset converted from elsewhere (its card has a ``source``) gives its stored samples, without images.

    Returns (samples, titles, part_names). Raises DatasetError if a re-rendered cloud differs from
    the stored one (the assets or renderer changed since generation).
    """
    ds = load(data, split)
    if len(ds) == 0:
        raise DatasetError(f"the {split} split of {data} is empty; choose another split (--split train, test or all)")
    if indices is None:
        indices = np.linspace(0, len(ds) - 1, min(count, len(ds))).round().astype(int)
    if "source" in ds.card:  # converted from elsewhere (e.g. OP-Align's real data): nothing to re-render
        items = [ds[int(i)] for i in indices]
        titles = [f"[{ds.manifest['split'].iloc[int(i)]}] {ds.category} #{it['instance_id']} view {it['view_id']} "
                  "(stored cloud)" for i, it in zip(indices, items)]
        return items, titles, [ds.part_names] * len(items)
    cfg = GenerateConfig.from_dict(read_json(Path(data) / "config.json", "dataset config", DatasetError,
                                             "rerun 'scapo generate' with the dataset's arguments to rewrite it"))
    renderer = Renderer(cfg.render.camera, cfg.render.shader)
    samples, titles = [], []
    for i in indices:
        item = ds[int(i)]
        spec = load_instance(cfg, instance_asset_path(cfg, Path(data), item["instance_id"], cache_dir))
        s, _ = render_with_retries(renderer, spec, cfg.render, cfg.view_for(int(item["instance_id"])),
                                   sample_seed_key(cfg, item["instance_id"], item["view_id"]), keep_images=True)
        if not np.allclose(s["points"], item["points"], atol=1e-5):
            raise DatasetError(f"re-rendering sample {item['instance_id']}/{item['view_id']} of {data} does not "
                               "reproduce the stored points (assets or renderer changed since generation)")
        samples.append(s)
        state = [f"{np.degrees(v):.0f}deg" if t == 0 else f"{100 * v:.0f}cm"
                 for t, v in zip(item["joint_type"], item["joint_state"])]
        titles.append(f"[{ds.manifest['split'].iloc[int(i)]}] {cfg.category} #{item['instance_id']} view "
                      f"{item['view_id']} state {', '.join(state)}")
    renderer.close()
    return samples, titles, [ds.part_names] * len(samples)


def prediction_figure(data: str | Path, predictions: Predictions, path: str | Path, count: int = 4,
                      cache_dir=None) -> Path:
    """Top row: ground truth (labelled depth image, axes), titled as such. Bottom row: the method's segmentation
    and joint axes on the same cloud (3D), each predicted part coloured as the ground-truth part it overlaps most
    in that cloud (so a correct prediction reads in the ground truth's colours and the legend's part names); the
    legend lists only the joint kinds drawn. Test samples spread over the split."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    ds = load(data, "test")
    idx = np.linspace(0, len(ds) - 1, min(count, len(ds))).round().astype(int)
    samples, titles, names = render_dataset_samples(data, "test", count, cache_dir, indices=idx)
    rows = {(int(i), int(v)): k for k, (i, v, s) in enumerate(zip(predictions.instance_id, predictions.view_id,
                                                                    predictions.split)) if s == "test"}
    n = len(samples)
    fig = plt.figure(figsize=(3.3 * n, 6.6))
    for c, (s, i) in enumerate(zip(samples, idx)):
        item = ds[int(i)]
        if "image_part_map" in s:
            draw_sample(fig, s, f"ground truth\n{titles[c]}", column=c, columns=n, show_cloud=False)
        else:  # a converted dataset has no image: the GT cloud in 3-D instead
            ax = fig.add_subplot(2, n, c + 1, projection="3d")
            gp, gl = np.asarray(s["points"]), np.asarray(s["part_label"])
            ax.scatter(gp[:, 0], gp[:, 2], -gp[:, 1], c=part_colors(gl), s=1.5, depthshade=False)
            _draw_axes(ax, gp[gl >= 0], s["joint_type"], s["joint_axis"], s["joint_pivot"], float(s["bbox_diag"]))
            ax.set_title(f"ground truth\n{titles[c]}", fontsize=8)
            frame_cloud_axes(ax, gp, float(s["bbox_diag"]))
        ax = fig.add_subplot(2, n, n + c + 1, projection="3d")
        r = rows.get((item["instance_id"], item["view_id"]))
        pts = item["points"]
        if r is not None:
            lab = _matched_labels(predictions.part_label[r], item["part_label"])
            ax.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], c=part_colors(lab), s=1.5, depthshade=False)
            diag = float(item["bbox_diag"])
            _draw_axes(ax, pts[lab >= 0], predictions.joint_type[r], predictions.joint_axis[r],
                       predictions.joint_pivot[r], diag)
            ax.set_title(f"{predictions.method}: segmentation + joint axes", fontsize=8)
        frame_cloud_axes(ax, pts, float(item["bbox_diag"]))
    handles = [Line2D([], [], marker="o", ls="", color=c, label=nm)
               for c, nm in zip(palette(len(names[0])), part_legend(names[0]))]
    handles += _axis_handles(ds[int(idx[0])]["joint_type"] if len(idx) else ())
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    path = Path(path)
    check_output_file(path, "figure", "figure.png")
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
    return path


def _matched_labels(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Predicted part labels renamed to the ground-truth part each overlaps most (Hungarian on the
    point counts of one cloud), so that colours compare across methods; unmatched slots become -1."""
    from scipy.optimize import linear_sum_assignment

    S, P = int(max(pred.max(), 0)) + 1, int(max(gt.max(), 0)) + 1
    counts = np.zeros((S, P))
    ok = (pred >= 0) & (gt >= 0)
    np.add.at(counts, (pred[ok], gt[ok]), 1)
    rows, cols = linear_sum_assignment(-counts)
    table = np.full(S, -1, dtype=np.int64)
    table[rows] = cols
    return np.where(pred >= 0, table[np.maximum(pred, 0)], -1)


def _axis_handles(joint_types) -> list:
    """Legend entries of the joint kinds among ``joint_types`` (0 revolute: black; 1 prismatic: magenta)."""
    from matplotlib.lines import Line2D

    kinds = {int(t) for t in joint_types}
    return ([Line2D([], [], color="k", lw=2, label="revolute axis")] if 0 in kinds else []) + \
        ([Line2D([], [], color="m", lw=2, label="prismatic axis")] if 1 in kinds else [])


def _draw_axes(ax, pts: np.ndarray, types, axes, pivots, diag: float) -> None:
    for t, a, p in zip(types, axes, pivots):
        p = axis_anchor(t, a, p, pts)
        seg = np.stack([p - 0.3 * diag * a, p + 0.3 * diag * a])
        ax.plot(seg[:, 0], seg[:, 2], -seg[:, 1], "-", color="k" if t == 0 else "m", lw=2)


def methods_figure(data: str | Path, predictions: dict, path: str | Path, count: int = 3,
                   names: dict | None = None, split: str = "test") -> Path:
    """Ground truth and every method's output on the same test views.

    Args:
        data: dataset folder. predictions: row label -> :class:`~scapo.eval.predictions.Predictions`
            covering its test split. path: PNG to write. count: test views, spread over the split.
        names: row label -> display name. split: "test" (the tables' figures) or "val" (for choices).

    One column per view; the first row is the ground truth (part labels and joint axes), then one row
    per method: its segmentation, each predicted part coloured as the ground-truth part it overlaps
    most in that cloud (a display choice; the evaluator's matching is the protocol's), and its joint
    axes (black: revolute, through the pivot; magenta: prismatic, through the centroid). Camera frame.

    Raises:
        DatasetError: no test split. PredictionError: predictions that miss a shown view.
        OutputError: unwritable ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from scapo.errors import PredictionError

    ds = load(data, split)
    if len(ds) == 0:
        raise DatasetError(f"the {split} split of {data} is empty")
    check_output_file(path, "figure", "figure.png")
    names = dict(names or {})
    idx = np.linspace(0, len(ds) - 1, min(count, len(ds))).round().astype(int)
    items = [ds[int(i)] for i in idx]
    rows = [("ground truth", None), *predictions.items()]
    fig = plt.figure(figsize=(3.0 * len(items), 2.9 * len(rows)))
    for r, (label, preds) in enumerate(rows):
        index = None if preds is None else {(int(i), int(v)): k for k, (i, v, s) in enumerate(
            zip(preds.instance_id, preds.view_id, preds.split)) if s == split}
        for c, item in enumerate(items):
            ax = fig.add_subplot(len(rows), len(items), r * len(items) + c + 1, projection="3d")
            pts, diag = item["points"], float(item["bbox_diag"])
            if preds is None:
                lab, jt, ja, jp = item["part_label"], item["joint_type"], item["joint_axis"], item["joint_pivot"]
                title = f"GT #{item['instance_id']} view {item['view_id']}"
            else:
                k = index.get((int(item["instance_id"]), int(item["view_id"])))
                if k is None:
                    raise PredictionError(f"predictions {label!r} miss {split} sample {item['instance_id']}/"
                                          f"{item['view_id']} of {data}")
                lab = _matched_labels(preds.part_label[k], item["part_label"])
                jt, ja, jp = preds.joint_type[k], preds.joint_axis[k], preds.joint_pivot[k]
                title = names.get(label, label)
            ax.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], c=part_colors(lab), s=1.2, depthshade=False)
            _draw_axes(ax, pts[lab >= 0], jt, ja, jp, diag)
            ax.set_title(title, fontsize=8)
            frame_cloud_axes(ax, pts, diag)
    handles = [Line2D([], [], marker="o", ls="", color=c, label=nm)
               for c, nm in zip(palette(len(ds.part_names)), part_legend(ds.part_names))]
    handles += _axis_handles(items[0]["joint_type"] if items else ())
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.suptitle(f"{ds.card.get('category', '')}: {split} views, ground truth and each method (parts coloured as the "
                 "GT part they overlap most)", fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 0.97))
    atomic_savefig(fig, Path(path), dpi=90)
    plt.close(fig)
    return Path(path)


def error_distribution_figure(results, path: str | Path, names: dict | None = None) -> Path:
    """Cumulative distributions of the part rotation error R (top row; every part of every test
    sample) and the joint direction error D (bottom row; every joint), one column per category and one
    curve per method, its training seeds pooled; log error axis, so medians and flip rates (R > 90 deg)
    both show.

    Args:
        results: :class:`~scapo.eval.EvalResult` list (test split; per-sample columns ``R_p*``, ``D_j*``).
        path: PNG to write. names: method label -> display name.

    Raises:
        OutputError: unwritable ``path``. ValueError: no results.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not results:
        raise ValueError("no results to plot")
    check_output_file(path, "figure", "errors.png")
    names = dict(names or {})
    cats = list(dict.fromkeys(r.category for r in results))
    methods = list(dict.fromkeys(r.method for r in results))
    fig, axes = plt.subplots(2, len(cats), figsize=(3.4 * len(cats), 6.0), squeeze=False)
    for c, cat in enumerate(cats):
        for row, (prefix, what) in enumerate((("R_p", "part rotation error R (deg)"),
                                              ("D_j", "joint direction error D (deg)"))):
            ax = axes[row, c]
            for i, m in enumerate(methods):
                rs = [r for r in results if r.category == cat and r.method == m]
                vals = np.concatenate([r.per_sample[[k for k in r.per_sample.columns if k.startswith(prefix)]]
                                       .to_numpy(dtype=np.float64).ravel() for r in rs]) if rs else np.zeros(0)
                vals = np.sort(vals[np.isfinite(vals)])
                if vals.size == 0:
                    continue
                y = np.arange(1, vals.size + 1) / vals.size
                ax.step(np.maximum(vals, 0.1), y, where="post", color=PART_COLORS[i % len(PART_COLORS)],
                        label=f"{names.get(m, m)} (n={len(rs)})" if c == 0 and row == 0 else None)
            ax.set_xscale("log")
            ax.set_xlim(0.1, 180)
            ax.set_ylim(0, 1)
            ax.axvline(5, color="0.8", lw=0.8)
            ax.axvline(90, color="0.8", lw=0.8)
            ax.set_xlabel(what, fontsize=8)
            ax.set_ylabel("fraction <= x", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.set_title(cat, fontsize=9)
    fig.legend(loc="lower center", ncol=min(len(methods), 5), fontsize=8)
    fig.suptitle("Error distributions on the test split (seeds pooled; n: training seeds); grey lines at 5 and "
                 "90 deg", fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 0.96))
    atomic_savefig(fig, Path(path), dpi=90)
    plt.close(fig)
    return Path(path)


#: The at-a-glance figure's panels (:func:`summary_figure`): an :class:`~scapo.eval.EvalResult` summary key, the
#: paper's metric marked on it (:func:`scapo.eval.tables.paper_values`) and the panel's axis label. The paper reports
#: R as a mean only; its value is marked on the median R panel and the legend says so.
SUMMARY_METRICS = (("S", "S", "S: segmentation mIoU (%)"), ("R_median", "R", "median part rotation error R (deg)"))


def summary_bars(results, metrics=tuple(k for k, _, _ in SUMMARY_METRICS)):
    """The bars of :func:`summary_figure`: per row (a results' ``method`` label), category and metric, the mean over
    the row's training seeds (one :class:`~scapo.eval.EvalResult` per seed and category), their standard deviation
    (``ddof=1``; NaN for one seed) and the seeds' values; then per row and metric the category ``"mean"``: the mean
    over the categories of the per-category means (std NaN), for a row present in every category of ``results``.

    Returns:
        ``pandas.DataFrame`` with columns ``method, category, metric, mean, std, values`` (``values``: a tuple of
        floats, one per seed, in the results' order), rows in the results' order of methods and categories.

    Raises:
        ValueError: no results."""
    import pandas as pd

    if not results:
        raise ValueError("no results to plot")
    cats = list(dict.fromkeys(r.category for r in results))
    methods = list(dict.fromkeys(r.method for r in results))
    rows = []
    for m in methods:
        for metric in metrics:
            means = []
            for c in cats:
                vals = np.array([float(r.summary.get(metric, np.nan)) for r in results
                                 if r.method == m and r.category == c], dtype=np.float64)
                vals = vals[np.isfinite(vals)]
                if vals.size == 0:
                    continue
                means.append(float(vals.mean()))
                rows.append(dict(method=m, category=c, metric=metric, mean=means[-1],
                                 std=float(vals.std(ddof=1)) if vals.size > 1 else float("nan"),
                                 values=tuple(float(v) for v in vals)))
            if len(means) == len(cats) and len(cats) > 1:
                rows.append(dict(method=m, category="mean", metric=metric, mean=float(np.mean(means)),
                                 std=float("nan"), values=()))
    return pd.DataFrame(rows, columns=["method", "category", "metric", "mean", "std", "values"])


def summary_figure(results, path: str | Path, names: dict | None = None, paper: dict | None = None,
                   title: str | None = None) -> Path:
    """A table at a glance: one panel per metric of :data:`SUMMARY_METRICS` (S, median R), per category (and their
    mean) a group of bars, one per row: the mean over its training seeds, the seeds' standard deviation as an error
    bar and each seed as a dot (:func:`summary_bars`). The paper's value of a row, where ``paper`` gives one, is a
    black diamond on its bar (its R is the paper's mean R: the paper reports no median).

    Args:
        results: :class:`~scapo.eval.EvalResult` list (one per row, category and training seed; the test split).
        path: PNG to write. names: row label -> display name.
        paper: row label -> the paper's metric (``"S"``, ``"R"``) -> category (or ``"mean"``) -> the paper's value
            (:func:`scapo.eval.tables.paper_values`).
        title: the figure's title (default: what the bars are).

    Raises:
        OutputError: unwritable ``path``. ValueError: no results.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bars = summary_bars(results)
    check_output_file(path, "figure", "summary.png")
    names, paper = dict(names or {}), dict(paper or {})
    cats = list(dict.fromkeys(bars["category"]))
    methods = list(dict.fromkeys(bars["method"]))
    width = 0.8 / max(len(methods), 1)
    fig, axes = plt.subplots(len(SUMMARY_METRICS), 1, squeeze=False, figsize=(
        min(14.0, max(6.0, 2.0 + 0.4 * len(cats) * len(methods))), 2.8 * len(SUMMARY_METRICS)))
    marked = False
    for row, (metric, paper_metric, label) in enumerate(SUMMARY_METRICS):
        ax = axes[row, 0]
        for i, m in enumerate(methods):
            color = PART_COLORS[i % len(PART_COLORS)]
            for c, cat in enumerate(cats):
                hit = bars[(bars.method == m) & (bars.category == cat) & (bars.metric == metric)]
                x = c + (i - (len(methods) - 1) / 2) * width
                if len(hit):
                    b = hit.iloc[0]
                    ax.bar(x, b["mean"], width * 0.9, color=color, alpha=0.85,
                           yerr=None if np.isnan(b["std"]) else b["std"], capsize=2, error_kw=dict(lw=0.8),
                           label=names.get(m, m) if c == 0 and row == 0 else None)
                    if b["values"]:
                        ax.plot([x] * len(b["values"]), b["values"], ".", color="0.2", ms=3)
                p = paper.get(m, {}).get(paper_metric, {}).get(cat)
                if p is not None and np.isfinite(p):
                    ax.plot(x, p, "D", color="black", ms=4, label=None if marked else
                            "the paper's value (R: its mean; it reports no median)")
                    marked = True
        ax.set_xticks(range(len(cats)))
        ax.set_xticklabels(cats, fontsize=8)
        ax.set_ylabel(label, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(axis="y", color="0.9", lw=0.6)
        ax.set_axisbelow(True)
    fig.legend(loc="lower center", ncol=min(len(methods) + int(marked), 6), fontsize=7)
    fig.suptitle(title or "Test split: bars the mean over training seeds, error bars their std, dots the seeds",
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    atomic_savefig(fig, Path(path), dpi=90)
    plt.close(fig)
    return Path(path)
