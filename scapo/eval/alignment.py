"""Canonical-frame alignment for self-supervised methods (SPEC section 8, step 2).

A self-supervised method chooses its own canonical frame (and rest articulation), so its part
poses differ from the ground truth by a fixed rigid offset per part: ``P_gt ~ P_pred @ O_p``.
As OP-Align does, ``O_p`` is estimated once per category and part from *training-split*
predictions, robustly (RANSAC over per-sample offsets, then the chordal mean of the inliers'
rotations and the median of their translations), and applied to test predictions. Joint states
get a per-joint sign (from the axis orientation) and offset the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from scapo.geometry import as_transform, invert_transform, project_to_so3


@dataclass(frozen=True)
class CanonicalAlignment:
    """Estimated offsets: ``part_offset (P, 4, 4)`` and joint ``state_offset (J,)``, inlier ratios."""

    part_offset: np.ndarray
    state_offset: np.ndarray
    inlier_ratio: np.ndarray

    def apply_poses(self, part_pose: np.ndarray) -> np.ndarray:
        """Aligned poses ``part_pose (M, P, 4, 4) @ part_offset`` (already matched to GT parts)."""
        return part_pose @ self.part_offset[None]

    def apply_states(self, state: np.ndarray, axis_sign: np.ndarray) -> np.ndarray:
        """Aligned joint states ``sign * state + offset`` for (M, J) inputs."""
        return axis_sign * state + self.state_offset[None]

    @staticmethod
    def identity(num_parts: int, num_joints: int) -> CanonicalAlignment:
        return CanonicalAlignment(np.tile(np.eye(4), (num_parts, 1, 1)), np.zeros(num_joints), np.ones(num_parts))


def robust_rotation_mean(R: np.ndarray, inlier_deg: float = 15.0, max_candidates: int = 200,
                         seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Robust average of rotations ``R (M, 3, 3)``.

    RANSAC: each of up to ``max_candidates`` sampled rotations is a hypothesis; the one with the
    most rotations within ``inlier_deg`` wins; the result is the chordal L2 mean
    (``scipy.spatial.transform.Rotation.mean``) of its inliers. Returns ``(R_mean (3,3), inliers (M,) bool)``.
    """
    R = project_to_so3(np.asarray(R, dtype=np.float64))
    M = len(R)
    if M == 0:
        raise ValueError("robust_rotation_mean needs at least one rotation")
    rng = np.random.default_rng(seed)
    cand = np.arange(M) if M <= max_candidates else rng.choice(M, max_candidates, replace=False)
    cos_thr = np.cos(np.radians(inlier_deg))
    # rotation angle between candidate c and every m: tr(Rc^T Rm) = 1 + 2 cos(theta)
    tr = np.einsum("cij,mij->cm", R[cand], R)
    inl = (tr - 1.0) / 2.0 >= cos_thr
    best = int(np.argmax(inl.sum(1)))
    inliers = inl[best]
    mean = Rotation.from_matrix(R[inliers]).mean().as_matrix()
    # refine once around the mean
    tr2 = np.einsum("ij,mij->m", mean, R)
    inliers = (tr2 - 1.0) / 2.0 >= cos_thr
    if inliers.any():
        mean = Rotation.from_matrix(R[inliers]).mean().as_matrix()
    return mean, inliers


def estimate_alignment(pred_pose: np.ndarray, gt_pose: np.ndarray, pred_axis: np.ndarray, gt_axis: np.ndarray,
                       pred_state: np.ndarray, gt_state: np.ndarray, inlier_deg: float = 15.0) -> CanonicalAlignment:
    """Estimate the per-part offsets and per-joint state offsets from training-split predictions.

    Args:
        pred_pose, gt_pose: (M, P, 4, 4) predicted poses (matched to GT parts) and GT part poses.
        pred_axis, gt_axis: (M, J, 3) joint axes (camera frame), predicted joints matched to GT.
        pred_state, gt_state: (M, J) joint states.

    Returns:
        :class:`CanonicalAlignment`.
    """
    M, P = pred_pose.shape[:2]
    offsets, ratios = [], []
    for p in range(P):
        O = invert_transform(pred_pose[:, p]) @ gt_pose[:, p]  # P_gt = P_pred @ O
        R, inl = robust_rotation_mean(O[:, :3, :3], inlier_deg)
        t = np.median(O[inl, :3, 3], axis=0) if inl.any() else np.median(O[:, :3, 3], axis=0)
        offsets.append(as_transform(R, t))
        ratios.append(inl.mean())
    sign = axis_sign(pred_axis, gt_axis)
    diff = gt_state - sign * pred_state
    state_offset = np.median(diff, axis=0) if M else np.zeros(pred_state.shape[1])
    return CanonicalAlignment(np.stack(offsets), state_offset, np.array(ratios))


def axis_sign(pred_axis: np.ndarray, gt_axis: np.ndarray) -> np.ndarray:
    """+1 / -1 per (sample, joint): whether the predicted axis points the same way as the GT axis.

    A state measured about a flipped axis has the opposite sign; the sign is thus derived from
    the axes, which both live in the camera frame.
    """
    return np.where(np.sum(pred_axis * gt_axis, -1) >= 0, 1.0, -1.0)
