"""Figures of datasets and predictions (matplotlib), built on :mod:`scapo.sim.preview`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scapo.data.config import GenerateConfig
from scapo.data.dataset import load
from scapo.data.generate import sample_seed_key
from scapo.errors import DatasetError
from scapo.eval.predictions import Predictions
from scapo.files import atomic_savefig, check_output_file, read_json
from scapo.sim.assets import build_instance, parse_urdf
from scapo.sim.preview import PART_COLORS, draw_sample, frame_cloud_axes, part_colors
from scapo.sim.render import Renderer, render_with_retries


def render_dataset_samples(data: str | Path, split: str = "test", count: int = 4, cache_dir=None, indices=None):
    """Re-render ``count`` stored samples of a dataset with their images (generation is deterministic).

    Returns (samples, titles, part_names). Raises DatasetError if a re-rendered cloud differs from
    the stored one (the assets or renderer changed since generation).
    """
    ds = load(data, split)
    if len(ds) == 0:
        raise DatasetError(f"the {split} split of {data} is empty; choose another split (--split train, test or all)")
    cfg = GenerateConfig.from_dict(read_json(Path(data) / "config.json", "dataset config", DatasetError,
                                             "rerun 'scapo generate' with the dataset's arguments to rewrite it"))
    if indices is None:
        indices = np.linspace(0, len(ds) - 1, min(count, len(ds))).round().astype(int)
    renderer = Renderer(cfg.render.camera, cfg.render.shader)
    samples, titles = [], []
    for i in indices:
        item = ds[int(i)]
        rec = build_instance(cfg.category, item["instance_id"], cfg.seed, cache_dir)
        spec = parse_urdf(rec.urdf, category=cfg.category)
        s, _ = render_with_retries(renderer, spec, cfg.render, cfg.view_config,
                                   sample_seed_key(cfg, item["instance_id"], item["view_id"]), keep_images=True)
        if not np.allclose(s["points"], item["points"], atol=1e-5):
            raise DatasetError(f"re-rendering sample {item['instance_id']}/{item['view_id']} of {data} does not "
                               "reproduce the stored points (assets or renderer changed since generation)")
        samples.append(s)
        state = [f"{np.degrees(v):.0f}deg" if t == 0 else f"{100 * v:.0f}cm"
                 for t, v in zip(item["joint_type"], item["joint_state"])]
        titles.append(f"{cfg.category} #{item['instance_id']} view {item['view_id']} state {', '.join(state)}")
    renderer.close()
    return samples, titles, [ds.part_names] * len(samples)


def prediction_figure(data: str | Path, predictions: Predictions, path: str | Path, count: int = 4,
                      cache_dir=None) -> Path:
    """Top row: ground truth (labelled depth image, axes). Bottom row: the method's segmentation and
    joint axes on the same cloud (3D). Test samples spread over the split."""
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
        draw_sample(fig, s, titles[c], column=c, columns=n, show_cloud=False)
        ax = fig.add_subplot(2, n, n + c + 1, projection="3d")
        r = rows.get((item["instance_id"], item["view_id"]))
        pts = item["points"]
        if r is not None:
            lab = predictions.part_label[r]
            ax.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], c=part_colors(lab), s=1.5, depthshade=False)
            diag = float(item["bbox_diag"])
            for t, a, p in zip(predictions.joint_type[r], predictions.joint_axis[r], predictions.joint_pivot[r]):
                p = p if t == 0 else pts.mean(0)
                seg = np.stack([p - 0.3 * diag * a, p + 0.3 * diag * a])
                ax.plot(seg[:, 0], seg[:, 2], -seg[:, 1], "-", color="k" if t == 0 else "m", lw=2)
            ax.set_title(f"{predictions.method}: segmentation + joint axes", fontsize=8)
        frame_cloud_axes(ax, pts, float(item["bbox_diag"]))
    handles = [Line2D([], [], marker="o", ls="", color=PART_COLORS[i], label=nm) for i, nm in enumerate(names[0])]
    handles.append(Line2D([], [], color="k", lw=2, label="revolute axis"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    path = Path(path)
    check_output_file(path, "figure", "figure.png")
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
    return path
