"""Revolute axes from the sweep of each child part over the training views (``axis_sweep``; an addition to the paper,
issue 52, offered to every trained method).

A revolute child turns about one axis fixed in its parent's frame. Any direction the child carries that is normal to
that axis (an eyeglasses temple's length, a laptop lid's normal) therefore stays in the plane normal to it as the joint
moves, while a direction along the axis (the lid's width) stays put. Over the training views of a category, in the
frame of the method's own base pose (``T_cam_obj``), the child's principal direction of largest variance (of the points
the method labels as the child) thus sweeps a great circle whose normal is the axis, or stays on the axis. This
module reads the axis as the direction that the collected directions' second moment ``sum u u^T`` spreads least along
(the sweep) and, where the directions instead stay put (the largest eigenvalue holds more than
:data:`STILL_SHARE` of the moment), as that direction. Each view's axis is then that canonical direction turned by
the view's base rotation, signed as the method's own axis.

What it needs from the method: a base pose that is one frame across views (frame consistency) and a segmentation
that gives the child's points; nothing else is read (no ground truth, no labels). Measured in
``results/canonical_ladder/README.md``, "The hinge axes from the sweep" (session 33).
"""

from __future__ import annotations

import numpy as np

from scapo.errors import TrainingError
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
        points: ``(V, N, 3)`` camera-frame clouds (metres). part_label: ``(V, N)`` int predicted parts.
        T_cam_obj: ``(V, 4, 4)`` the method's base poses (object -> camera). child: the child's part slot.
        min_points: fewest points of the child a view needs.

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


class SweepAxes:
    """``axis_sweep``: canonical revolute axes fitted on the training split's predictions (:meth:`fit`), applied to a
    prediction's joints (:meth:`__call__`). Prismatic joints and joints with fewer than :data:`MIN_VIEWS` usable
    training views keep the method's own axes."""

    def __init__(self, joint_types, joint_parts):
        self.joint_types = [int(t) for t in joint_types]
        self.joint_parts = [tuple(int(k) for k in p) for p in np.asarray(joint_parts).reshape(-1, 2)]
        self.axes: list[np.ndarray | None] | None = None
        self.found: list[dict] = []

    def fit(self, points: np.ndarray, out: dict) -> SweepAxes:
        """Read each revolute joint's canonical axis from training clouds ``points (V, N, 3)`` and the method's
        predictions of them ``out`` (``part_label (V, N)``, ``T_cam_obj (V, 4, 4)``); returns self."""
        self.axes, self.found = [], []
        for t, (_, child) in zip(self.joint_types, self.joint_parts):
            u = child_directions(points, out["part_label"], out["T_cam_obj"], child) if t == 0 else np.zeros((0, 3))
            if len(u) < MIN_VIEWS:
                self.axes.append(None)
                self.found.append({"views": int(len(u)), "mode": "kept"})
                continue
            axis, info = sweep_axis(u)
            self.axes.append(axis)
            self.found.append({**info, "axis": [round(float(x), 4) for x in axis]})
        return self

    def __call__(self, out: dict) -> dict:
        """A copy of the prediction ``out`` whose revolute ``joint_axis (B, J, 3)`` are the fitted canonical axes
        turned by each view's base rotation (``T_cam_obj``), signed as the method's own.

        Raises:
            TrainingError: not fitted on a training split."""
        if self.axes is None:
            raise TrainingError("axis_sweep needs its axes fitted on the training split first: fit(train)")
        o = dict(out)
        axis = np.array(out["joint_axis"], dtype=np.float64, copy=True)
        R = np.asarray(out["T_cam_obj"], dtype=np.float64)[:, :3, :3]
        for j, a in enumerate(self.axes):
            if a is None:
                continue
            new = R @ a
            sign = np.sign((new * axis[:, j]).sum(-1))
            axis[:, j] = new * np.where(sign == 0, 1.0, sign)[:, None]
        o["joint_axis"] = axis.astype(np.asarray(out["joint_axis"]).dtype)
        return o

    def info(self) -> list[dict]:
        """Per joint what :meth:`fit` found (views used, eigenvalue shares, mode, axis), for the predictions' info."""
        return list(self.found)
