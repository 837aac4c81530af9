"""The canonical frame read from the base part's principal axes (an addition to the paper).

SCAPO's stage-1 frame is a function of the whole cloud. The principal axes of the whole cloud turn with the joint state
and with what a view shows; those of the base part alone do not: with the ground-truth base points, the base's
principal axes put 0.98 (laptop, paper viewpoints) and 1.00 (eyeglasses) of the ladder's val views within 15 deg of
one frame, against 0.54 and 0.46 for the whole cloud (``docs/canonical_ladder.md``, "The base part's
axes"). This module snaps a prediction's frame to the principal axes of the points the prediction itself labels as
the base, through a fixed offset fitted on the training split, and turns every part pose and joint with it:

1. :func:`base_axes`: per view, the principal axes ``E (3, 3)`` of the predicted base points
   (:func:`scapo.nn.encoder.principal_frame`: order by variance, signs by third moments; ambiguous up to the 24
   signed permutations ``G_k``, the rotation group "O").
2. :func:`fit_base_offset`: on training views, the offset ``O`` with ``R_base O = E G_k`` for most views (the base
   axes in canonical coordinates), by consensus over the views (no labels).
3. :func:`snap_to_base`: per test view, ``k`` = the signed permutation with ``E G_k`` nearest the network's
   ``R_base O``; the base rotation becomes ``E G_k O^T``, and the correction ``Delta = E G_k O^T R_base^T`` turns
   the rotation of every part pose and of ``T_cam_obj`` (``R_p <- Delta R_p``: the parts' relative rotations are
   kept). What the network estimated in the camera frame is kept: the poses' translations (the canonical origins),
   the joint axes and pivots, the joint states and the labels. (Turning the joints with ``Delta`` as well was
   measured to raise D on val, 4.8 -> 7.0 deg on the laptop 45-core-minute run: the network's camera-frame axis
   does not share the frame's error.)

It needs no ground truth: the base is the network's own segmentation, part slot 0 by default. The network's slot 0
need not be the physical base: a run can learn its frame on the child part (the laptop's lid: seed 1 of the 45-core-
minute ladder cell labels the lid part 0 in 0.75 of the training views). :func:`choose_base_slot` (``base_slot=auto``)
takes instead the slot whose predicted camera-frame rotations vary least over the training views: the base turns
only with the viewpoint, every other part also with its joint states. The snapped frame is then that slot's pose.

A view with fewer than ``min_points`` base points keeps its frame.

``base_frame=parts`` (:func:`parts_signed_axes`) signs the axes from the object instead of the network: the
base's principal directions of two ranks are each signed towards the centroid of the points of the other parts (an
eyeglasses front's normal towards its temples, its height towards the hinges above its centre; a laptop base's depth
towards the hinge and its normal towards the open lid), the third by the right-hand rule. Which two ranks is chosen
on the training split (:func:`choose_signed_pair`: with two or more other parts, the ranks along which all of them lie
on one side of the base in most views, so that an axis a mirror pair straddles is not signed; with one,
the ranks along which the other parts lie farthest, in units of the base's spread, in most views). The axes then have
no ambiguity left, so the offset is fitted with no group and each view's base rotation is ``E O^T`` whatever the
network's frame: on the eyeglasses' paper rung, where SCAPO's frame scatters, this is what can give one frame
(``docs/canonical_ladder.md``, "The base's axes signed by the other parts").
"""

from __future__ import annotations

import numpy as np
import torch

from scapo.errors import InputError


def _group() -> np.ndarray:
    from scapo.ops.groups import rotation_group

    return np.asarray(rotation_group("O"), dtype=np.float64)  # (24, 3, 3)


def _angle(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Angles (deg) between rotations ``A (..., 3, 3)`` and ``B (..., 3, 3)`` (the evaluator's geodesic angle)."""
    from scapo.eval.metrics import rotation_error_deg

    A, B = np.broadcast_arrays(np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64))
    return rotation_error_deg(A, B)


def rotation_dispersion(R: np.ndarray) -> float:
    """How much rotations ``R (V, 3, 3)`` spread: 1 minus the mean singular value of their mean matrix (0 when all
    are equal, near 1 under uniform SO(3); the chordal dispersion)."""
    R = np.asarray(R, dtype=np.float64)
    return float(1.0 - np.linalg.svd(R.mean(0), compute_uv=False).mean())


def choose_base_slot(part_pose: np.ndarray, level: float = 0.95, resamples: int = 200,
                     seed: int = 0) -> tuple[int, np.ndarray]:
    """The part slot that acts as the base over a set of training views, with no labels: the slot whose camera-frame
    rotations spread least (:func:`rotation_dispersion`). A base turns only with the viewpoint; a part on a joint also
    turns with the joint's state, so its rotations spread more. Under uniform SO(3) viewpoints every slot spreads
    alike (near 1) and the choice carries no information, so another slot replaces slot 0 only when it spreads least
    in at least ``level`` of ``resamples`` bootstrap resamples of the views (seeded: the same poses give the same
    slot).

    Args:
        part_pose: ``(V, P, 4, 4)`` predicted part poses (canonical -> camera) of training views.
        level: the bootstrap share a slot other than 0 needs. resamples, seed: the bootstrap's size and seed.

    Returns:
        The slot (int) and each slot's dispersion ``(P,)`` float64 on all views.

    Raises:
        InputError: not a ``(V, P, 4, 4)`` array with V > 0.
    """
    pose = np.asarray(part_pose, dtype=np.float64)
    if pose.ndim != 4 or pose.shape[-2:] != (4, 4) or len(pose) == 0:
        raise InputError(f"scapo: choose_base_slot needs part poses (V, P, 4, 4) with V > 0, got {pose.shape}")
    R = pose[..., :3, :3]
    disp = np.array([rotation_dispersion(R[:, p]) for p in range(R.shape[1])])
    slot = int(disp.argmin())
    if slot != 0:
        rng = np.random.default_rng(seed)
        wins = 0
        for _ in range(int(resamples)):
            idx = rng.integers(0, len(R), len(R))
            wins += int(np.argmin([rotation_dispersion(R[idx, p]) for p in range(R.shape[1])]) == slot)
        slot = slot if wins >= level * resamples else 0
    return slot, disp


def base_axes(points: np.ndarray, part_label: np.ndarray, min_points: int = 16,
              slot: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes of each view's predicted base points.

    Args:
        points: ``(V, N, 3)`` camera-frame clouds (metres). part_label: ``(V, N)`` int predicted part per point.
            min_points: fewest base points for axes. slot: the part slot taken as the base (0 by default,
            :func:`choose_base_slot`).

    Returns:
        ``E (V, 3, 3)`` float64 rotations (columns: the axes, largest variance first, camera frame; identity where
        there are too few points) and ``ok (V,)`` bool.

    Raises:
        InputError: shapes that do not match, or non-finite points.
    """
    points = np.asarray(points, dtype=np.float64)
    part_label = np.asarray(part_label)
    if points.ndim != 3 or points.shape[-1] != 3 or part_label.shape != points.shape[:2]:
        raise InputError(f"scapo: base_axes needs points (V, N, 3) and part_label (V, N), got {points.shape} and "
                         f"{part_label.shape}")
    if not np.isfinite(points).all():
        raise InputError("scapo: base_axes got NaN or infinite points; drop them before predicting")
    mask = part_label == int(slot)
    count = mask.sum(1)
    ok = count >= max(int(min_points), 4)
    w = np.where(ok[:, None], mask, True).astype(np.float64)
    w /= w.sum(1, keepdims=True)
    from scapo.nn.encoder import principal_frame

    with torch.no_grad():
        E = principal_frame(torch.from_numpy(points), torch.from_numpy(w)).numpy()
    E[~ok] = np.eye(3)
    return E, ok


def choose_signed_pair(points: np.ndarray, part_label: np.ndarray, slot: int = 0,
                       min_points: int = 16) -> tuple[int, int]:
    """:func:`scapo.ops.signed_axes.choose_signed_pair` (the two ranks ``base_frame=parts`` signs, chosen on training
    views with no labels): ``points (V, N, 3)`` camera frame (m), ``part_label (V, N)`` int -> ``(i, j)``, ``i < j``.

    Raises:
        InputError: shapes that do not match, or no view with enough points of the base and of the other parts.
    """
    from scapo.ops import signed_axes

    try:
        return signed_axes.choose_signed_pair(points, part_label, slot, min_points)
    except ValueError as e:
        raise InputError(f"scapo: {e}") from None


def parts_signed_axes(points: np.ndarray, part_label: np.ndarray, pair: tuple[int, int], slot: int = 0,
                      min_points: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """:func:`scapo.ops.signed_axes.parts_signed_axes` (``base_frame=parts``: the base's principal axes, two ranks
    signed towards the other parts' centroid): ``points (V, N, 3)`` camera frame (m), ``part_label (V, N)`` int, the
    ranks ``pair`` -> (``E (V, 3, 3)`` rotations, columns the axes in rank order; ``ok (V,)`` bool).

    Raises:
        InputError: shapes that do not match, non-finite points, or a pair that is not two distinct ranks in 0..2.
    """
    from scapo.ops import signed_axes

    try:
        return signed_axes.parts_signed_axes(points, part_label, pair, slot, min_points)
    except ValueError as e:
        raise InputError(f"scapo: {e}") from None


def fit_base_offset(R_base: np.ndarray, E: np.ndarray, inlier_deg: float = 15.0,
                    candidates: int = 64, group: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """The offset ``O (3, 3)`` from the canonical base frame to the base's principal axes that most training views
    share: ``R_base_i O ~ E_i G_k`` for some signed permutation ``G_k`` of each view.

    Each view's offset ``M_i = R_base_i^T E_i`` is known up to ``G_k`` on the right. For each of up to
    ``candidates`` evenly spaced views as reference, every ``M_i`` takes the ``G_k`` nearest the reference; the
    reference with the most views within ``inlier_deg`` wins, and ``O`` is the chordal mean of those views.

    Args:
        R_base: ``(V, 3, 3)`` the network's base rotations (canonical -> camera). E: ``(V, 3, 3)`` the base axes
            (:func:`base_axes`), only views with axes.
        group: ``(K, 3, 3)`` the rotations ``E`` is known up to (default: the 24 signed permutations; the identity
            alone for axes with no ambiguity, :func:`scapo.steps.hinge.part_axes`).

    Returns:
        ``O (3, 3)`` float64 rotation, the share of views within ``inlier_deg`` of it, and each view's angle to it
        ``(V,)`` (deg, after its best signed permutation).

    Raises:
        InputError: no views, or shapes that differ.
    """
    R_base, E = np.asarray(R_base, dtype=np.float64), np.asarray(E, dtype=np.float64)
    if R_base.shape != E.shape or R_base.ndim != 3 or len(R_base) == 0:
        raise InputError(f"scapo: fit_base_offset needs two (V, 3, 3) arrays with V > 0, got {R_base.shape} and "
                         f"{E.shape}; is part 0 (the base) predicted on the training views?")
    G = _group() if group is None else np.asarray(group, dtype=np.float64).reshape(-1, 3, 3)
    M = np.einsum("vji,vjk->vik", R_base, E)  # R^T E
    MG = np.einsum("vij,gjk->vgik", M, G)  # (V, 24, 3, 3)
    best = (-1, None)
    for r in np.unique(np.linspace(0, len(M) - 1, min(candidates, len(M))).round().astype(int)):
        d = _angle(MG, M[r][None, None])
        aligned = MG[np.arange(len(M)), d.argmin(1)]
        inl = d.min(1) < inlier_deg
        if inl.sum() > best[0]:
            best = (int(inl.sum()), aligned[inl])
    U, _, Vt = np.linalg.svd(best[1].sum(0))
    O = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    angle = _angle(MG, O[None, None]).min(1)
    return O, float((angle < inlier_deg).mean()), angle


def snap_to_base(points: np.ndarray, out: dict, offset: np.ndarray, min_points: int = 16, slot: int = 0,
                 pair: tuple[int, int] | None = None) -> dict:
    """Turn each view's prediction so that its base rotation is its base points' principal axes ``E G_k O^T``.

    Args:
        points: ``(V, N, 3)`` camera-frame clouds (metres), the ones predicted on. out: the prediction (numpy arrays,
            :meth:`scapo.models.predict.Predictor.predict`): ``part_label (V, N)``, ``part_pose (V, P, 4, 4)``,
            ``T_cam_obj (V, 4, 4)`` (camera frame, m). offset:
            ``O (3, 3)`` (:func:`fit_base_offset`, fitted with the same ``slot``). slot: the part slot taken as the
            base (:func:`choose_base_slot`). pair: with ``base_frame=parts``, the signed ranks
            (:func:`choose_signed_pair`): the axes are :func:`parts_signed_axes` and the base rotation ``E O^T``.

    Returns:
        A copy of ``out`` with the rotations of ``part_pose`` and ``T_cam_obj`` turned (translations, joints and
        labels kept; with ``slot`` other than 0, ``T_cam_obj`` becomes that slot's turned pose) and
        ``base_snap_deg (V,)`` float64, the correction's angle per view (0 where the view has fewer
        than ``min_points`` base points and keeps its frame).
    """
    pose = np.asarray(out["part_pose"], dtype=np.float64)
    R0 = pose[:, int(slot), :3, :3]
    if pair is not None:  # the axes' signs from the other parts: no choice left to the network's frame
        E, ok = parts_signed_axes(points, out["part_label"], pair, slot, min_points)
        R_new = E @ np.asarray(offset, dtype=np.float64).T
    else:
        E, ok = base_axes(points, out["part_label"], min_points, slot)
        target = R0 @ np.asarray(offset, dtype=np.float64)  # where the network puts the base axes
        EG = np.einsum("vij,gjk->vgik", E, _group())
        k = _angle(EG, target[:, None]).argmin(1)
        R_new = EG[np.arange(len(E)), k] @ np.asarray(offset, dtype=np.float64).T
    delta = np.einsum("vij,vkj->vik", R_new, R0)  # R_new R0^T
    delta[~ok] = np.eye(3)
    res = dict(out)
    pose_new = pose.copy()
    pose_new[:, :, :3, :3] = np.einsum("vij,vpjk->vpik", delta, pose[:, :, :3, :3])
    res["part_pose"] = pose_new.astype(np.asarray(out["part_pose"]).dtype)
    T = np.asarray(out["T_cam_obj"], dtype=np.float64).copy()
    T[:, :3, :3] = np.einsum("vij,vjk->vik", delta, T[:, :3, :3])
    if int(slot) != 0:  # the frame is the base slot's pose
        T = pose_new[:, int(slot)].copy()
    res["T_cam_obj"] = T.astype(np.asarray(out["T_cam_obj"]).dtype)
    res["base_snap_deg"] = np.where(ok, _angle(delta, np.eye(3)[None]), 0.0)
    return res
