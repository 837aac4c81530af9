"""Revolute axes from the sweep of a child part's direction over views in its parent's frame (numpy; an addition to
the paper).

A revolute child turns about one axis fixed in its parent's frame. Any direction the child carries that is normal to
that axis (an eyeglasses temple's length, a laptop lid's normal) therefore stays in the plane normal to it as the joint
moves, while a direction along the axis stays put. Over the views of a category, in a frame that is one frame across
them, the child's principal direction of largest variance thus sweeps a great circle whose normal is the axis, or
stays on the axis. Used by the prediction step ``axis_sweep`` (:mod:`scapo.steps.sweep`) and by the training switch
``TrainConfig.axis_init = "sweep"`` (:mod:`scapo.models.train`). Measured in ``docs/canonical_ladder.md``,
"The base's plane and the hinge axes from the sweep".
"""

from __future__ import annotations

import numpy as np

from scapo.ops.signed_axes import principal_axes

MIN_POINTS = 20
"""Fewest points a view's child part needs for its direction to be collected."""

MIN_VIEWS = 8
"""Fewest training views a joint needs for its axis to be read; fewer keep the method's own axes."""

STILL_SHARE = 0.9
"""Where the largest eigenvalue of the collected directions' second moment holds more than this share, the child's
direction did not sweep (it lies along the axis) and the axis is that direction."""


def child_directions(points: np.ndarray, part_label: np.ndarray, T_cam_obj: np.ndarray, child: int,
                     min_points: int = MIN_POINTS) -> np.ndarray:
    """Per view the child part's principal direction of largest variance in the base frame.

    Args:
        points: ``(V, N, 3)`` clouds (metres; camera frame, or any frame ``T_cam_obj`` maps the base frame to).
        part_label: ``(V, N)`` int parts. T_cam_obj: ``(V, 4, 4)`` (or ``(V, 3, 3)``) the base poses (object ->
        camera; only the rotation is read). child: the child's part slot. min_points: fewest points of the child a
        view needs.

    Returns:
        ``(V', 3)`` float64 unit directions (object frame, sign arbitrary) of the ``V'`` views with enough points.
    """
    out = []
    for x, lab, T in zip(np.asarray(points, dtype=np.float64), np.asarray(part_label), np.asarray(T_cam_obj)):
        q = x[lab == int(child)]
        if len(q) < max(int(min_points), 3):
            continue
        out.append(np.asarray(T, dtype=np.float64)[:3, :3].T @ principal_axes(q)[1][:, 0])
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def sweep_axis(directions: np.ndarray) -> tuple[np.ndarray, dict]:
    """The axis ``(3,)`` (unit, object frame) that the directions ``(V, 3)`` sweep about: the eigenvector of least
    eigenvalue of ``sum u u^T / V``, or the one of largest where that eigenvalue exceeds :data:`STILL_SHARE` (the
    directions lie along the axis); and ``{"views", "eigenvalues" (ascending, shares), "mode": "sweep"|"still"}``.

    Raises:
        ValueError: fewer than 2 directions, or not ``(V, 3)`` finite."""
    u = np.asarray(directions, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != 3 or len(u) < 2 or not np.isfinite(u).all():
        raise ValueError(f"sweep_axis needs at least 2 finite directions (V, 3), got {u.shape}")
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    w, v = np.linalg.eigh(u.T @ u / len(u))
    still = bool(w[2] > STILL_SHARE)
    axis = v[:, 2] if still else v[:, 0]
    return axis, {"views": int(len(u)), "eigenvalues": [round(float(x), 4) for x in w],
                  "mode": "still" if still else "sweep"}


