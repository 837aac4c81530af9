"""The frame-consistency measure: does a method predict one canonical object frame across views?

One definition for every table, ladder and diagnosis (:func:`frame_consistency`, :func:`frame_inliers`): the share
of samples whose object-frame rotation offset ``R_pred^T R_gt`` lies within :data:`CONSISTENCY_DEG` of the one offset
most of them share. It is scored on the object frame in the dataset's convention, ``T_cam_obj`` = the base part's
pose (``docs/usage.md``), for every method, on the split a table reports; :func:`scapo.eval.evaluate` adds it to
every result's summary (``frame_consistency``, strict; ``frame_consistency_sym``, against the category's declared
symmetric ground truths too, :func:`scapo.eval.evaluator.object_frame_twins`) and a per-sample ``frame_inlier``
column. The evaluator's training-split alignment inlier ratio (``info["alignment_inlier_ratio"]``, per part, of
the methods that need a canonical-frame alignment) is another quantity and keeps its own label.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Inlier threshold of :func:`frame_consistency`, degrees (the evaluator's alignment uses the same).
CONSISTENCY_DEG = 15.0
#: Version of the cells' frame consistency: 2 takes a symmetric category's twin object frame from the twin ground
#: truth (:func:`scapo.eval.evaluator.object_frame_twins`; the laptop's follows the lid's state); 1 (records without
#: the field) turned the base's frame by the symmetry's rest-state rotation. :func:`_upgrade` rescores version-1
#: records of symmetric categories from their predictions (:func:`scapo.bench.ladder._upgrade`).
CONSISTENCY_VERSION = 2
#: Most offsets :func:`frame_consistency` tries as the common frame (a sample draw beyond it). Every offset of the
#: tables' splits (at most 240 samples, two ground truths each) is tried, so the symmetry-aware share is never below
#: the strict one; it was 400 before ``CONSISTENCY_VERSION`` 2.
MAX_HYPOTHESES = 1000


def frame_consistency(pred_T: np.ndarray, gt_T: np.ndarray, inlier_deg: float = CONSISTENCY_DEG) -> float:
    """Share of samples whose object-frame rotation offset agrees with the one frame most of them agree on: the mean of
    :func:`frame_inliers` (same arguments and errors; NaN for no samples)."""
    inl = frame_inliers(pred_T, gt_T, inlier_deg)[0]
    return float(inl.mean()) if len(inl) else float("nan")


def frame_inliers(pred_T: np.ndarray, gt_T: np.ndarray, inlier_deg: float = CONSISTENCY_DEG
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Which samples' object-frame rotation offsets agree with the one frame most of them agree on.

    For each sample the offset ``O = R_pred^T R_gt`` maps the ground-truth object frame into the method's canonical
    frame; a method with one canonical frame has one offset for every sample (1.0), a method whose frame depends on
    the shape, view or sampling scatters them. Every offset is a hypothesis (at most :data:`MAX_HYPOTHESES` of them,
    drawn with a fixed seed); the share is the largest fraction of samples within ``inlier_deg`` degrees of one
    hypothesis (the hypothesis step of :func:`scapo.eval.alignment.robust_rotation_mean`, which cannot take several
    symmetric offsets per sample). A supervised method predicts in the ground-truth frame: its share is that of
    samples within ``inlier_deg`` of one common offset, near the identity.

    Args:
        pred_T: ``(M, 4, 4)`` float64 predicted ``T_cam_obj``.
        gt_T: ``(M, 4, 4)`` ground-truth ``T_cam_obj`` of the same samples (the strict share), or ``(M, K, 4, 4)``:
            each sample's K valid ground truths, its own first, then its twins under the category's declared
            symmetries (:func:`scapo.eval.evaluator.object_frame_twins`); a sample then agrees when any of them does
            (the symmetry-aware share).

    Returns:
        ``(inlier (M,) bool, angle (M, K) float64)``: the samples within ``inlier_deg`` of the common frame, and each
        ground truth's angle (deg) to it (empty arrays for no samples).

    Raises:
        ValueError: arrays that are not ``(M, 4, 4)`` and ``(M, 4, 4)`` or ``(M, K, 4, 4)`` of one ``M``.
    """
    from scapo.ops.rigid import project_to_so3

    pred_T, gt_T = np.asarray(pred_T, dtype=np.float64), np.asarray(gt_T, dtype=np.float64)
    if gt_T.ndim == 3:
        gt_T = gt_T[:, None]
    if (pred_T.ndim != 3 or pred_T.shape[1:] != (4, 4) or gt_T.ndim != 4 or gt_T.shape[2:] != (4, 4)
            or len(gt_T) != len(pred_T)):
        raise ValueError(f"frame_consistency needs (M, 4, 4) predictions and (M, 4, 4) or (M, K, 4, 4) ground truth, "
                         f"got {pred_T.shape} and {gt_T.shape}")
    M, K = gt_T.shape[:2]
    if M == 0:
        return np.zeros(0, dtype=bool), np.zeros((0, K))
    O = project_to_so3(np.einsum("mji,mkjl->mkil", pred_T[:, :3, :3], gt_T[:, :, :3, :3]).reshape(-1, 3, 3))
    O = O.reshape(M, K, 3, 3)
    hyp = O.reshape(-1, 3, 3)
    if len(hyp) > MAX_HYPOTHESES:
        hyp = hyp[np.random.default_rng(0).choice(len(hyp), MAX_HYPOTHESES, replace=False)]
    cos_thr = np.cos(np.radians(inlier_deg))
    tr = np.einsum("hij,msij->hms", hyp, O)  # tr(H^T O) = 1 + 2 cos(angle)
    inl = ((tr - 1.0) / 2.0 >= cos_thr - 1e-12).any(-1)  # (H, M)
    best = int(inl.sum(1).argmax())
    return inl[best], np.degrees(np.arccos(np.clip((tr[best] - 1.0) / 2.0, -1.0, 1.0)))



def split_consistency(data: str | Path, preds, split: str = "val") -> tuple[float, float]:
    """:func:`frame_consistency` of predictions ``preds`` (:class:`~scapo.eval.Predictions`) on one split of the
    dataset ``data``: strict and symmetry-aware (the declared symmetries of its card), as :func:`scapo.eval.evaluate`
    puts them in its summary; for diagnoses that score predictions without the evaluator.

    Raises:
        PredictionError: the predictions name samples the split lacks.
    """
    from scapo.data import load
    from scapo.errors import PredictionError
    from scapo.eval.evaluator import object_frame_twins

    d = load(data, split)
    gt = object_frame_twins(d)
    keys = {k: i for i, k in enumerate(d.keys())}
    rows = [i for i in range(len(preds)) if str(preds.split[i]) == split]
    try:
        order = np.array([keys[(int(preds.instance_id[i]), int(preds.view_id[i]))] for i in rows], dtype=np.int64)
    except KeyError as e:
        raise PredictionError(f"predictions of {preds.method!r} name sample {e.args[0]}, which the {split} split of "
                              f"{data} lacks") from None
    strict = frame_consistency(preds.T_cam_obj[rows], gt[order, 0])
    return strict, (frame_consistency(preds.T_cam_obj[rows], gt[order]) if gt.shape[1] > 1 else strict)
