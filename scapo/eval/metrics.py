"""Metric functions of SPEC section 8 (pure, numpy float64, vectorised over leading axes).

Angles are returned in degrees, distances in the unit of the inputs (callers divide by the
bounding-box diagonal or convert to cm). Each function is checked against a naive loop
reference in ``tests/test_metrics.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from scapo.ops.rigid import project_to_so3


@dataclass(frozen=True)
class MetricInfo:
    """How a metric is reported: column symbol, unit, and whether higher is better."""

    symbol: str
    description: str
    unit: str
    higher_is_better: bool
    decimals: int


#: Metrics of Table 1 (and the joint-state error the paper omits), keyed by column symbol.
TABLE1_METRICS: dict[str, MetricInfo] = {
    "S": MetricInfo("S", "part segmentation IoU", "%", True, 2),
    "D": MetricInfo("D", "joint direction error", "deg", False, 2),
    "C": MetricInfo("C", "joint pivot (axis line) error", "x bbox diag", False, 3),
    "R": MetricInfo("R", "part rotation error", "deg", False, 2),
    "t": MetricInfo("t", "part translation error", "x bbox diag", False, 3),
    "state_deg": MetricInfo("state_deg", "revolute joint state error", "deg", False, 2),
    "state_cm": MetricInfo("state_cm", "prismatic joint state error", "cm", False, 2),
}


def rotation_error_deg(R_pred: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Geodesic angle ``arccos((tr(R_gt R_pred^T) - 1) / 2)`` in degrees.

    Computed as ``atan2(sin, cos)`` of the relative rotation ``M = R_gt R_pred^T``, with
    ``cos = (tr M - 1) / 2`` and ``sin = |vee(M - M^T)| / 2``: the same angle, but accurate near 0
    and 180 degrees where arccos loses digits.

    Args:
        R_pred: (..., 3, 3) predicted rotations; first projected to SO(3) by SVD.
        R_gt: (..., 3, 3) ground-truth rotations.

    Returns:
        (...,) float64 in [0, 180].
    """
    R_pred = project_to_so3(np.asarray(R_pred, dtype=np.float64))
    R_gt = np.asarray(R_gt, dtype=np.float64)
    M = R_gt @ np.swapaxes(R_pred, -1, -2)
    cos = (np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    A = M - np.swapaxes(M, -1, -2)
    sin = np.sqrt(A[..., 2, 1] ** 2 + A[..., 0, 2] ** 2 + A[..., 1, 0] ** 2) / 2.0
    return np.degrees(np.arctan2(sin, cos))


def translation_error(t_pred: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """Euclidean distance ``||t_gt - t_pred||`` over the last axis (unit of the inputs)."""
    return np.linalg.norm(np.asarray(t_gt, dtype=np.float64) - np.asarray(t_pred, dtype=np.float64), axis=-1)


def axis_error_deg(d_pred: np.ndarray, d_gt: np.ndarray) -> np.ndarray:
    """Joint direction error ``arccos(|d_gt . d_pred|)`` in degrees, sign ignored, in [0, 90].

    Inputs (..., 3) need not be unit length; zero vectors give NaN.
    """
    a = np.asarray(d_pred, dtype=np.float64)
    b = np.asarray(d_gt, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs(np.sum(a * b, -1)) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))


def line_distance(p_pred: np.ndarray, d_pred: np.ndarray, p_gt: np.ndarray, d_gt: np.ndarray,
                  parallel_eps: float = 1e-6) -> np.ndarray:
    """Distance between the 3D lines ``p_pred + s d_pred`` and ``p_gt + s d_gt``.

    For skew lines this is ``|(p_pred - p_gt) . (d_pred x d_gt)| / |d_pred x d_gt|``; when the
    directions are parallel (``|d_pred x d_gt| < parallel_eps`` for unit directions) it is the
    distance from ``p_pred`` to the ground-truth line. Shapes (..., 3) -> (...,).
    """
    p1, p2 = np.asarray(p_pred, dtype=np.float64), np.asarray(p_gt, dtype=np.float64)
    d1 = np.asarray(d_pred, dtype=np.float64)
    d2 = np.asarray(d_gt, dtype=np.float64)
    d1 = d1 / np.linalg.norm(d1, axis=-1, keepdims=True)
    d2 = d2 / np.linalg.norm(d2, axis=-1, keepdims=True)
    w = p1 - p2
    n = np.cross(d1, d2)
    nn = np.linalg.norm(n, axis=-1)
    skew = np.abs(np.sum(w * n, -1)) / np.maximum(nn, parallel_eps)
    par = np.linalg.norm(np.cross(w, d2), axis=-1)
    return np.where(nn < parallel_eps, par, skew)


def segmentation_iou(pred_label: np.ndarray, gt_label: np.ndarray, num_parts: int,
                     ignore_background: bool = False) -> np.ndarray:
    """Point IoU of each ground-truth part, as a fraction in [0, 1].

    Args:
        pred_label: (N,) predicted part per point (already mapped to GT part indices; -1 = none).
        gt_label: (N,) ground-truth part per point (-1 = not object).
        num_parts: P.
        ignore_background: False: a point with GT -1 counts as a false positive of the part it is
            predicted as. True: such points are left out, as OP-Align scores its real scans
            (SPConvNets/models/art_metric.py ``evaluation_segmentation`` with ``noise_exist``, which
            SPConvNets/trainer_art.py ``_setup_metric`` sets for ``dataset_type == 'Real'``).

    Returns:
        (P,) float64; NaN for a part absent from both prediction and ground truth.
    """
    pred = np.asarray(pred_label)
    gt = np.asarray(gt_label)
    if ignore_background:
        obj = gt >= 0
        pred, gt = pred[obj], gt[obj]
    ious = np.full(num_parts, np.nan)
    for p in range(num_parts):
        a, b = pred == p, gt == p
        union = np.count_nonzero(a | b)
        if union:
            ious[p] = np.count_nonzero(a & b) / union
    return ious


def iou_matrix(pred_label: np.ndarray, gt_label: np.ndarray, num_slots: int, num_parts: int) -> np.ndarray:
    """(num_slots, num_parts) point IoU between every predicted slot and every GT part."""
    pred = np.asarray(pred_label)
    gt = np.asarray(gt_label)
    valid_p = (pred >= 0) & (pred < num_slots)
    valid_g = (gt >= 0) & (gt < num_parts)
    inter = np.zeros((num_slots, num_parts))
    np.add.at(inter, (pred[valid_p & valid_g], gt[valid_p & valid_g]), 1.0)
    size_p = np.bincount(pred[valid_p], minlength=num_slots)[:num_slots].astype(np.float64)
    size_g = np.bincount(gt[valid_g], minlength=num_parts)[:num_parts].astype(np.float64)
    union = size_p[:, None] + size_g[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def match_parts(pred_label: np.ndarray, gt_label: np.ndarray, num_parts: int,
                num_slots: int | None = None) -> np.ndarray:
    """Hungarian assignment of predicted part slots to GT parts, maximising the total point IoU.

    Args:
        pred_label: (N,) predicted slot per point (unordered slots of a self-supervised method).
        gt_label: (N,) GT part per point. num_parts: P. num_slots: number of predicted slots
            (default: P).

    Returns:
        (P,) int64: the slot matched to each GT part (-1 if there are fewer slots than parts).
    """
    S = num_parts if num_slots is None else num_slots
    M = iou_matrix(pred_label, gt_label, S, num_parts)
    rows, cols = linear_sum_assignment(-M)
    out = np.full(num_parts, -1, dtype=np.int64)
    out[cols] = rows
    return out


def relabel(pred_label: np.ndarray, slot_of_part: np.ndarray) -> np.ndarray:
    """Map predicted slots to GT part indices given ``slot_of_part`` from :func:`match_parts`."""
    pred = np.asarray(pred_label)
    lut = np.full(max(int(pred.max(initial=-1)), int(slot_of_part.max(initial=-1))) + 2, -1, dtype=np.int64)
    for p, s in enumerate(slot_of_part):
        if s >= 0:
            lut[s] = p
    return np.where(pred >= 0, lut[np.clip(pred, 0, len(lut) - 1)], -1)


def joint_state_error(state_pred: np.ndarray, state_gt: np.ndarray, joint_type: np.ndarray) -> np.ndarray:
    """|state error| in degrees for revolute joints (type 0) and in centimetres for prismatic (type 1)."""
    err = np.abs(np.asarray(state_pred, dtype=np.float64) - np.asarray(state_gt, dtype=np.float64))
    return np.where(np.asarray(joint_type) == 0, np.degrees(err), 100.0 * err)


def precision_under(err_a: np.ndarray, err_b: np.ndarray, thr_a: float, thr_b: float) -> float:
    """Fraction of samples whose two errors are both below their thresholds (NaN counts as a miss)."""
    a, b = np.asarray(err_a, dtype=np.float64), np.asarray(err_b, dtype=np.float64)
    if a.size == 0:
        return float("nan")
    ok = (a < thr_a) & (b < thr_b)
    return float(np.mean(ok))


#: Table 2 thresholds: (degrees, centimetres).
AP_THRESHOLDS = ((5.0, 5.0), (10.0, 10.0), (15.0, 15.0))
#: Table 2 segmentation thresholds (IoU fractions).
SEG_THRESHOLDS = (0.75, 0.50)


def point_line_distance(p_pred: np.ndarray, p_gt: np.ndarray, d_gt: np.ndarray) -> np.ndarray:
    """Distance from the point ``p_pred`` to the line ``p_gt + s d_gt`` (shapes (..., 3) -> (...,)).

    The pivot error of OP-Align's released evaluation (``Art_Metric.evaluation_joint`` in
    YC-Che/OP-Align SPConvNets/models/art_metric.py: the residual minus its component along the GT
    direction), applied there to every joint, prismatic ones included.
    """
    d = np.asarray(d_gt, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    w = np.asarray(p_pred, dtype=np.float64) - np.asarray(p_gt, dtype=np.float64)
    return np.linalg.norm(w - np.sum(w * d, -1, keepdims=True) * d, axis=-1)


def origin_offset_difference(origin: np.ndarray, p_pred: np.ndarray, d_pred: np.ndarray, p_gt: np.ndarray,
                             d_gt: np.ndarray) -> np.ndarray:
    """``| dist(origin, predicted axis line) - dist(origin, GT axis line) |`` (shapes (..., 3) -> (...,)).

    The pivot error of EAP's released evaluation (Meowuu7/equi-articulated-pose: ``part_pv_offset`` of
    SPConvNets/datasets/MotionDataset.py, the distance of the centred cloud's origin to the axis, compared
    by absolute difference in SPConvNets/trainer_unsup_arti_align.py); ``origin`` is the cloud's centroid.
    """
    o = np.asarray(origin, dtype=np.float64)
    return np.abs(point_line_distance(o, p_pred, d_pred) - point_line_distance(o, p_gt, d_gt))


def fold_rotation_error(theta_deg: np.ndarray) -> np.ndarray:
    """``min(theta, 180 - theta)`` in degrees: EAP's released evaluation folds part rotation errors so
    that a part turned by 180 degrees counts as exact (trainer_unsup_arti_align.py)."""
    t = np.asarray(theta_deg, dtype=np.float64)
    return np.minimum(t, 180.0 - t)


def symmetry_rotations(discrete=(), continuous=(), max_step_deg: float = 5.0) -> np.ndarray:
    """The rotations ``(K, 3, 3)`` of an object's symmetries (object frame), identity first, following the BOP
    toolkit (``misc.get_symmetry_transformations``): each continuous symmetry (a unit axis) is discretised into
    turns of at most ``max_step_deg``, and every discrete one (a ``(3, 3)`` rotation) is combined with each of
    them. A pose ``R`` (object -> camera) and ``R @ S`` are then indistinguishable for every ``S`` returned.

    Raises:
        ValueError: a discrete symmetry that is not a rotation, an axis of zero length, a step <= 0."""
    if not max_step_deg > 0:
        raise ValueError(f"max_step_deg must be > 0, got {max_step_deg}")
    disc = [np.eye(3)]
    for R in discrete:
        R = np.asarray(R, dtype=np.float64)[:3, :3]
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
            raise ValueError("a discrete symmetry must be a rotation matrix")
        disc.append(R)
    cont = [np.eye(3)]
    for axis in continuous:
        a = np.asarray(axis, dtype=np.float64)
        if not np.linalg.norm(a) > 1e-9:
            raise ValueError("a continuous symmetry needs a non-zero axis")
        n = int(np.ceil(360.0 / max_step_deg))
        cont = [C @ Rotation.from_rotvec(a / np.linalg.norm(a) * (2 * np.pi * k / n)).as_matrix()
                for C in cont for k in range(n)]
    out = [D @ C for D in disc for C in cont]
    return np.stack(out)


def symmetric_rotation_error_deg(R_pred: np.ndarray, R_gt: np.ndarray, symmetries: np.ndarray) -> np.ndarray:
    """The rotation error against the symmetric ground truth that fits best: ``min_k e(R_pred, R_gt S_k)`` over
    the object's symmetry rotations ``symmetries (K, 3, 3)`` (:func:`symmetry_rotations`, identity included), as
    the BOP toolkit scores symmetric objects (Hodan et al., ECCV 2020 workshop; ``pose_error.py``, errors
    minimised over ``syms``). ``R_pred, R_gt (..., 3, 3)`` -> ``(...,)`` degrees in [0, 180]; with only the
    identity it is :func:`rotation_error_deg`."""
    S = np.asarray(symmetries, dtype=np.float64)
    R_gt = np.asarray(R_gt, dtype=np.float64)
    errs = np.stack([rotation_error_deg(R_pred, R_gt @ S[k]) for k in range(len(S))], -1)
    return errs.min(-1)


def fixed_order_match(pred_label: np.ndarray, gt_label: np.ndarray, orders: tuple[tuple[int, ...], ...]
                      ) -> np.ndarray:
    """OP-Align's part matching: of the fixed slot ``orders`` (order[p] = slot of GT part p), the one
    with the highest point accuracy over the object points (``Art_Metric.standardization_order``).

    Returns:
        (P,) int64 slot of each GT part (the first order on ties).
    """
    pred = np.asarray(pred_label)
    gt = np.asarray(gt_label)
    obj = gt >= 0
    best, best_acc = None, -1.0
    for o in orders:
        o = np.asarray(o)
        acc = float(np.mean(pred[obj] == o[gt[obj]])) if obj.any() else 0.0
        if acc > best_acc:
            best, best_acc = o, acc
    return best.astype(np.int64)


def mean_centroid_distance(points: np.ndarray, labels: np.ndarray | None = None) -> np.ndarray:
    """Mean distance of each cloud's points to their centroid, ``points (M, N, 3) -> (M,)`` (object
    points only when ``labels (M, N)`` are given): the scale OP-Align normalises every cloud to 0.25
    (SPConvNets/datasets/LightDataset.py)."""
    pts = np.asarray(points, dtype=np.float64)
    w = np.ones(pts.shape[:2]) if labels is None else (np.asarray(labels) >= 0).astype(np.float64)
    n = np.maximum(w.sum(1, keepdims=True), 1.0)
    c = (pts * w[..., None]).sum(1, keepdims=True) / n[..., None]
    return (np.linalg.norm(pts - c, axis=-1) * w).sum(1) / n[:, 0]
