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

from scapo.ops.rigid import as_transform, invert_transform, project_to_so3


@dataclass(frozen=True)
class CanonicalAlignment:
    """Estimated offsets: ``part_offset (P, 4, 4)`` (translation in the protocol's units: metres, or a
    per-sample unit given to :meth:`apply_poses`), joint ``state_offset (J,)``, inlier ratios (P,)."""

    part_offset: np.ndarray
    state_offset: np.ndarray
    inlier_ratio: np.ndarray

    def apply_poses(self, part_pose: np.ndarray, unit: np.ndarray | None = None) -> np.ndarray:
        """Aligned poses ``part_pose (M, P, 4, 4) @ part_offset`` (already matched to GT parts); with
        ``unit (M,)`` (metres per unit of each sample) the offsets' translations are scaled by it."""
        if unit is None:
            return part_pose @ self.part_offset[None]
        O = np.repeat(self.part_offset[None], len(part_pose), axis=0)
        O[..., :3, 3] *= np.asarray(unit, dtype=np.float64)[:, None, None]
        return part_pose @ O

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


def ransac_sample_means(R: np.ndarray, t: np.ndarray, iterations: int = 100, sample: int = 5,
                        inlier_deg: float = 10.0, inlier_t: float = 0.25, seed: int = 0
                        ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """OP-Align's canonical-frame estimator (``Art_Metric.standardization_ransac`` in YC-Che/OP-Align
    SPConvNets/models/art_metric.py): each iteration averages ``sample`` random training samples'
    offsets (per part: chordal mean of rotations, mean of translations); the rotation means and the
    translation means with the most inliers over all parts (within ``inlier_deg``, resp. ``inlier_t``)
    win, separately.

    Args:
        R: (M, P, 3, 3) per-sample offset rotations. t: (M, P, 3) offset translations (any unit).

    Returns:
        (R_mean (P, 3, 3), t_mean (P, 3), rotation inlier ratio, translation inlier ratio).
    """
    R = project_to_so3(np.asarray(R, dtype=np.float64))
    t = np.asarray(t, dtype=np.float64)
    M, P = R.shape[:2]
    rng = np.random.default_rng(seed)
    k = min(sample, M)
    cos_thr = np.cos(np.radians(inlier_deg))
    best_r, best_t = (-1, None), (-1, None)
    for _ in range(iterations):
        idx = rng.choice(M, size=k, replace=False)
        Rm = np.stack([Rotation.from_matrix(R[idx, p]).mean().as_matrix() for p in range(P)])
        tm = t[idx].mean(0)
        n_r = int((((np.einsum("pij,mpij->mp", Rm, R) - 1.0) / 2.0) >= cos_thr).sum())
        n_t = int((np.linalg.norm(t - tm[None], axis=-1) <= inlier_t).sum())
        if n_r > best_r[0]:
            best_r = (n_r, Rm)
        if n_t > best_t[0]:
            best_t = (n_t, tm)
    return best_r[1], best_t[1], best_r[0] / (M * P), best_t[0] / (M * P)


def estimate_alignment(pred_pose: np.ndarray, gt_pose: np.ndarray, pred_axis: np.ndarray, gt_axis: np.ndarray,
                       pred_state: np.ndarray, gt_state: np.ndarray, inlier_deg: float = 15.0,
                       method: str = "ransac-offsets", unit: np.ndarray | None = None,
                       inlier_t: float = 0.25) -> CanonicalAlignment:
    """Estimate the per-part offsets and per-joint state offsets from training-split predictions.

    Args:
        pred_pose, gt_pose: (M, P, 4, 4) predicted poses (matched to GT parts) and GT part poses.
        pred_axis, gt_axis: (M, J, 3) joint axes (camera frame), predicted joints matched to GT.
        pred_state, gt_state: (M, J) joint states.
        method: "ransac-offsets" (default: RANSAC over per-sample rotation offsets within
            ``inlier_deg``, chordal mean of the inliers, median translation of the inliers) or
            "ransac-sample-means" (:func:`ransac_sample_means`, OP-Align's).
        unit: (M,) metres per unit of each sample; offsets' translations are estimated in these units
            (default: metres).

    Returns:
        :class:`CanonicalAlignment` (translations in ``unit``).
    """
    M, P = pred_pose.shape[:2]
    O = invert_transform(pred_pose) @ gt_pose  # P_gt = P_pred @ O, (M, P, 4, 4)
    t_units = O[..., :3, 3] / (1.0 if unit is None else np.asarray(unit, dtype=np.float64)[:, None, None])
    if method == "ransac-sample-means":
        Rm, tm, r_ratio, _ = ransac_sample_means(O[..., :3, :3], t_units, inlier_deg=inlier_deg, inlier_t=inlier_t)
        offsets = np.stack([as_transform(Rm[p], tm[p]) for p in range(P)])
        ratios = np.full(P, r_ratio)
    else:
        offsets, ratios = [], []
        for p in range(P):
            R, inl = robust_rotation_mean(O[:, p, :3, :3], inlier_deg)
            t = np.median(t_units[inl, p], axis=0) if inl.any() else np.median(t_units[:, p], axis=0)
            offsets.append(as_transform(R, t))
            ratios.append(inl.mean())
        offsets = np.stack(offsets)
    sign = axis_sign(pred_axis, gt_axis)
    diff = gt_state - sign * pred_state
    state_offset = np.median(diff, axis=0) if M else np.zeros(pred_state.shape[1])
    return CanonicalAlignment(offsets, state_offset, np.asarray(ratios, dtype=np.float64))


def axis_sign(pred_axis: np.ndarray, gt_axis: np.ndarray) -> np.ndarray:
    """+1 / -1 per (sample, joint): whether the predicted axis points the same way as the GT axis.

    A state measured about a flipped axis has the opposite sign; the sign is thus derived from
    the axes, which both live in the camera frame.
    """
    return np.where(np.sum(pred_axis * gt_axis, -1) >= 0, 1.0, -1.0)
