"""The part split re-fitted about each revolute joint: a two-ray fit (an addition to the paper).

A self-supervised segmentation learned from motion is weakest next to a revolute joint: a point near the axis
moves little whichever part it is given to, so the losses that separate parts by their motion (SCAPO's cycle and
cross-space terms) barely see it. On the laptop's paper viewpoints, most of SCAPO's mislabelled points lie within a
tenth of the bounding-box diagonal of the hinge, and its predicted pivot lies a twentieth to a tenth of the diagonal
from the true hinge line, while its predicted axis is within a few degrees (``bench/diagnostics/hinge_diagnosis.py``;
the
measurements are in ``results/canonical_ladder/hinge/`` (at 9a79e15)).

This step re-estimates the pivot from the points and re-splits them, view by view, from a method's own one-pass
prediction (its labels, joint axis and pivot; no ground truth, no training):

1. Points are seen along the predicted axis ``a``: ``q_i`` = the components of ``x_i - pivot`` in a basis of the
   plane normal to ``a`` (metres, camera frame; the view's own 2-D section of the hinge).
2. Each of the joint's two parts (the points the current labels give to its parent and child slots) is fitted by a
   line in that plane (centroid and first principal direction). Near a hinge, a thin part (a laptop's lid and base,
   an eyeglasses temple and the front) is a segment whose line runs through the axis, so the two lines meet at the
   hinge: their intersection is the new 2-D pivot (kept at the previous one when the lines are within ~3 deg of
   parallel or the intersection lies farther than the pair's radius from its centroid).
3. Each part becomes the ray from the pivot along its line, towards its centroid; every point of the pair takes the
   part of the nearer ray (a point behind both rays is nearest the pivot itself and keeps the first part).
4. Steps 2-3 repeat ``iters`` times. Points of other parts are untouched; the pivot moves only in the plane normal
   to the axis (its position along the axis is the method's). Joints are fitted in order (parents first in SCAPO's
   kinematic list), each on the labels the previous one left. A prismatic joint is skipped (no hinge), and so is a
   joint whose parent or child has fewer than ``min_points`` points in the view.

5. Optionally (``axis_from_planes``, the option ``hinge_axis=true``): where both parts are planar slabs (a laptop's
   base and lid), the axis is re-estimated as the line where their planes meet (:func:`plane_axis`, on the re-split
   points), the fit is repeated about it, and the axis re-estimated once more. A bar-like part (an eyeglasses temple)
   or near-parallel planes keep the predicted axis.

5b. Optionally (``bar_axes``, the option ``hinge_bar_axis=true``): where the child is a bar (an eyeglasses temple)
   it turns about an axis perpendicular to its length, and that axis is one of its parent's principal directions
   (the front's height). Which one is chosen per joint on the training split (:func:`bar_axis_choice`), as the
   parent's principal direction the child's length is most nearly perpendicular to in every view; each view's axis
   is then its parent's principal direction of that rank (:func:`bar_axis`) and its pivot the lines' intersection
   about it. That joint's split is not re-fitted: a shut bar lies along its parent, where two rays cannot split it
   (measured in ``results/canonical_ladder/bar_axis/`` (at 9a79e15): from the true eyeglasses split, the two-ray
   re-split keeps
   60-66 % of S).

6. Optionally (``hinge_frames=true``, after the steps above): each part's rotation read from its hinge
   (:func:`part_axes`: the axis, signed by the pair's chirality, and the direction the part runs away from the hinge),
   through per-part offsets fitted on the training split (:class:`HingeFrames`); with ``hinge_view_prior=true`` each
   view's base chosen between its two parts by the training views' base orientation (a viewpoint prior, off under
   views from the whole sphere). Measured in ``docs/canonical_ladder.md``, "The part rotations from the
   hinges".

What it assumes: parts that are thin in the section normal to their hinge (a box-shaped body beside a door is a
region, not a segment, and its line can miss the hinge), and a predicted axis near the true one (the fit moves the
pivot, never the axis). It reads only what the method predicts, so it is offered to every trained method alike
(``scapo predict --option hinge=true``; the predictions' label gets ``+hinge`` and ``info["hinge"]`` records the share
of points that changed part and the median pivot move; :func:`hinge_predictions` applies it to a predictions file
already written). It is not free: a method whose split is already right but whose pivot is far off loses (ICP on
Table 1's laptop views, ``results/table1_paper_hinge_5min/`` (at 9a79e15)).
"""

from __future__ import annotations

import numpy as np

from scapo.errors import ConfigError, InputError
from scapo.ops.signed_axes import principal_axes

#: Iterations of the line fit and re-split (fixed before any measurement, not tuned).
HINGE_ITERS = 8
#: A part with fewer points in a view is not fitted (a line through a handful of points means little).
HINGE_MIN_POINTS = 8
#: The two lines' intersection is used only when the sine of their angle exceeds this (~3 deg).
_MIN_SINE = 0.05


def _plane_basis(axis: np.ndarray) -> np.ndarray:
    """``(2, 3)`` an orthonormal basis of the plane normal to ``axis (3,)`` (any length > 0)."""
    a = axis / np.linalg.norm(axis)
    t = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(a, t)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(a, e1)])


def _line(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = Q.mean(0)
    _, _, vt = np.linalg.svd(Q - m, full_matrices=False)
    return m, vt[0]


def hinge_fit(points: np.ndarray, part_label: np.ndarray, pivot: np.ndarray, axis: np.ndarray, parent: int,
              child: int, iters: int = HINGE_ITERS, min_points: int = HINGE_MIN_POINTS
              ) -> tuple[np.ndarray, np.ndarray]:
    """Re-split one view's points between the parent and child of one revolute joint (module docstring, steps 1-4).

    Args:
        points: ``(N, 3)`` the view's points (camera frame, metres).
        part_label: ``(N,)`` int, the method's part slot per point (-1 = none).
        pivot: ``(3,)`` a point on the predicted joint axis (camera frame, metres).
        axis: ``(3,)`` the predicted joint direction (camera frame; any non-zero length).
        parent, child: the joint's two part slots.
        iters: fit/re-split rounds. min_points: the fewest points either part needs for a fit.

    Returns:
        ``(labels (N,) int64, pivot (3,) float64)``: the new slots (only points labelled ``parent`` or ``child``
        change) and the re-estimated pivot (moved in the plane normal to ``axis`` only). Unchanged inputs when a part
        has fewer than ``min_points`` points.

    Raises:
        InputError: mismatched shapes, non-finite values or a zero axis.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(part_label).astype(np.int64)
    piv, ax = np.asarray(pivot, dtype=np.float64), np.asarray(axis, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or lab.shape != pts.shape[:1] or piv.shape != (3,) or ax.shape != (3,):
        raise InputError(f"hinge_fit needs points (N, 3), part_label (N,), pivot (3,) and axis (3,); got "
                         f"{pts.shape}, {lab.shape}, {piv.shape}, {ax.shape}")
    if not (np.isfinite(pts).all() and np.isfinite(piv).all() and np.isfinite(ax).all()):
        raise InputError("hinge_fit: points, pivot and axis must be finite (NaN or inf given)")
    if np.linalg.norm(ax) < 1e-12:
        raise InputError("hinge_fit: the joint axis has zero length")
    E = _plane_basis(ax)
    q = (pts - piv) @ E.T  # (N, 2)
    pair = (lab == parent) | (lab == child)
    if min(np.count_nonzero(lab == parent), np.count_nonzero(lab == child)) < min_points:
        return lab.copy(), piv.copy()
    radius = float(np.linalg.norm(q[pair] - q[pair].mean(0), axis=1).max())
    c = np.zeros(2)
    new = lab.copy()
    for _ in range(int(iters)):
        if min(np.count_nonzero(pair & (new == parent)), np.count_nonzero(pair & (new == child))) < min_points:
            break
        (m0, d0), (m1, d1) = _line(q[pair & (new == parent)]), _line(q[pair & (new == child)])
        M = np.stack([d0, -d1], 1)
        if abs(np.linalg.det(M)) > _MIN_SINE:
            s = np.linalg.solve(M, m1 - m0)[0]
            x = m0 + s * d0
            if np.linalg.norm(x - q[pair].mean(0)) <= radius:
                c = x
        dist = []
        for m, d in ((m0, d0), (m1, d1)):
            r = d if (m - c) @ d >= 0 else -d
            w = q - c
            along = np.clip(w @ r, 0.0, None)
            dist.append(np.linalg.norm(w - along[:, None] * r, axis=1))
        new = np.where(pair, np.where(dist[0] <= dist[1], parent, child), lab)
    return new, piv + c @ E


def plane_axis(points: np.ndarray, part_label: np.ndarray, parent: int, child: int, axis: np.ndarray,
               flat: float = 0.05, extent: float = 0.05) -> np.ndarray:
    """A revolute joint's direction as the line where its two parts' planes meet, when both parts are planar
    (``axis_from_planes``; an addition to the paper): each part's plane normal is the least-variance direction of its
    points; a part is planar when its smallest variance is under ``flat`` times its middle one and its middle one over
    ``extent`` times its largest (a slab, not a bar: an eyeglasses temple is a bar and keeps ``axis``).

    Args:
        points: ``(N, 3)`` camera frame (metres). part_label: ``(N,)`` slots. parent, child: the joint's slots.
        axis: ``(3,)`` the current direction, kept when a part is not planar, has fewer than
            :data:`HINGE_MIN_POINTS` points, or the planes are within ~6 deg of parallel (a laptop open flat or shut).

    Returns:
        ``(3,)`` unit direction, signed to agree with ``axis``.
    """
    ax = np.asarray(axis, dtype=np.float64)
    normals = []
    for q in (parent, child):
        Q = np.asarray(points, dtype=np.float64)[np.asarray(part_label) == q]
        if len(Q) < HINGE_MIN_POINTS:
            return ax
        w, v = np.linalg.eigh(np.cov((Q - Q.mean(0)).T))  # ascending variances
        if not (w[0] < flat * w[1] and w[1] > extent * w[2]):
            return ax
        normals.append(v[:, 0])
    a = np.cross(normals[0], normals[1])
    if np.linalg.norm(a) < 0.1:
        return ax
    a /= np.linalg.norm(a)
    return a if a @ ax >= 0 else -a


#: A child part is a bar in a view when its largest variance exceeds this multiple of its middle one (fixed before
#: any measurement: an eyeglasses temple's is 30 or more, a laptop lid's under 3).
BAR_RATIO = 4.0
#: :func:`bar_axis_choice` takes a rank only when its mean squared cosine is under this share of the next rank's.
BAR_MARGIN = 0.25


def bar_axis_choice(points: np.ndarray, part_label: np.ndarray, joint_type, joint_parts,
                    min_points: int = HINGE_MIN_POINTS) -> list[int | None]:
    """Per joint, the rank of the parent's principal direction that a bar-shaped child turns about (``bar_axes``;
    an addition to the paper, fitted on a method's own training-split predictions, no labels).

    A revolute child that is a bar (its largest variance over :data:`BAR_RATIO` times its middle one) turns about an
    axis perpendicular to its length; where that axis is one of the parent's principal directions (an eyeglasses
    front's height), the child's length ``u`` is perpendicular to it in every view. Over the views where both parts
    have ``min_points`` points and the child is a bar, the mean of ``(u . e_k)^2`` is taken for each of the parent's
    principal directions ``e_k`` (rank 0 the largest variance); the smallest wins if it is under :data:`BAR_MARGIN`
    times the next one and at least 8 views gave it.

    Args:
        points: ``(B, N, 3)`` views (camera frame, metres). part_label: ``(B, N)`` int slots.
        joint_type: ``(J,)`` 0 revolute, 1 prismatic. joint_parts: ``(J, 2)`` (parent, child) slots.

    Returns:
        Per joint the rank (0, 1 or 2), or None (a prismatic joint, a child that is not a bar, no clear rank).

    Raises:
        InputError: mismatched shapes.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(part_label)
    jp = np.asarray(joint_parts).reshape(-1, 2)
    jt = np.asarray(joint_type).reshape(-1)
    if pts.ndim != 3 or pts.shape[-1] != 3 or lab.shape != pts.shape[:2] or len(jp) != len(jt):
        raise InputError(f"bar_axis_choice needs points (B, N, 3), part_label (B, N) and one (parent, child) per "
                         f"joint type; got {pts.shape}, {lab.shape}, {len(jp)} parts, {len(jt)} types")
    out: list[int | None] = []
    for j in range(len(jt)):
        pa, ch = int(jp[j, 0]), int(jp[j, 1])
        cos2 = []
        for b in range(len(pts) if int(jt[j]) == 0 else 0):  # a prismatic joint has no bar axis
            Qp, Qc = pts[b][lab[b] == pa], pts[b][lab[b] == ch]
            if len(Qp) < min_points or len(Qc) < min_points:
                continue
            wc, vc = principal_axes(Qc)
            if wc[0] < BAR_RATIO * wc[1]:
                continue
            cos2.append((principal_axes(Qp)[1].T @ vc[:, 0]) ** 2)
        if len(cos2) < 8:
            out.append(None)
            continue
        m = np.mean(cos2, axis=0)
        order = np.argsort(m)
        out.append(int(order[0]) if m[order[0]] < BAR_MARGIN * m[order[1]] else None)
    return out


def bar_axis(points: np.ndarray, part_label: np.ndarray, parent: int, rank: int, axis: np.ndarray,
             min_points: int = HINGE_MIN_POINTS) -> np.ndarray:
    """One view's axis of a joint whose bar-shaped child turns about its parent's principal direction of ``rank``
    (:func:`bar_axis_choice`): that direction of the parent's points, signed to agree with ``axis (3,)``; ``axis``
    kept when the parent has fewer than ``min_points`` points or that direction's variance is within 10 % of a
    neighbour's (not a direction the points fix).

    Args:
        points: ``(N, 3)`` camera frame (metres). part_label: ``(N,)`` slots. parent: the joint's parent slot.
        rank: 0, 1 or 2 (the largest variance first). axis: ``(3,)`` the current direction.

    Returns:
        ``(3,)`` unit direction."""
    ax = np.asarray(axis, dtype=np.float64)
    Q = np.asarray(points, dtype=np.float64)[np.asarray(part_label) == parent]
    if len(Q) < min_points:
        return ax
    w, v = principal_axes(Q)
    near = [w[k] for k in (rank - 1, rank + 1) if 0 <= k < 3]
    if any(abs(w[rank] - x) < 0.1 * max(w[rank], x, 1e-18) for x in near):
        return ax
    a = v[:, rank]
    return a if a @ ax >= 0 else -a


def hinge_prediction(points: np.ndarray, out: dict, joint_type, joint_parts, iters: int = HINGE_ITERS,
                     min_points: int = HINGE_MIN_POINTS, axis_from_planes: bool = False,
                     bar_axes: list | None = None) -> dict:
    """:func:`hinge_fit` for every view and revolute joint of a prediction.

    Args:
        points: ``(B, N, 3)`` the views (camera frame, metres).
        out: the one-pass prediction: ``part_label (B, N)``, ``joint_axis (B, J, 3)``, ``joint_pivot (B, J, 3)``
            (camera frame, metres); other entries are passed through.
        joint_type: ``(J,)`` 0 revolute, 1 prismatic (prismatic joints are skipped).
        joint_parts: ``(J, 2)`` (parent slot, child slot) per joint, in the order the joints are fitted.
        axis_from_planes: after the fit, also re-estimate each revolute axis where its two parts are planar
            (:func:`plane_axis` on the re-split points), fit again about it, and re-estimate it once more.
        bar_axes: per joint a rank from :func:`bar_axis_choice` (or None): that joint's axis becomes the parent's
            principal direction of that rank (:func:`bar_axis`, in place of the planes' axis) and its pivot the two
            lines' intersection about it (:func:`hinge_fit`); its split is kept.

    Returns:
        A copy of ``out`` with ``part_label`` and ``joint_pivot`` (and, with ``axis_from_planes``, ``joint_axis``)
        replaced, and ``hinge_changed (B,)`` (the share of
        each view's points that changed part) and ``hinge_pivot_move (B, J)`` (metres).

    Raises:
        InputError: mismatched shapes or non-finite values (see :func:`hinge_fit`).
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(out["part_label"]).astype(np.int64)
    axis, pivot = np.asarray(out["joint_axis"], np.float64), np.asarray(out["joint_pivot"], np.float64)
    jt = np.asarray(joint_type).reshape(-1)
    jp = np.asarray(joint_parts).reshape(-1, 2)
    B = pts.shape[0] if pts.ndim == 3 else -1
    if pts.ndim != 3 or lab.shape != pts.shape[:2] or axis.shape != (B, len(jt), 3) or pivot.shape != axis.shape \
            or len(jp) != len(jt):
        raise InputError(f"hinge_prediction needs points (B, N, 3), part_label (B, N), joint_axis and joint_pivot "
                         f"(B, J, 3) and J joint types and parts; got {pts.shape}, {lab.shape}, {axis.shape}, "
                         f"{pivot.shape}, {len(jt)} types, {len(jp)} parts")
    new_lab, new_piv, new_axis = lab.copy(), pivot.copy(), axis.copy()
    for b in range(B):
        for j in range(len(jt)):
            if int(jt[j]) != 0:
                continue
            pa, ch = int(jp[j, 0]), int(jp[j, 1])
            rank = None if bar_axes is None else bar_axes[j]
            if rank is not None:  # a bar child: the axis from the parent's principal direction, the pivot from the
                # two lines about it; the split is kept (a shut bar lies along its parent: no two rays to split by)
                new_axis[b, j] = bar_axis(pts[b], new_lab[b], pa, int(rank), axis[b, j], min_points)
                new_piv[b, j] = hinge_fit(pts[b], new_lab[b], pivot[b, j], new_axis[b, j], pa, ch, iters,
                                          min_points)[1]
                continue
            new_lab[b], new_piv[b, j] = hinge_fit(pts[b], new_lab[b], pivot[b, j], axis[b, j], pa, ch, iters,
                                                  min_points)
            if axis_from_planes:
                a = plane_axis(pts[b], new_lab[b], pa, ch, axis[b, j])
                new_lab[b], new_piv[b, j] = hinge_fit(pts[b], new_lab[b], new_piv[b, j], a, pa, ch, iters, min_points)
                new_axis[b, j] = plane_axis(pts[b], new_lab[b], pa, ch, a)
    res = dict(out)
    res["part_label"] = new_lab
    res["joint_pivot"] = new_piv.astype(np.asarray(out["joint_pivot"]).dtype)
    res["joint_axis"] = new_axis.astype(np.asarray(out["joint_axis"]).dtype)
    res["hinge_changed"] = (new_lab != lab).mean(1)
    res["hinge_pivot_move"] = np.linalg.norm(new_piv - pivot, axis=-1)
    res["hinge_axis_turn"] = np.degrees(np.arccos(np.clip((new_axis * axis).sum(-1) / np.maximum(
        np.linalg.norm(new_axis, axis=-1) * np.linalg.norm(axis, axis=-1), 1e-12), -1.0, 1.0)))
    return res


def hinge_info(result: dict, axis_from_planes: bool = False, bar_axes: list | None = None) -> dict:
    """What predictions record of the step (their ``info["hinge"]``), from :func:`hinge_prediction`'s output and
    whether it re-estimated the axes (from the planes; ``bar_axes``: the ranks of :func:`bar_axis_choice`)."""
    move = np.asarray(result["hinge_pivot_move"])
    turn = np.asarray(result.get("hinge_axis_turn", np.zeros(0)))
    extra = {} if bar_axes is None else {"bar_axes": [None if r is None else int(r) for r in bar_axes]}
    return {"iters": HINGE_ITERS, "min_points": HINGE_MIN_POINTS, "axis_from_planes": bool(axis_from_planes), **extra,
            "axis_turn_deg_median": round(float(np.median(turn)), 3) if turn.size else 0.0,
            "changed_share_mean": round(float(np.mean(result["hinge_changed"])), 4),
            "pivot_move_m_median": round(float(np.median(move)), 5) if move.size else 0.0}


def hinge_predictions(dataset, preds, axis_from_planes: bool = False, axis_from_bars: bool = False):
    """The hinge step applied to a predictions file already written (``scapo predict`` output of any method, made
    without ``hinge``): what ``--option hinge=true`` would have given, without predicting again (the step reads only
    the prediction and the points). Each sample's joints are its own ``joint_type``/``joint_parts`` rows.

    Args:
        dataset: the dataset folder (or an opened dataset of any split) the predictions were made on.
        preds: :class:`~scapo.eval.predictions.Predictions` (or a path to one).
        axis_from_planes: also the axes (:func:`hinge_prediction`; the label is then ``<method>+hinge-axis``).
        axis_from_bars: also the axes of bar-shaped children (:func:`bar_axis_choice` on the file's own
            training-split predictions, then :func:`bar_axis` per view; the label gets ``-bar``).

    Returns:
        New :class:`~scapo.eval.predictions.Predictions`: ``part_label`` and ``joint_pivot`` replaced, the label
        ``<method>+hinge``, ``info["hinge"]`` (:func:`hinge_info`) and ``info["hinge_source"]`` (the source's label).

    Raises:
        PredictionError: the predictions are of another dataset (its hash), already hinged, or name samples the
            dataset lacks; ``axis_from_bars`` on a file without training-split predictions. DatasetError: not a
            dataset.
    """
    from scapo.errors import PredictionError
    from scapo.eval.predictions import Predictions

    p = preds if isinstance(preds, Predictions) else Predictions.load(preds)
    if "hinge" in p.info:
        raise PredictionError(f"predictions of {p.method!r} already went through the hinge step")
    if axis_from_bars and not (p.split == "train").any():
        raise PredictionError(f"predictions of {p.method!r} hold no training-split views to choose the bar axes on; "
                              "predict the training split too")
    points = _points_of(dataset, p)
    lab, piv, axis = p.part_label.copy(), p.joint_pivot.copy(), p.joint_axis.copy()
    changed, moves, turns = np.zeros(len(p)), [], []
    rows = np.arange(len(p))
    ranks = None
    for jt, jp in {(tuple(p.joint_type[r]), tuple(map(tuple, p.joint_parts[r]))) for r in rows}:
        sub = rows[[tuple(p.joint_type[r]) == jt and tuple(map(tuple, p.joint_parts[r])) == jp for r in rows]]
        train = sub[p.split[sub] == "train"]
        ranks = bar_axis_choice(points[train], p.part_label[train], jt, jp) if axis_from_bars and len(train) else \
            [None] * len(jt) if axis_from_bars else None
        o = hinge_prediction(points[sub], {"part_label": p.part_label[sub], "joint_axis": p.joint_axis[sub],
                                           "joint_pivot": p.joint_pivot[sub]}, jt, jp,
                             axis_from_planes=axis_from_planes, bar_axes=ranks)
        lab[sub], piv[sub], axis[sub], changed[sub] = (o["part_label"], o["joint_pivot"], o["joint_axis"],
                                                       o["hinge_changed"])
        moves.append(o["hinge_pivot_move"].ravel())
        turns.append(o["hinge_axis_turn"].ravel())
    moves, turns = (np.concatenate(x) if x else np.zeros(0) for x in (moves, turns))
    info = {**p.info, "hinge": hinge_info({"hinge_changed": changed, "hinge_pivot_move": moves,
                                           "hinge_axis_turn": turns}, axis_from_planes, ranks),
            "hinge_source": p.method}
    kw = {k: getattr(p, k) for k in ("instance_id", "view_id", "split", "part_pose", "joint_parts", "joint_type",
                                     "joint_state", "T_cam_obj")}
    return Predictions(method=f"{p.method}+hinge" + ("-axis" if axis_from_planes else "") +
                       ("-bar" if axis_from_bars else ""), part_label=lab,
                       joint_pivot=piv, joint_axis=axis, needs_alignment=p.needs_alignment,
                       supervision=dict(p.supervision), dataset_hash=p.dataset_hash, info=info, **kw)


# ------------------------------------------------------------------------------------------- part frames
#: Fewest views a part needs for its offset (:func:`fit_part_frames`); with fewer it keeps the method's rotations.
FRAME_MIN_VIEWS = 8
#: A view's hinge chirality is used only when the sine between its two parts' directions exceeds this (~6 deg).
_FRAME_MIN_SINE = 0.1


def _across(Q: np.ndarray, pivot: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """``(3,)`` the direction a part runs away from its hinge, across the axis: the first principal direction of the
    points' offsets from ``pivot`` with their components along ``axis`` removed, signed towards their mean."""
    d = Q - pivot
    d = d - np.outer(d @ axis, axis)
    m = d.mean(0)
    _, _, vt = np.linalg.svd(d - m, full_matrices=False)
    return vt[0] if vt[0] @ m >= 0 else -vt[0]


def part_axes(points: np.ndarray, out: dict, joint_type, joint_parts,
              min_points: int = HINGE_MIN_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Each part's axes read from its hinge, per view (``hinge_frames``; an addition to the paper).

    For a revolute joint with unit axis ``a`` and pivot ``c`` (the prediction's, after :func:`hinge_prediction`), each
    of its two parts runs away from the hinge along ``u`` (:func:`_across`: the principal direction of its points
    seen along ``a``, signed from the pivot towards them: a laptop's base towards its front edge, the lid towards its
    top edge, an eyeglasses temple towards its tip). The sign of ``a`` is fixed by the pair's chirality,
    ``(u_parent x u_child) . a > 0``, so both signs come from the geometry alone. A part's axes are then
    ``E = [a, u, a x u]`` (columns, camera frame): rigid with the part, so ``R_p^T E`` is one constant rotation in
    the part's canonical coordinates for every view where the part and its hinge are found. A part on several
    joints (an eyeglasses front) takes its first revolute joint in ``joint_parts`` order, in every view: where that
    joint is shut the part keeps the method's rotation (it once fell through to the next joint, whose
    axes sit in the part at another offset, so that a front whose first temple was shut turned by a half turn: 25 %
    of the aligned rung's val views with the true split).

    Args:
        points: ``(B, N, 3)`` camera frame (metres). out: a prediction with ``part_label (B, N)``,
            ``joint_axis (B, J, 3)``, ``joint_pivot (B, J, 3)`` and ``part_pose (B, P, 4, 4)`` (for P).
        joint_type: ``(J,)`` 0 revolute, 1 prismatic (prismatic joints give no axes).
        joint_parts: ``(J, 2)`` (parent slot, child slot). min_points: fewest points a part needs in a view.

    Returns:
        ``E (B, P, 3, 3)`` float64 rotations (identity where not found) and ``ok (B, P)`` bool: found (both parts
        of the joint have ``min_points`` points and their directions are more than ~6 deg from parallel, i.e. the
        joint is neither shut nor open flat).

    Raises:
        InputError: mismatched shapes or non-finite points.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(out["part_label"])
    axis, pivot = np.asarray(out["joint_axis"], np.float64), np.asarray(out["joint_pivot"], np.float64)
    jt = np.asarray(joint_type).reshape(-1)
    jp = np.asarray(joint_parts).reshape(-1, 2)
    B, P = (pts.shape[0] if pts.ndim == 3 else -1), np.asarray(out["part_pose"]).shape[1]
    if pts.ndim != 3 or lab.shape != pts.shape[:2] or axis.shape != (B, len(jt), 3) or pivot.shape != axis.shape \
            or len(jp) != len(jt):
        raise InputError(f"part_axes needs points (B, N, 3), part_label (B, N), joint_axis and joint_pivot (B, J, 3) "
                         f"and J joint types and parts; got {pts.shape}, {lab.shape}, {axis.shape}, {pivot.shape}, "
                         f"{len(jt)} types, {len(jp)} parts")
    if not (np.isfinite(pts).all() and np.isfinite(axis).all() and np.isfinite(pivot).all()):
        raise InputError("part_axes got NaN or infinite points, axes or pivots; drop them before predicting")
    E = np.tile(np.eye(3), (B, P, 1, 1))
    ok = np.zeros((B, P), dtype=bool)
    first: dict[int, int] = {}  # each part's first revolute joint: the only one its axes are read from
    for j in range(len(jt)):
        for q in map(int, jp[j]):
            if int(jt[j]) == 0 and q < P:
                first.setdefault(q, j)
    for b in range(B):
        for j in range(len(jt)):
            pa, ch = int(jp[j, 0]), int(jp[j, 1])
            n = np.linalg.norm(axis[b, j])
            mine = [q for q in (pa, ch) if first.get(q) == j]
            if not mine or n < 1e-9:
                continue
            a = axis[b, j] / n
            Qp, Qc = pts[b][lab[b] == pa], pts[b][lab[b] == ch]
            if len(Qp) < min_points or len(Qc) < min_points:
                continue
            up, uc = _across(Qp, pivot[b, j], a), _across(Qc, pivot[b, j], a)
            s = float(np.cross(up, uc) @ a)
            if abs(s) < _FRAME_MIN_SINE:  # shut or open flat
                continue
            a = a if s > 0 else -a
            for q, u in ((pa, up), (ch, uc)):
                if q in mine:
                    E[b, q] = np.stack([a, u, np.cross(a, u)], axis=1)
                    ok[b, q] = True
    return E, ok


def fit_part_frames(part_pose: np.ndarray, E: np.ndarray, ok: np.ndarray,
                    min_views: int = FRAME_MIN_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """Per part, the offset ``O_p`` with ``R_p O_p ~ E_p`` on most training views: where the part's hinge axes
    (:func:`part_axes`) sit in the method's canonical part frame (by consensus, :func:`scapo.steps.base_frame.
    fit_base_offset` with no symmetry group; no labels).

    Args:
        part_pose: ``(V, P, 4, 4)`` the method's part poses of training views. E, ok: :func:`part_axes` of them.
        min_views: fewest views with axes a part needs.

    Returns:
        ``O (P, 3, 3)`` float64 (identity for a part with too few views) and ``support (P,)``: the share of the
        part's views within 15 deg of its offset (0 where not fitted: that part keeps the method's rotations).

    Raises:
        InputError: shapes that do not match.
    """
    from scapo.steps.base_frame import fit_base_offset

    R = np.asarray(part_pose, dtype=np.float64)[..., :3, :3]
    E, ok = np.asarray(E, dtype=np.float64), np.asarray(ok, dtype=bool)
    if R.ndim != 4 or E.shape != R.shape or ok.shape != R.shape[:2]:
        raise InputError(f"fit_part_frames needs part_pose (V, P, 4, 4), E (V, P, 3, 3) and ok (V, P); got "
                         f"{np.shape(part_pose)}, {E.shape}, {ok.shape}")
    P = R.shape[1]
    O, support = np.tile(np.eye(3), (P, 1, 1)), np.zeros(P)
    for q in range(P):
        m = ok[:, q]
        if m.sum() >= max(int(min_views), 1):
            O[q], support[q], _ = fit_base_offset(R[m, q], E[m, q], group=np.eye(3)[None])
    return O, support


def snap_to_part_axes(out: dict, E: np.ndarray, ok: np.ndarray, offsets: np.ndarray, support: np.ndarray,
                      root: int = 0, object_offset: np.ndarray | None = None) -> dict:
    """Each part's rotation read from its hinge: ``R_p <- E_p O_p^T`` where the view's axes were found and the
    part's offset was fitted (``support > 0``); other parts and views keep the method's rotations. Translations
    (the canonical origins), joints, joint states and labels are kept. The object frame is the ``root`` part's:
    ``T_cam_obj``'s rotation becomes ``R_root C`` with ``C = object_offset`` where the root was snapped (the method's
    object frame need not be rigid with its root part: SCAPO's comes from the whole cloud), and turns with the root's
    correction elsewhere.

    Args:
        out: a prediction with ``part_pose (B, P, 4, 4)`` and ``T_cam_obj (B, 4, 4)`` (camera frame, metres).
        E, ok: :func:`part_axes` of its views. offsets, support: :func:`fit_part_frames` (on training views).
        root: the part whose frame is the object's (the base: :attr:`HingeFrames.base`). object_offset:
            ``C (3, 3)``, the rotation from that part's canonical frame to the method's object frame most training
            views share (default: the identity).

    Returns:
        A copy of ``out`` with ``part_pose`` and ``T_cam_obj`` turned and ``frame_snap_deg (B, P)`` float64, each
        part's correction angle (0 where kept).
    """
    from scapo.steps.base_frame import _angle

    pose = np.asarray(out["part_pose"], dtype=np.float64)
    use = np.asarray(ok, dtype=bool) & (np.asarray(support) > 0)[None]
    R_new = np.where(use[..., None, None], np.einsum("bpij,pkj->bpik", E, offsets), pose[..., :3, :3])
    delta = np.einsum("bpij,bpkj->bpik", R_new, pose[..., :3, :3])  # R_new R^T
    res = dict(out)
    new = pose.copy()
    new[..., :3, :3] = R_new
    res["part_pose"] = new.astype(np.asarray(out["part_pose"]).dtype)
    T = np.asarray(out["T_cam_obj"], dtype=np.float64).copy()
    C = np.eye(3) if object_offset is None else np.asarray(object_offset, dtype=np.float64)
    T[:, :3, :3] = np.where(use[:, int(root), None, None], R_new[:, int(root)] @ C,
                            np.einsum("bij,bjk->bik", delta[:, int(root)], T[:, :3, :3]))
    res["T_cam_obj"] = T.astype(np.asarray(out["T_cam_obj"]).dtype)
    res["frame_snap_deg"] = np.where(use, _angle(delta, np.eye(3)), 0.0)
    return res


def kinematic_root(joint_parts, num_parts: int) -> int:
    """The lowest part slot that is no joint's child (0 for a part with no joints)."""
    children = {int(c) for _, c in np.asarray(joint_parts).reshape(-1, 2)}
    return next((q for q in range(int(num_parts)) if q not in children), 0)


#: ``view_prior``: the training views' root axes must lie within this angle (deg) of their consensus ...
PRIOR_DEG = 45.0
#: ... in at least this share of the views, or the prior is not used (views from the whole sphere spread too far).
PRIOR_SHARE = 0.5


def _swap_pair(label: np.ndarray, a: int, b: int) -> np.ndarray:
    out = label.copy()
    out[label == a], out[label == b] = b, a
    return out


class HingeFrames:
    """The ``hinge_frames`` step of a trained method: offsets fitted on training views, then each view's part
    rotations read from its hinges (:func:`part_axes`, :func:`fit_part_frames`, :func:`snap_to_part_axes`). Applied
    after the hinge step (it reads the re-split labels and pivot). It reads only the method's own prediction and the
    points: no ground truth, no training.

    With ``view_prior`` (the option ``hinge_view_prior=true``), each view also chooses which of its base joint's two
    parts is the base (:meth:`fit` chooses the base slot): a laptop's base and lid are exchanged by a half-turn about
    the bisector of the opening, and a network can give the base's slot to the lid in a whole view, turning every part
    by 180 deg (the views are the same across training seeds: ``results/canonical_ladder/hinge/`` (at 9a79e15)). Each
    training
    view offers two hypotheses for the base's camera-frame axes ``E_base``: its base slot's, and the other part's
    with the two exchanged; when the views come from a limited range of viewpoints (the paper's), one orientation
    ``M`` is reached by most views with one of their two (:meth:`_fit_prior`), and a view takes the exchanged split
    when its exchanged ``E_base`` lies nearer ``M`` than its own. The prior is used only when at least
    :data:`PRIOR_SHARE` of the training views reach :data:`PRIOR_DEG` of ``M`` (not under views from the whole
    sphere); like the refinement's upright prior, it is a viewpoint prior fitted on the training split, with no
    labels.

    Args:
        joint_type: ``(J,)``; joint_parts: ``(J, 2)`` the method's joints. view_prior: see above.

    Raises:
        ConfigError: no revolute joint (a drawer's prismatic joint has no hinge to read).
    """

    def __init__(self, joint_type, joint_parts, view_prior: bool = False):
        self.joint_type = np.asarray(joint_type).reshape(-1)
        self.joint_parts = np.asarray(joint_parts).reshape(-1, 2)
        if not (self.joint_type == 0).any():
            raise ConfigError("hinge_frames reads each part's rotation from a revolute joint (a hinge); this "
                              "object's joints are " + (", ".join("revolute" if t == 0 else "prismatic"
                                                                  for t in self.joint_type) or "none")
                              + ": predict without hinge_frames")
        self.view_prior = bool(view_prior)
        self.prior: np.ndarray | None = None
        """``(3, 3)`` the consensus of the training views' root axes (camera frame); None when not used."""
        self.prior_share = float("nan")
        self.offsets: np.ndarray | None = None
        self.support: np.ndarray | None = None
        self.object_offset = np.eye(3)
        self.base = kinematic_root(self.joint_parts, int(self.joint_parts.max()) + 1 if self.joint_parts.size else 1)
        """The part slot taken as the base (the object frame's; chosen on the training views by :meth:`fit`)."""

    def fit(self, points: np.ndarray, out: dict) -> HingeFrames:
        """Fit on training views ``points (V, N, 3)`` and the method's hinged prediction of them, with no labels:

        1. the base slot: the part whose hinge axes spread least over the views where every part has axes (it turns
           with the viewpoint only; :func:`scapo.steps.base_frame.choose_base_slot`, which keeps the kinematic
           root unless another slot spreads least in 95 % of bootstrap resamples);
        2. with ``view_prior``, the prior (the consensus of the base's axes) and each training view's split;
        3. each part's offset (:func:`fit_part_frames`) and the object frame's to the base's (the consensus of
           ``R_base^T R_obj``, :func:`scapo.steps.base_frame.fit_base_offset`)."""
        from scapo.steps.base_frame import choose_base_slot, fit_base_offset

        E, ok = part_axes(points, out, self.joint_type, self.joint_parts)
        pose = np.asarray(out["part_pose"], dtype=np.float64)
        P = pose.shape[1]
        self.base = kinematic_root(self.joint_parts, P)
        every = ok.all(1)
        if every.sum() >= FRAME_MIN_VIEWS:
            axes = np.tile(np.eye(4), (int(every.sum()), P, 1, 1))
            axes[..., :3, :3] = E[every]
            slot, _ = choose_base_slot(axes)
            if slot != 0:
                self.base = slot
        if self.view_prior:
            other = self._fit_prior(points, out, E, ok)
            out, E, ok, _ = self._choose_root(points, out, E, ok, other)
        self.offsets, self.support = fit_part_frames(pose, E, ok)
        T = np.asarray(out["T_cam_obj"], dtype=np.float64)[:, :3, :3]
        if len(T):
            self.object_offset = fit_base_offset(pose[:, self.base, :3, :3], T, group=np.eye(3)[None])[0]
        return self

    def _fit_prior(self, points: np.ndarray, out: dict, E: np.ndarray, ok: np.ndarray, candidates: int = 128):
        """The view prior ``M`` (:attr:`prior`): each training view offers two hypotheses for the base's axes, its
        base slot's (``E``) and, with the base joint's two parts exchanged, the other part's; ``M`` is the hypothesis
        (of up to ``candidates`` evenly spaced ones) that the most views reach within :data:`PRIOR_DEG` with either of
        theirs, refined to the chordal mean of the nearer hypotheses of those views. A method that gives the base's
        slot to the child in half of its views still has one base orientation that most views reach. Returns the
        exchanged split's ``(labels, E, ok)`` (None without a base joint), which :meth:`_choose_root` reuses."""
        from scapo.steps.base_frame import _angle

        pair, b = self._root_pair(), self.base
        if pair is None:
            return None
        other = _swap_pair(np.asarray(out["part_label"]), *pair)
        E2, ok2 = part_axes(points, {**out, "part_label": other}, self.joint_type, self.joint_parts)
        valid = ok[:, b] | ok2[:, b]
        H = np.concatenate([E[ok[:, b], b], E2[ok2[:, b], b]])
        if valid.sum() < FRAME_MIN_VIEWS:
            return other, E2, ok2
        C = H[np.unique(np.linspace(0, len(H) - 1, min(len(H), int(candidates))).round().astype(int))]
        d1 = np.where(ok[None, :, b], _angle(E[None, :, b], C[:, None]), np.inf)  # (C, V)
        d2 = np.where(ok2[None, :, b], _angle(E2[None, :, b], C[:, None]), np.inf)
        near = (np.minimum(d1, d2) < PRIOR_DEG) & valid[None]
        k = int(near.sum(1).argmax())
        self.prior_share = float(near[k].sum() / valid.sum())
        if self.prior_share < PRIOR_SHARE:
            self.prior = None
            return other, E2, ok2
        pick = np.where((d1[k] <= d2[k])[:, None, None], E[:, b], E2[:, b])[near[k]]
        U, _, Vt = np.linalg.svd(pick.sum(0))
        self.prior = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
        return other, E2, ok2

    def _root_pair(self) -> tuple[int, int] | None:
        for (pa, ch), t in zip(self.joint_parts, self.joint_type):
            if int(t) == 0 and self.base in (int(pa), int(ch)):
                return int(pa), int(ch)
        return None

    def _choose_root(self, points: np.ndarray, out: dict, E: np.ndarray, ok: np.ndarray, exchanged=None):
        """The ``view_prior`` step: per view, the split (as predicted or with the base's joint's two parts exchanged;
        ``exchanged``: that split's ``(labels, E, ok)`` when already computed) whose base axes lie nearer the prior.
        Returns (out, E, ok, swapped (B,) bool)."""
        from scapo.steps.base_frame import _angle

        B = len(ok)
        pair = self._root_pair()
        if self.prior is None or pair is None:
            return out, E, ok, np.zeros(B, dtype=bool)
        lab = np.asarray(out["part_label"])
        if exchanged is None:
            other = _swap_pair(lab, *pair)
            E2, ok2 = part_axes(points, {**out, "part_label": other}, self.joint_type, self.joint_parts)
        else:
            other, E2, ok2 = exchanged
        root = self.base
        swap = ok[:, root] & ok2[:, root] & (_angle(E2[:, root], self.prior) < _angle(E[:, root], self.prior))
        res = dict(out)
        res["part_label"] = np.where(swap[:, None], other, lab).astype(lab.dtype)
        return (res, np.where(swap[:, None, None, None], E2, E), np.where(swap[:, None], ok2, ok), swap)

    def __call__(self, points: np.ndarray, out: dict) -> dict:
        """:func:`snap_to_part_axes` on a hinged prediction of ``points (B, N, 3)``.

        Raises:
            InputError: called before :meth:`fit`, or mismatched shapes.
        """
        if self.offsets is None:
            raise InputError("hinge_frames needs its offsets fitted on a training split first (fit)")
        E, ok = part_axes(points, out, self.joint_type, self.joint_parts)
        out, E, ok, swapped = self._choose_root(points, out, E, ok)
        P = np.asarray(out["part_pose"]).shape[1]
        res = snap_to_part_axes(out, E, ok, self.offsets, self.support, min(self.base, P - 1), self.object_offset)
        res["frame_swapped"] = swapped
        if "joint_state" in out and swapped.any():
            res["joint_state"] = self.exchanged_states(out["joint_state"], swapped)
        return res

    def exchanged_states(self, joint_state, swapped) -> np.ndarray:
        """``joint_state (B, J)`` (rad / m) with the base joint's state negated in the ``swapped (B,)`` views: when
        its parent and child exchange points, the joint's state is the old child's motion seen from the other part,
        which about the same axis and pivot is the opposite turn (the evaluator matches the exchanged joint with its
        parent and child reversed and negates it back). Without this the view prior's exchanged views score their
        state with the wrong sign (measured in ``results/table1_paper_hinge_5min/joint_state_sign.md`` (at 9a79e15))."""
        js = np.array(joint_state, dtype=np.float64, copy=True)
        pair = self._root_pair()
        if pair is None:
            return js
        sw = np.asarray(swapped, dtype=bool)
        for j, (pa, ch) in enumerate(self.joint_parts):
            if {int(pa), int(ch)} == set(pair):
                js[sw, j] = -js[sw, j]
        return js

    def info(self, result: dict | None = None) -> dict:
        """What predictions record (``info["hinge_frames"]``): each part's offset support on the training views and,
        given a result, the share of part rotations replaced and their median correction (deg)."""
        d = {"support": np.round(self.support, 4).tolist() if self.support is not None else [], "base": int(self.base)}
        if result is not None:
            snap = np.asarray(result["frame_snap_deg"])
            d["replaced_share"] = round(float((snap > 0).mean()), 4) if snap.size else 0.0
            d["snap_deg_median"] = round(float(np.median(snap[snap > 0])), 2) if (snap > 0).any() else 0.0
        if self.view_prior:
            d["view_prior"] = {"used": self.prior is not None, "train_share": round(self.prior_share, 4)}
            if result is not None and "frame_swapped" in result:
                d["view_prior"]["swapped_share"] = round(float(np.mean(result["frame_swapped"])), 4)
        return d


def hinge_frame_predictions(dataset, preds, view_prior: bool = False):
    """The ``hinge_frames`` step applied to a predictions file already written with the hinge step (``+hinge`` or
    ``+hinge-axis``): offsets fitted on the file's own training-split predictions (a self-supervised method's file
    holds them), then every sample's part rotations read from its hinges; what ``--option hinge_frames=true`` gives.

    Args:
        dataset: the dataset folder (or an opened dataset) the predictions were made on.
        preds: :class:`~scapo.eval.predictions.Predictions` (or a path to one).
        view_prior: also choose each view's root part by the training views' prior (:class:`HingeFrames`).

    Returns:
        New :class:`~scapo.eval.predictions.Predictions` with ``part_pose`` and ``T_cam_obj`` turned (and, with
        ``view_prior``, ``part_label`` exchanged in the views that take the other split), the label
        ``<method>+hinge-frames`` (``+view-prior``) and ``info["hinge_frames"]``; in the exchanged views the base
        joint's state is negated (:meth:`HingeFrames.exchanged_states`).

    Raises:
        PredictionError: not hinged, already through this step, no training-split samples, another dataset, or
            samples the dataset lacks; more than one joint structure.
    """
    from scapo.errors import PredictionError
    from scapo.eval.predictions import Predictions

    p = preds if isinstance(preds, Predictions) else Predictions.load(preds)
    if "hinge" not in p.info:
        raise PredictionError(f"predictions of {p.method!r} did not go through the hinge step; hinge_frames reads "
                              "its re-split labels and pivots: run bench/diagnostics/hinge_rows.py on them first")
    if "hinge_frames" in p.info:
        raise PredictionError(f"predictions of {p.method!r} already went through the hinge_frames step")
    if not (p.split == "train").any():
        raise PredictionError(f"predictions of {p.method!r} hold no training-split samples to fit the hinge frames' "
                              "offsets on (a supervised method's file has none: predict with --option "
                              "hinge_frames=true instead)")
    if len({(tuple(t), tuple(map(tuple, j))) for t, j in zip(p.joint_type, p.joint_parts)}) != 1:
        raise PredictionError(f"predictions of {p.method!r} mix joint structures; hinge_frames needs one")
    pts = _points_of(dataset, p)
    step = HingeFrames(p.joint_type[0], p.joint_parts[0], view_prior=view_prior)
    fields = {k: getattr(p, k) for k in ("part_label", "part_pose", "joint_axis", "joint_pivot", "T_cam_obj",
                                         "joint_state")}
    tr = p.split == "train"
    step.fit(pts[tr], {k: v[tr] for k, v in fields.items()})
    o = step(pts, fields)
    kw = {k: getattr(p, k) for k in ("instance_id", "view_id", "split", "joint_parts", "joint_type",
                                     "joint_axis", "joint_pivot")}
    return Predictions(method=f"{p.method}+hinge-frames" + ("+view-prior" if view_prior else ""),
                       part_label=o["part_label"], part_pose=o["part_pose"], T_cam_obj=o["T_cam_obj"],
                       joint_state=np.asarray(o["joint_state"], dtype=np.float64),
                       needs_alignment=p.needs_alignment, supervision=dict(p.supervision),
                       dataset_hash=p.dataset_hash, info={**p.info, "hinge_frames": step.info(o)}, **kw)


def prediction_arrays(dataset, p, fields=("points",)) -> dict[str, np.ndarray]:
    """The dataset's ``fields`` (e.g. ``points``, or ground truth such as ``part_label``) for each sample of
    predictions ``p``, in the predictions' order (every split they name).

    Raises:
        PredictionError: predictions of another dataset, or samples the dataset lacks."""
    from scapo.data import load
    from scapo.data.dataset import ArticulationDataset
    from scapo.errors import PredictionError

    root = dataset.root if isinstance(dataset, ArticulationDataset) else dataset
    out: dict[str, np.ndarray] = {}
    for split in np.unique(p.split):
        d = load(root, str(split))
        if p.dataset_hash and d.card.get("dataset_hash") and p.dataset_hash != d.card.get("dataset_hash"):
            raise PredictionError(f"predictions of {p.method!r} were made on dataset {p.dataset_hash[:12]}, not on "
                                  f"{root} ({str(d.card.get('dataset_hash'))[:12]})")
        a = d.arrays(list(fields))
        key = {(int(i), int(v)): k for k, (i, v) in enumerate(zip(a["instance_id"], a["view_id"]))}
        rows = np.flatnonzero(p.split == split)
        try:
            src = np.array([key[(int(p.instance_id[r]), int(p.view_id[r]))] for r in rows], dtype=np.int64)
        except KeyError as e:
            raise PredictionError(f"predictions of {p.method!r} name sample {e.args[0]} (instance, view), which the "
                                  f"{split} split of {root} lacks") from None
        for f in fields:
            if f not in out:
                out[f] = np.zeros((len(p),) + a[f].shape[1:], dtype=a[f].dtype)
            out[f][rows] = a[f][src]
    return out


def _points_of(dataset, p) -> np.ndarray:
    """``(M, N, 3)`` float64 the dataset's points of each sample of predictions ``p``, in their order."""
    return prediction_arrays(dataset, p, ("points",))["points"].astype(np.float64)
