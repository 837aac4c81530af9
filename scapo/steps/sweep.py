"""Revolute axes from the sweep of each child part over the training views (``axis_sweep``; an addition to the paper,
offered to every trained method).

Over the training views, in the frame of the method's own base pose (``T_cam_obj``), the principal direction of the
points the method labels as a revolute joint's child sweeps about the joint's axis (:mod:`scapo.ops.sweep`: the
direction the collected directions' second moment spreads least along, or the one they stay on). Each view's axis
is then that canonical direction turned by the view's base rotation, signed as the method's own axis.

What it needs from the method: a base pose that is one frame across views (frame consistency) and a segmentation
that gives the child's points; nothing else is read (no ground truth, no labels). Measured in
``docs/canonical_ladder.md``, "The base's plane and the hinge axes from the sweep".
"""

from __future__ import annotations

import numpy as np

from scapo.errors import TrainingError
from scapo.ops.sweep import MIN_VIEWS, child_directions, sweep_axis


class SweepAxes:
    """``axis_sweep``: canonical revolute axes fitted on the training split's predictions (:meth:`fit`), applied to a
    prediction's joints (:meth:`__call__`). Prismatic joints and joints with fewer than
    :data:`scapo.ops.sweep.MIN_VIEWS` usable training views keep the method's own axes."""

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
