"""The evaluator: one scoring path for every method (SPEC section 8), under a named protocol.

Steps, each as the protocol (:mod:`scapo.eval.protocols`) says: (1) match predicted part slots to
GT parts (Hungarian on point IoU per sample or per category, or OP-Align's fixed orders); joints
follow their parts; (2) for methods whose canonical frame is arbitrary, estimate per-part offsets
from training-split predictions and apply them to the evaluated split (:mod:`scapo.eval.alignment`);
(3) compute the metrics of :mod:`scapo.eval.metrics` per sample in float64; the summary holds their
means and the robust statistics beside them (medians, rates under 5 / 10 deg and over 90 deg).

Unmatched joints (a predicted joint connecting other slots than the GT joint's parts) count as
failures: D = 90 deg and C = 1 bbox diagonal; their state error is left out.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scapo.data.dataset import ArticulationDataset, load
from scapo.errors import DatasetError, PredictionError, warn_few_instances
from scapo.eval.alignment import CanonicalAlignment, axis_sign, estimate_alignment
from scapo.eval.frames import frame_inliers
from scapo.eval.metrics import (
    AP_THRESHOLDS,
    SEG_THRESHOLDS,
    axis_error_deg,
    precision_under,
    relabel,
    segmentation_iou,
    translation_error,
)
from scapo.eval.predictions import Predictions
from scapo.eval.protocols import PROTOCOLS, PivotCase, Protocol, get_protocol

__all__ = ["PROTOCOLS", "EvalResult", "evaluate", "robust_summary"]


@dataclass
class EvalResult:
    """Scores of one method on one dataset split.

    Attributes:
        method, category, split: identity. per_sample: one row per sample with the metrics
        (and per-part / per-joint columns). summary: metric name -> mean over samples (S in %,
        D/R/state_deg in degrees, C/t in bbox diagonals, state_cm in cm, ``ap_*`` in %).
        alignment: offsets applied to the predictions (None when not needed). info: provenance.
    """

    method: str
    category: str
    split: str
    per_sample: pd.DataFrame
    summary: dict
    alignment: CanonicalAlignment | None = None
    info: dict = field(default_factory=dict)


def _rows_for(preds: Predictions, ds: ArticulationDataset, split: str) -> np.ndarray:
    """Index into ``preds`` of every sample of ``ds`` (raises if any is missing)."""
    index = {(int(i), int(v), str(s)): k for k, (i, v, s) in enumerate(zip(preds.instance_id, preds.view_id,
                                                                          preds.split))}
    keys = ds.keys()
    rows = np.array([index.get((i, v, split), -1) for i, v in keys], dtype=np.int64)
    if (rows < 0).any():
        miss = [keys[k] for k in np.flatnonzero(rows < 0)[:3]]
        raise PredictionError(f"predictions of {preds.method!r} miss {int((rows < 0).sum())} of {len(rows)} "
                              f"{split} samples of {ds.root} (e.g. instance/view {miss})")
    return rows


def _match(preds: Predictions, rows: np.ndarray, gt_label: np.ndarray, P: int, proto: Protocol) -> np.ndarray:
    """(M, P) slot of each GT part per sample, by the protocol's matching rule."""
    return proto.match(preds.part_label[rows], gt_label, P, preds.part_pose.shape[1])


#: Ground-truth fields that differ between the two valid ground truths of a symmetric category's view.
TWIN_FIELDS = ("part_label", "npcs", "part_pose", "T_cam_obj", "joint_axis", "joint_pivot", "joint_state",
               "joint_limit", "bbox_diag")


def _symmetry(ds: ArticulationDataset, proto: Protocol):
    """The dataset's symmetry when the protocol scores twins (``Protocol.symmetric_gt``), else None."""
    if not proto.symmetric_gt or not ds.card.get("symmetry"):
        return None
    from scapo.sim.assets.symmetry import Symmetry

    sym = Symmetry.from_dict(ds.card["symmetry"])
    return sym if list(sym.parts) != list(range(len(sym.parts))) else None


def _use_twins(gt: dict, slots: np.ndarray, sym) -> tuple[dict, np.ndarray, np.ndarray]:
    """OP-Align's standardisation (art_metric.py ``standardization_order``): the samples matched in the symmetry's
    part order are scored against their twin ground truth, in the identity order. Returns the ground truth with
    those rows replaced, the slots, and the (M,) bool rows replaced."""
    from scapo.sim.assets.symmetry import twin

    swapped = (slots == np.asarray(sym.parts)[None]).all(1)
    if not swapped.any():
        return gt, slots, swapped
    gt = dict(gt)
    tw = twin({k: gt[k][swapped] for k in TWIN_FIELDS if k in gt}, sym)
    for k in tw:
        if k in TWIN_FIELDS and k in gt:
            gt[k] = gt[k].copy()
            gt[k][swapped] = tw[k]
    slots = slots.copy()
    slots[swapped] = np.arange(slots.shape[1])
    return gt, slots, swapped


def _gather(preds: Predictions, rows: np.ndarray, slots: np.ndarray, gt_joint_parts: np.ndarray):
    """Predicted poses per GT part and predicted joints per GT joint (with a matched flag).

    A predicted joint matches a GT joint when it links the same two parts, in either order; when its
    parent is the GT child, its state is negated (the motion of the parent relative to the child).
    """
    M, P = slots.shape
    J = gt_joint_parts.shape[0]
    pose = np.tile(np.eye(4), (M, P, 1, 1))
    ok = slots >= 0
    pose[ok] = preds.part_pose[np.repeat(rows, P).reshape(M, P)[ok], slots[ok]]
    axis = np.zeros((M, J, 3))
    pivot = np.zeros((M, J, 3))
    state = np.zeros((M, J))
    matched = np.zeros((M, J), dtype=bool)
    for m, r in enumerate(rows):
        pj = preds.joint_parts[r]
        for j, (a, b) in enumerate(gt_joint_parts):
            want = {int(slots[m, a]), int(slots[m, b])}
            for k in range(len(pj)):
                if {int(pj[k, 0]), int(pj[k, 1])} == want:
                    # a joint matched with parent and child exchanged describes the inverse motion
                    # (the parent moves by -state relative to the child), so its state changes sign
                    reverse = int(pj[k, 0]) != int(slots[m, a])
                    axis[m, j], pivot[m, j] = preds.joint_axis[r, k], preds.joint_pivot[r, k]
                    state[m, j] = -preds.joint_state[r, k] if reverse else preds.joint_state[r, k]
                    matched[m, j] = True
                    break
    return pose, axis, pivot, state, matched


def evaluate(dataset: str | Path | ArticulationDataset, predictions: str | Path | Predictions,
             protocol: str | Protocol = "scapo", check_hash: bool = True, split: str = "test") -> EvalResult:
    """Score ``predictions`` on the test split (or the val split, where choices are made) of ``dataset``.

    Args:
        dataset: dataset directory (or an opened dataset of any split; its root is used).
        predictions: predictions file or object; must cover every sample of ``split``, and every
            training sample too when ``needs_alignment`` is set.
        protocol: a name of :data:`~scapo.eval.protocols.PROTOCOLS` ("scapo", the default; "op-align";
            "eap"; "scapo-per-category") or a :class:`~scapo.eval.protocols.Protocol`.
        check_hash: refuse predictions made on a dataset with another hash.
        split: "test" (reported results) or "val" (choices: hyperparameters, margins, checkpoints).

    Returns:
        :class:`EvalResult`; its summary holds S (%), D, R, state_deg (deg), t and C (the protocol's
        unit: bbox diagonals, or OP-Align's), t_cm, C_cm, state_cm (cm), AP (%), the robust
        statistics of :func:`robust_summary`, and the symmetry-aware R_sym (deg, against the best of the
        dataset's declared symmetric ground truths, :func:`symmetric_part_errors`) with sym_rate (% of samples
        whose best ground truth is a symmetric one); the strict R stays the paper's column; and the frame
        consistency of the predicted object frames ``T_cam_obj`` on the split (:mod:`scapo.eval.frames`:
        ``frame_consistency``, ``frame_consistency_sym``, shares in [0, 1]; per sample ``frame_inlier``,
        ``frame_inlier_sym``).

    Raises:
        PredictionError: missing samples, wrong shapes or values (see
            :meth:`~scapo.eval.predictions.Predictions.validate`), predictions of another dataset, or
            an unknown protocol.
        DatasetError: ``dataset`` is not a dataset, or the split is empty.
    """
    t0 = time.perf_counter()
    proto = get_protocol(protocol)
    root = dataset.root if isinstance(dataset, ArticulationDataset) else Path(dataset)
    test, preds = _open(root, predictions, split, check_hash)
    P, J = test.num_parts, test.num_joints
    warn_few_instances(test.num_instances, split, root, "its scores")
    gt, rows, slots, sym, twinned = _matched_ground_truth(test, preds, split, proto)
    gt_jp = gt["joint_parts"][0] if J else np.zeros((0, 2), dtype=np.int64)
    pose, axis, pivot, state, matched = _gather(preds, rows, slots, gt_jp)
    unit = proto.unit(gt["points"], gt["part_label"], gt["bbox_diag"])  # metres per reported unit
    alignment = None
    if preds.needs_alignment:
        alignment = _alignment(root, preds, proto, sym, gt_jp, P)
        t_unit = None if proto.alignment == "ransac-offsets" else unit
        pose = alignment.apply_poses(pose, t_unit)
        state = alignment.apply_states(state, axis_sign(axis, gt["joint_axis"]))
    elif J:
        state = axis_sign(axis, gt["joint_axis"]) * state
    per_sample, errors = _score_samples(proto, preds, rows, slots, gt, pose, axis, pivot, state, matched, unit)
    R_sym, choice = symmetric_part_errors(proto, pose, gt["part_pose"], declared_rotations(test.card))
    per_sample["R_sym"] = R_sym.mean(1) if len(rows) else np.zeros(0)
    per_sample["symmetry"] = choice
    for p in range(P):
        per_sample[f"R_sym_p{p}"] = R_sym[:, p]
    frame = object_frame_twins(test)  # the split's order; rows[i] is sample i's prediction
    strict, _ = frame_inliers(preds.T_cam_obj[rows], frame[:, 0])
    per_sample["frame_inlier"] = strict
    per_sample["frame_inlier_sym"] = frame_inliers(preds.T_cam_obj[rows], frame)[0] if frame.shape[1] > 1 else strict
    summary = _summarise(per_sample, errors, proto, gt["joint_type"], P, J)
    summary["R_sym"] = float(per_sample["R_sym"].mean()) if len(rows) else float("nan")
    for k in ("frame_consistency", "frame_consistency_sym"):  # scapo.eval.frames: one object frame across views
        summary[k] = float(per_sample[k.replace("consistency", "inlier")].mean()) if len(rows) else float("nan")
    summary["sym_rate"] = 100.0 * float((choice > 0).mean()) if len(rows) else float("nan")
    if sym is not None:  # share of test samples scored against their twin ground truth (%)
        summary["twin_rate"] = 100.0 * float(twinned.mean()) if len(rows) else float("nan")
    summary["joint_match_rate"] = float(matched.mean()) if J and len(rows) else float("nan")
    info = {"protocol": proto.name, "dataset_hash": test.dataset_hash, "seconds": round(time.perf_counter() - t0, 3),
            "needs_alignment": preds.needs_alignment, "supervision": preds.supervision, **preds.info}
    if alignment is not None:
        info["alignment_inlier_ratio"] = alignment.inlier_ratio.round(3).tolist()
    info["split"] = split
    info["instances"] = test.num_instances
    return EvalResult(preds.method, test.category, split, per_sample, summary, alignment, info)


def declared_rotations(card: dict) -> np.ndarray:
    """``(K, 3, 3)``: the identity, then the rotation of each symmetry the dataset's card declares (object frame at
    rest; :mod:`scapo.sim.assets.symmetry`). A twin ground truth poses the points of GT part p by
    ``part_pose[p] @ S^-1``, so its part rotations are ``R_gt R_S^T``, whatever the symmetry's centre."""
    out = [np.eye(3)]
    if card.get("symmetry"):
        from scapo.sim.assets.symmetry import Symmetry

        out.append(np.asarray(Symmetry.from_dict(card["symmetry"]).rotation, dtype=np.float64))
    return np.stack(out)


#: The ground-truth fields of :func:`twin_ground_truth` (a twin needs its joints and scale besides the poses).
FRAME_TWIN_FIELDS = ("T_cam_obj", "part_pose", "joint_pivot", "joint_axis", "joint_state", "bbox_diag")


def twin_ground_truth(ds: ArticulationDataset) -> tuple[dict, dict | None]:
    """Each sample's ground truth and its :func:`~scapo.sim.assets.symmetry.twin`'s under the dataset card's declared
    symmetry: two dicts of :data:`FRAME_TWIN_FIELDS` (``T_cam_obj (M, 4, 4)``, ``part_pose (M, P, 4, 4)`` camera frame,
    metres; ``joint_pivot``, ``joint_axis (M, J, 3)``; ``joint_state (M, J)``; ``bbox_diag (M,)``), the samples in the
    split's order; the second is None for a category without a declared symmetry.

    Args:
        ds: one split of a dataset (:func:`scapo.data.load`).
    """
    gt = ds.arrays(list(FRAME_TWIN_FIELDS))
    if not ds.card.get("symmetry"):
        return gt, None
    from scapo.sim.assets.symmetry import Symmetry, twin

    return gt, twin({k: gt[k] for k in FRAME_TWIN_FIELDS}, Symmetry.from_dict(ds.card["symmetry"]))


def object_frame_twins(ds: ArticulationDataset) -> np.ndarray:
    """``(M, K, 4, 4)`` float64: each sample's valid ground-truth object poses ``T_cam_obj``, its own first, then its
    :func:`~scapo.sim.assets.symmetry.twin`'s under the dataset card's declared symmetry (K = 1 without one;
    :func:`twin_ground_truth`).

    The twin's object frame is its base part's pose. Where the symmetry exchanges the base (the laptop's base and
    lid), that is the exchanged part's pose turned by the symmetry, ``part_pose[lid] S^-1``, which follows the joint
    state, not ``T_cam_obj S^-1`` (equal only at rest); the part rotations of :func:`declared_rotations` stay right
    because the parts are matched by their points first.

    Args:
        ds: one split of a dataset (:func:`scapo.data.load`); the samples in its order.
    """
    if not ds.card.get("symmetry"):
        return ds.arrays(["T_cam_obj"])["T_cam_obj"].astype(np.float64)[:, None]
    gt, tw = twin_ground_truth(ds)
    return np.stack([gt["T_cam_obj"], tw["T_cam_obj"]], 1).astype(np.float64)  # a new array: the split's are cached


def symmetric_part_errors(proto: Protocol, pose: np.ndarray, gt_pose: np.ndarray, rotations: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The symmetry-aware part rotation errors: each sample scored against the symmetric ground truth that fits it
    best, one symmetry for all its parts (BOP's symmetric pose errors, Hodan et al., ECCV 2020 workshop, bop_toolkit
    ``pose_error.py``: the error minimised over the object's symmetries; here over the declared object symmetries,
    whose twins exchange parts, with the protocol's own rotation error).

    Args:
        pose, gt_pose: ``(M, P, 4, 4)`` predicted (after the protocol's alignment) and GT part poses (the GT the
            protocol scores, after its own standardisation). rotations: ``(K, 3, 3)`` from :func:`declared_rotations`.

    Returns:
        ``(R_sym (M, P) deg, choice (M,) int)``: the errors and the symmetry each sample took (0: the identity). With
        only the identity, ``R_sym`` is the strict error.
    """
    M, P = pose.shape[:2]
    if M == 0:
        return np.zeros((0, P)), np.zeros(0, dtype=np.int64)
    errs = np.stack([proto.rotation_error(pose[..., :3, :3], gt_pose[..., :3, :3] @ R.T) for R in rotations])
    choice = errs.mean(2).argmin(0)
    return errs[choice, np.arange(M)], choice


def _open(root: Path, predictions, split: str, check_hash: bool) -> tuple[ArticulationDataset, Predictions]:
    """The split to score and the predictions, checked against each other (see :func:`evaluate`'s errors)."""
    if split not in ("test", "val"):
        raise PredictionError(f"evaluate scores the 'test' or 'val' split, not {split!r}")
    test = load(root, split)
    if len(test) == 0:
        raise DatasetError(f"the {split} split of {root} is empty (generated with --{split}-fraction "
                           f"{test.card.get('config', {}).get(f'{split}_fraction')}); nothing to evaluate: "
                           f"regenerate it with {split} instances")
    preds = predictions if isinstance(predictions, Predictions) else Predictions.load(predictions)
    if check_hash and not preds.dataset_hash:
        raise PredictionError(f"predictions of {preds.method!r} carry no dataset hash (written by hand or by an old "
                              f"scapo), so nothing shows they were made on {root}; predict again with 'scapo predict'")
    if check_hash and preds.dataset_hash != test.dataset_hash:
        raise PredictionError(f"predictions of {preds.method!r} were made on dataset {preds.dataset_hash[:12]}..., "
                              f"not on {root} ({test.dataset_hash[:12]}...)")
    return test, preds


def _matched_ground_truth(test: ArticulationDataset, preds: Predictions, split: str, proto: Protocol):
    """The split's ground truth, the predictions' row of each sample, the slot of each GT part (the protocol's
    matching), the dataset's symmetry when the protocol scores twins, and which samples were scored against
    their twin ground truth: ``(gt, rows (M,), slots (M, P), sym, twinned (M,) bool)``."""
    gt = test.arrays()
    rows = _rows_for(preds, test, split)
    if preds.part_label.shape[1] != gt["points"].shape[1]:
        raise PredictionError(f"predictions have {preds.part_label.shape[1]} labels per sample, the dataset "
                              f"{gt['points'].shape[1]} points")
    slots = _match(preds, rows, gt["part_label"], test.num_parts, proto)
    sym = _symmetry(test, proto)
    twinned = np.zeros(len(rows), dtype=bool)
    if sym is not None:
        gt, slots, twinned = _use_twins(gt, slots, sym)
    return gt, rows, slots, sym, twinned


def _alignment(root: Path, preds: Predictions, proto: Protocol, sym, gt_jp: np.ndarray, P: int) -> CanonicalAlignment:
    """The canonical-frame offsets of a method whose frame is arbitrary, from its training-split predictions
    (:func:`~scapo.eval.alignment.estimate_alignment`, the protocol's estimator)."""
    train = load(root, "train")
    gtr = train.arrays(["part_label", "part_pose", "joint_axis", "joint_state", "points", "bbox_diag", "T_cam_obj",
                        "joint_pivot"])
    trows = _rows_for(preds, train, "train")
    tslots = _match(preds, trows, gtr["part_label"], P, proto)
    if sym is not None:
        gtr, tslots, _ = _use_twins(gtr, tslots, sym)
    tpose, taxis, _, tstate, tmatched = _gather(preds, trows, tslots, gt_jp)
    good = tmatched.all(1) & (tslots >= 0).all(1)
    if not good.any():
        raise PredictionError(f"no training prediction of {preds.method!r} has all parts and joints matched; "
                              "cannot estimate the canonical-frame alignment")
    t_unit = None if proto.alignment == "ransac-offsets" else \
        proto.unit(gtr["points"], gtr["part_label"], gtr["bbox_diag"])[good]
    return estimate_alignment(tpose[good], gtr["part_pose"][good], taxis[good], gtr["joint_axis"][good],
                              tstate[good], gtr["joint_state"][good], inlier_deg=proto.alignment_deg,
                              method=proto.alignment, unit=t_unit, inlier_t=proto.alignment_t)


def _score_samples(proto: Protocol, preds: Predictions, rows, slots, gt: dict, pose, axis, pivot, state, matched,
                   unit) -> tuple[pd.DataFrame, dict]:
    """The metrics of every sample (one row each, with per-part and per-joint columns) and the arrays the summary
    needs (``iou (M, P)``, ``R_err (M, P)``, ``t_abs (M, P)`` m, ``D (M, J)``, ``C_abs (M, J)`` m, ``scored (M, J)``
    joints with a pivot score)."""
    P, J = slots.shape[1], gt["joint_axis"].shape[1]
    diag = gt["bbox_diag"]
    M = len(rows)
    seg_pred = np.stack([relabel(preds.part_label[r], s) for r, s in zip(rows, slots)]) if M else np.zeros((0, 0))
    ignore_bg = proto.ignores_background
    iou = np.stack([segmentation_iou(sp, g, P, ignore_bg) for sp, g in zip(seg_pred, gt["part_label"])]) if M else \
        np.zeros((0, P))
    R_err = proto.rotation_error(pose[..., :3, :3], gt["part_pose"][..., :3, :3])
    t_abs = translation_error(pose[..., :3, 3], gt["part_pose"][..., :3, 3])
    D = np.where(matched, axis_error_deg(axis, gt["joint_axis"]), 90.0)
    safe_axis = np.where(matched[..., None], axis, gt["joint_axis"])
    C_raw = proto.pivot_distance(PivotCase(pivot, safe_axis, gt["joint_pivot"], gt["joint_axis"], gt["points"],
                                           gt["part_label"]))
    C_abs = np.where(matched, C_raw, diag[:, None])
    jt = gt["joint_type"]
    revolute = jt == 0
    scored = np.ones_like(revolute) if proto.pivot_prismatic else revolute  # joints that get a pivot score
    state_err = np.abs(state - gt["joint_state"])
    rows_out = {
        "instance_id": gt["instance_id"], "view_id": gt["view_id"],
        "S": 100.0 * np.nanmean(iou, 1),
        "R": R_err.mean(1), "t": (t_abs / unit[:, None]).mean(1), "t_cm": 100.0 * t_abs.mean(1),
    }
    with np.errstate(invalid="ignore"):
        rows_out["D"] = D.mean(1) if J else np.full(M, np.nan)
        C_rel = np.where(scored, C_abs / unit[:, None], np.nan)
        rows_out["C"] = np.nanmean(C_rel, 1) if scored.any() else np.full(M, np.nan)
        rows_out["C_cm"] = np.nanmean(np.where(scored, 100.0 * C_abs, np.nan), 1) if scored.any() else \
            np.full(M, np.nan)
        sd = np.where(revolute & matched, np.degrees(state_err), np.nan)
        sc = np.where(~revolute & matched, 100.0 * state_err, np.nan)
        rows_out["state_deg"] = np.nanmean(sd, 1) if (revolute & matched).any() else np.full(M, np.nan)
        rows_out["state_cm"] = np.nanmean(sc, 1) if (~revolute & matched).any() else np.full(M, np.nan)
    rows_out["joints_matched"] = matched.sum(1) if J else np.zeros(M, dtype=int)
    for p in range(P):
        rows_out[f"S_p{p}"] = 100.0 * iou[:, p]
        rows_out[f"R_p{p}"] = R_err[:, p]
        rows_out[f"t_p{p}"] = t_abs[:, p] / unit
        rows_out[f"t_cm_p{p}"] = 100.0 * t_abs[:, p]
    for j in range(J):
        rows_out[f"D_j{j}"] = D[:, j]
        rows_out[f"C_j{j}"] = C_abs[:, j] / unit if scored[0, j] else np.full(M, np.nan)
        rows_out[f"C_cm_j{j}"] = 100.0 * C_abs[:, j] if scored[0, j] else np.full(M, np.nan)
        rows_out[f"state_err_j{j}"] = np.where(matched[:, j], np.degrees(state_err[:, j]) if revolute[0, j]
                                               else 100.0 * state_err[:, j], np.nan)
    return pd.DataFrame(rows_out), {"iou": iou, "R_err": R_err, "t_abs": t_abs, "D": D, "C_abs": C_abs,
                                    "scored": scored, "matched": matched}


def _summarise(per_sample: pd.DataFrame, e: dict, proto: Protocol, joint_type: np.ndarray, P: int, J: int) -> dict:
    """Means of the per-sample metrics, AP (:func:`_average_precision`) and the robust statistics
    (:func:`robust_summary`)."""
    iou, R_err, t_abs, D, C_abs, scored = (e[k] for k in ("iou", "R_err", "t_abs", "D", "C_abs", "scored"))
    M = len(per_sample)
    jt = joint_type
    summary = {k: float(np.nanmean(per_sample[k])) if per_sample[k].notna().any() else float("nan")
               for k in ("S", "D", "C", "R", "t", "t_cm", "C_cm", "state_deg", "state_cm")}
    summary.update(_average_precision(iou, R_err, 100.0 * t_abs, D, 100.0 * C_abs, scored[0] if J else
                                      np.zeros(0, dtype=bool), proto.min_ap))
    summary.update(robust_summary(per_sample, P, jt[0] if J else []))
    summary["samples"] = M
    return summary


#: Robust statistics in every summary: medians of the per-part / per-joint errors, and part rates.
ROBUST_KEYS = ("R_median", "t_median", "D_median", "C_median", "R_under5", "R_under10", "R_over90",
               "state_deg_median", "state_cm_median", "R_sym_median", "R_sym_over90")


def robust_summary(per_sample: pd.DataFrame, P: int, joint_type) -> dict:
    """Medians and rates over all parts (joints) of all samples, from the per-sample table.

    ``R_median``, ``t_median`` (protocol unit): medians of the per-part errors; ``D_median``,
    ``C_median``: of the per-joint errors (C of scored joints only); ``R_under5``, ``R_under10``,
    ``R_over90``: % of part poses with a rotation error under 5 / 10 deg and over 90 deg (the flip
    rate); ``state_deg_median`` / ``state_cm_median``: of the revolute / prismatic joints' state
    errors; ``R_sym_median``, ``R_sym_over90``: the same for the symmetry-aware errors
    (:func:`symmetric_part_errors`), when the table has them. NaN where nothing is defined.
    """
    jt = [int(t) for t in joint_type]

    def med(cols):
        v = per_sample[cols].to_numpy(dtype=np.float64).ravel() if cols else np.zeros(0)
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else float("nan")

    R = per_sample[[f"R_p{p}" for p in range(P)]].to_numpy(dtype=np.float64).ravel()
    out = {"R_median": med([f"R_p{p}" for p in range(P)]), "t_median": med([f"t_p{p}" for p in range(P)]),
           "D_median": med([f"D_j{j}" for j in range(len(jt))]), "C_median": med([f"C_j{j}" for j in range(len(jt))]),
           "state_deg_median": med([f"state_err_j{j}" for j, t in enumerate(jt) if t == 0]),
           "state_cm_median": med([f"state_err_j{j}" for j, t in enumerate(jt) if t == 1])}
    for name, mask in (("R_under5", R < 5.0), ("R_under10", R < 10.0), ("R_over90", R > 90.0)):
        out[name] = 100.0 * float(mask.mean()) if R.size else float("nan")
    if f"R_sym_p{P - 1}" in per_sample:  # the symmetry-aware errors beside the strict ones
        Rs = per_sample[[f"R_sym_p{p}" for p in range(P)]].to_numpy(dtype=np.float64).ravel()
        out["R_sym_median"] = med([f"R_sym_p{p}" for p in range(P)])
        out["R_sym_over90"] = 100.0 * float((Rs > 90.0).mean()) if Rs.size else float("nan")
    return out


def _average_precision(iou, R_err, t_cm, D, C_cm, pivot_scored, min_ap: bool = False) -> dict:
    """Table 2 metrics (%): segmentation precision at IoU > 75/50 %, joint and part AP at 5/10/15
    (averaged over parts / joints: "mean mAP"); with ``min_ap`` also OP-Align's "min mAP" at 5 and 10
    (a sample counts only if all its parts / joints pass; trainer_art.py ``val``). A joint without a
    pivot score is judged by its direction alone."""
    out = {}
    M = len(R_err)
    for thr in SEG_THRESHOLDS:
        per_part = [np.mean(iou[:, p] > thr) for p in range(iou.shape[1])]
        out[f"seg_{int(thr * 100)}"] = 100.0 * float(np.nanmean(per_part))
        if min_ap:
            out[f"min_seg_{int(thr * 100)}"] = 100.0 * float(np.mean((np.nan_to_num(iou, nan=0.0) > thr).all(1)))
    dist = np.where(np.asarray(pivot_scored, dtype=bool)[None], C_cm, 0.0) if D.shape[1] else np.zeros((M, 0))
    for a, d in AP_THRESHOLDS:
        tag = f"{int(a)}"
        parts = [precision_under(R_err[:, p], t_cm[:, p], a, d) for p in range(R_err.shape[1])]
        out[f"ap_part_{tag}"] = 100.0 * float(np.mean(parts))
        joints = [precision_under(D[:, j], dist[:, j], a, d) for j in range(D.shape[1])]
        out[f"ap_joint_{tag}"] = 100.0 * float(np.mean(joints)) if joints else float("nan")
        if min_ap and a in (5.0, 10.0):
            out[f"min_ap_part_{tag}"] = 100.0 * float(np.mean(((R_err < a) & (t_cm < d)).all(1))) if M else np.nan
            out[f"min_ap_joint_{tag}"] = 100.0 * float(np.mean(((D < a) & (dist < d)).all(1))) \
                if M and D.shape[1] else float("nan")
    return out
