"""Preview figures of rendered samples: parts coloured, joint axes drawn (matplotlib)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scapo.files import atomic_savefig, check_output_file, output_mark
from scapo.ops.rigid import closest_point_on_line

PART_COLORS = np.array([
    [0.12, 0.47, 0.71], [0.89, 0.10, 0.11], [0.20, 0.63, 0.17], [1.00, 0.50, 0.00],
    [0.42, 0.24, 0.60], [0.65, 0.34, 0.16], [0.97, 0.51, 0.75], [0.09, 0.75, 0.81],
])
BACKGROUND = np.array([0.93, 0.93, 0.93])
OTHER = np.array([0.70, 0.70, 0.70])


def palette(n: int) -> np.ndarray:
    """(n, 3) RGB colours of parts 0..n-1, all distinct: :data:`PART_COLORS` first, then hues spaced by the
    golden ratio (saturated, mid brightness, so none is mistaken for the grey of background points)."""
    import colorsys

    extra = [colorsys.hsv_to_rgb((0.11 + 0.618034 * k) % 1.0, 0.75, 0.8 if k % 2 else 0.6)
             for k in range(max(0, n - len(PART_COLORS)))]
    return np.concatenate([PART_COLORS[:n], np.array(extra).reshape(-1, 3)])


def part_legend(names) -> list[str]:
    """Legend labels of parts: their names, prefixed by the part index when a name repeats (``1 drawer``,
    ``2 drawer``)."""
    names = [str(n) for n in names]
    repeated = {n for n in names if names.count(n) > 1}
    return [f"{i} {n}" if n in repeated else n for i, n in enumerate(names)]


def part_colors(labels: np.ndarray) -> np.ndarray:
    """RGB (..., 3) for part labels (-1: grey), distinct for any number of parts (:func:`palette`)."""
    labels = np.asarray(labels)
    pal = palette(int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 1)
    return np.where(labels[..., None] >= 0, pal[np.maximum(labels, 0)], OTHER)


def _project(K: np.ndarray, p: np.ndarray) -> np.ndarray:
    uvw = p @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def axis_anchor(joint_type: int, axis: np.ndarray, pivot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Where a joint axis is drawn (camera frame, m): a revolute axis through its pivot; a prismatic one
    through the point of its line (``pivot`` + s ``axis``, the pivot locating the slide, see
    :class:`~scapo.sim.assets.urdf.GTJoint`) closest to the centroid of ``points (N, 3)``, so that two
    drawers of one cabinet are drawn on their own lines, next to the object."""
    if int(joint_type) == 0 or len(points) == 0:
        return np.asarray(pivot, dtype=np.float64)
    return closest_point_on_line(pivot, axis, np.asarray(points, dtype=np.float64).mean(0))


def draw_sample(fig, sample: dict, title: str = "", column: int = 0, columns: int = 1, part_names=None,
                show_cloud: bool = True) -> None:
    """Draw one sample into ``fig``: the labelled depth image (if present) and the 3D cloud.

    Joint axes are drawn as lines along the axis (length 0.6 bbox_diag) at :func:`axis_anchor`,
    revolute in black, prismatic in magenta.
    """
    pts, lab = np.asarray(sample["points"]), np.asarray(sample["part_label"])
    diag = float(sample["bbox_diag"])
    segs = []
    for t, a, c in zip(sample["joint_type"], sample["joint_axis"], sample["joint_pivot"]):
        c = axis_anchor(t, a, c, pts[lab >= 0])
        segs.append((t, np.stack([c - 0.3 * diag * a, c + 0.3 * diag * a])))
    rows = 2 if "image_part_map" in sample else 1
    if rows == 2:
        ax = fig.add_subplot(rows, columns, column + 1)
        img = np.asarray(sample["image_part_map"])
        rgb = np.where(img[..., None] == -2, BACKGROUND, part_colors(img))
        ax.imshow(rgb)
        K = np.asarray(sample["K"])
        for t, s in segs:
            if np.all(s[:, 2] > 1e-3):
                uv = _project(K, s)
                ax.plot(uv[:, 0], uv[:, 1], "-", color="k" if t == 0 else "m", lw=2)
                ax.plot(*uv.mean(0), "o", color="k" if t == 0 else "m", ms=4)
        ax.set_xlim(0, img.shape[1])
        ax.set_ylim(img.shape[0], 0)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    if not show_cloud:
        return
    ax = fig.add_subplot(rows, columns, (rows - 1) * columns + column + 1, projection="3d")
    # show camera-frame points with "up" = -y so the picture matches the image
    ax.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], c=part_colors(lab), s=1.5, depthshade=False)
    for t, s in segs:
        ax.plot(s[:, 0], s[:, 2], -s[:, 1], "-", color="k" if t == 0 else "m", lw=2)
    frame_cloud_axes(ax, pts, diag)
    if rows == 1:
        ax.set_title(title, fontsize=9)
    if part_names is not None:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], marker="o", ls="", color=c, label=n)
                   for c, n in zip(palette(len(part_names)), part_legend(part_names))]
        ax.legend(handles=handles, fontsize=7, loc="upper left")


def save_preview(samples: Sequence[dict], path: str | Path, titles: Sequence[str] | None = None,
                 part_names: Sequence[Sequence[str]] | None = None) -> Path:
    """Write a PNG with one column per sample; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(samples)
    rows = 2 if any("image_part_map" in s for s in samples) else 1
    fig = plt.figure(figsize=(3.2 * n, 3.2 * rows))
    for i, s in enumerate(samples):
        draw_sample(fig, s, titles[i] if titles else "", column=i, columns=n,
                    part_names=part_names[i] if part_names else None)
    fig.tight_layout()
    path = Path(path)
    check_output_file(path, "figure", "preview.png")
    mark = {"metadata": output_mark("scapo preview")} if Path(path).suffix.lower() == ".png" else {}
    atomic_savefig(fig, path, dpi=110, **mark)  # marked as a preview: a rerun may replace it, nothing else
    plt.close(fig)
    return path


def frame_cloud_axes(ax, pts: np.ndarray, diag: float) -> None:
    """Fit a matplotlib 3-D ``ax`` to camera-frame points ``pts (N, 3)`` plotted as (x, z, -y): a cube
    of side ``diag`` (m) around their mean, seen from the camera side, without ticks."""
    mid, r = pts.mean(0), 0.5 * float(diag)
    ax.set_xlim(mid[0] - r, mid[0] + r)
    ax.set_ylim(mid[2] - r, mid[2] + r)
    ax.set_zlim(-mid[1] - r, -mid[1] + r)
    ax.view_init(elev=10, azim=-90)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])
