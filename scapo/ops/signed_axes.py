"""The principal axes of a part signed by where the other parts lie (numpy; an addition to the paper).

Used by SCAPO's prediction option ``base_frame=parts`` (:mod:`scapo.steps.base_frame`, which turns these
``ValueError`` into ``scapo:`` input errors) and by its training switch ``TrainConfig.stage2_frame = "parts"``
(:mod:`scapo.models.train`). Measured in ``docs/canonical_ladder.md``, "The base's axes signed by the
other parts".
"""

from __future__ import annotations

import functools

import numpy as np


def principal_axes(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The variances ``(3,)``, largest first, and the matching unit directions as columns ``(3, 3)`` of the points
    ``Q (n, 3)`` (``n >= 2``; float64)."""
    w, v = np.linalg.eigh(np.cov((Q - Q.mean(0)).T))
    return w[::-1], v[:, ::-1]


PLANE_TOL = 0.1
"""``plane_axes``: a point is on the plane when it lies within this share of the points' largest standard deviation
of it (fixed before measuring; 0.05 gave the same frames on the eyeglasses' val views)."""

PLANE_TRIALS = 256
"""``plane_axes``: the number of three-point planes tried."""

AXES = ("pca", "plane")
"""How :func:`parts_signed_axes` finds the base's directions: ``"pca"`` the principal axes of all its points,
``"plane"`` those of the points on its dominant plane (:func:`plane_axes`)."""


@functools.lru_cache(maxsize=4096)  # one draw per point count: 6 KB each
def _plane_triples(n: int, trials: int) -> np.ndarray:
    """``(trials, 3)`` indices of the three points of each plane :func:`plane_axes` tries on ``n`` points: a fixed
    random draw (seed 0, three distinct points per plane), the same for every cloud of ``n`` points (cached: the draw
    costs more than the fit; read-only)."""
    rng = np.random.default_rng(0)
    tri = np.stack([rng.choice(n, 3, replace=False) for _ in range(trials)])
    tri.setflags(write=False)
    return tri


def plane_axes(Q: np.ndarray, tol: float = PLANE_TOL, trials: int = PLANE_TRIALS) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_axes` of the points of ``Q (n, 3)`` (``n >= 3``, float64) that lie on its dominant plane: of
    ``trials`` planes through three of the points (a fixed random draw, so the result is deterministic), the one
    with the most points within ``tol`` times the largest standard deviation of ``Q``. A slab-shaped base part
    (a laptop's base, an eyeglasses' front) keeps its own axes where a segmentation gives it some points of a child
    part: those leave the plane, where they would turn the principal axes of all the points (an addition to the
    paper; measured in ``docs/canonical_ladder.md``, "The base's plane").

    Returns:
        the variances ``(3,)``, largest first, and the directions as columns ``(3, 3)``, as :func:`principal_axes`;
        those of all of ``Q`` where no plane has more than three points.
    """
    Q = np.asarray(Q, dtype=np.float64)
    w, v = principal_axes(Q)
    if len(Q) < 4:
        return w, v
    tri = _plane_triples(len(Q), int(trials))
    a, b, c = Q[tri[:, 0]], Q[tri[:, 1]], Q[tri[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    good = norm > 1e-12
    if not good.any():
        return w, v
    n, a = n[good] / norm[good, None], a[good]
    dist = np.abs(np.einsum("tk,nk->tn", n, Q) - (n * a).sum(1)[:, None])
    on = dist < float(tol) * np.sqrt(max(w[0], 0.0))
    best = on[np.argmax(on.sum(1))]
    if best.sum() <= 3:
        return w, v
    return principal_axes(Q[best])


def _signed_candidates(points: np.ndarray, part_label: np.ndarray, slot: int, min_points: int, axes: str = "pca"):
    """Per view the base's directions ``V (3, 3)`` (columns, largest variance first; ``axes``: :data:`AXES`), the
    other parts' centroid's offset along them in units of the base's spread ``(3,)`` (signed), and whether both sets
    have ``min_points`` points."""
    if axes not in AXES:
        raise ValueError(f"unknown base axes {axes!r}; use one of {', '.join(AXES)}")
    out = []
    for x, lab in zip(points, part_label):
        base, other = x[lab == int(slot)], x[(lab != int(slot)) & (lab >= 0)]
        if len(base) < max(int(min_points), 4) or len(other) < max(int(min_points), 4):
            out.append((np.eye(3), np.zeros(3), False))
            continue
        w, v = plane_axes(base) if axes == "plane" else principal_axes(base)
        out.append((v, (v.T @ (other.mean(0) - base.mean(0))) / np.sqrt(np.maximum(w, 1e-18)), True))
    return out


def children_agreement(points: np.ndarray, part_label: np.ndarray, slot: int = 0, min_points: int = 16,
                       candidates: list | None = None) -> tuple[np.ndarray, int]:
    """Per rank of the base's principal directions, the share ``(3,)`` of views where every other part (each slot
    with ``min_points`` points, at least two of them) lies on the same side of the base's centroid along it, and the
    number of such views. A mirror pair (an eyeglasses' temples) straddles the axis its mirror plane is normal to, so
    that axis has a low share and its sign, read from the parts' centroid, is a coin toss. ``candidates``: the views'
    :func:`_signed_candidates` when already computed (their principal directions are reused)."""
    if candidates is None:
        candidates = _signed_candidates(points, part_label, slot, min_points)
    agree, views = np.zeros(3), 0
    for (v, _, found), x, lab in zip(candidates, points, part_label):
        if not found:  # fewer than min_points of the base or of the other parts
            continue
        kids = [x[lab == k] for k in np.unique(lab) if k >= 0 and k != int(slot) and (lab == k).sum() >= min_points]
        if len(kids) < 2:
            continue
        base = x[lab == int(slot)]
        sides = np.sign(np.stack([v.T @ (k.mean(0) - base.mean(0)) for k in kids]))
        agree += (sides == sides[0]).all(0)
        views += 1
    return agree / max(views, 1), views


def choose_signed_pair(points: np.ndarray, part_label: np.ndarray, slot: int = 0,
                       min_points: int = 16, axes: str = "pca") -> tuple[int, int]:
    """The two ranks of the base's principal directions that ``base_frame=parts`` (:mod:`scapo.steps.base_frame`)
    and ``TrainConfig.stage2_frame = "parts"`` sign (:func:`parts_signed_axes`), chosen on training views with no
    labels. Where views show two or more other parts, the two ranks along which all the other parts lie on one side
    of the base in the most views (:func:`children_agreement`; the rule below chose an eyeglasses front's
    width, which the temples straddle, in 2 of 12 runs, and those runs' frames failed), unless the third rank ties the
    second. Otherwise (a base with one child, a laptop) per view the two ranks along which the other parts' centroid
    lies farthest from the base's (in units of the base's spread along each); the pair most views give.

    Args:
        points: ``(V, N, 3)`` camera-frame clouds (metres). part_label: ``(V, N)`` int predicted parts (-1 none).
        slot: the base's part slot. min_points: fewest points the base and the other parts need in a view.
        axes: how the base's directions are found (:data:`AXES`).

    Returns:
        ``(i, j)`` with ``i < j`` in 0..2 (0 the largest variance).

    Raises:
        ValueError: shapes that do not match, an unknown ``axes``, or no view with enough points of both.
    """
    pts, lab = np.asarray(points, dtype=np.float64), np.asarray(part_label)
    if pts.ndim != 3 or pts.shape[-1] != 3 or lab.shape != pts.shape[:2]:
        raise ValueError(f"choose_signed_pair needs points (V, N, 3) and part_label (V, N), got {pts.shape} "
                         f"and {lab.shape}")
    candidates = _signed_candidates(pts, lab, slot, min_points, axes)  # one eigendecomposition per view for both rules
    share, views = children_agreement(pts, lab, slot, min_points, candidates)
    order = np.argsort(-share, kind="stable")
    if views and share[order[1]] > share[order[2]]:
        return tuple(sorted(int(k) for k in order[:2]))
    votes: dict[tuple[int, int], int] = {}
    for _, off, ok in candidates:
        if ok:
            pair = tuple(sorted(int(k) for k in np.argsort(-np.abs(off))[:2]))
            votes[pair] = votes.get(pair, 0) + 1
    if not votes:
        raise ValueError(f"no training view has {min_points} points of the base (slot {slot}) and of the "
                         "other parts; base_frame=parts needs the base and its children segmented")
    return max(sorted(votes), key=votes.__getitem__)


def parts_signed_axes(points: np.ndarray, part_label: np.ndarray, pair: tuple[int, int], slot: int = 0,
                      min_points: int = 16, axes: str = "pca") -> tuple[np.ndarray, np.ndarray]:
    """The base's principal axes with their signs from the other parts (``base_frame=parts``,
    :mod:`scapo.steps.base_frame`; ``TrainConfig.stage2_frame = "parts"``).

    Per view: the principal directions of the points labelled ``slot`` (largest variance first; with ``axes="plane"``
    those of its points on its dominant plane, :func:`plane_axes`); those of the ranks
    in ``pair`` (:func:`choose_signed_pair`) each signed towards the centroid of the points of the other parts; the
    third the cross product that makes the columns a rotation.

    Args:
        points: ``(V, N, 3)`` camera-frame clouds (metres). part_label: ``(V, N)`` int predicted parts (-1 none).
        pair: the two signed ranks. slot, min_points, axes: as :func:`choose_signed_pair`.

    Returns:
        ``E (V, 3, 3)`` float64 rotations (columns: the axes in rank order, camera frame; identity where not found)
        and ``ok (V,)`` bool (both sets have ``min_points`` points and neither signed offset is zero).

    Raises:
        ValueError: shapes that do not match, non-finite points, a pair that is not two distinct ranks in 0..2, or an
            unknown ``axes``.
    """
    pts, lab = np.asarray(points, dtype=np.float64), np.asarray(part_label)
    i, j = (int(k) for k in pair)
    if pts.ndim != 3 or pts.shape[-1] != 3 or lab.shape != pts.shape[:2] or not (0 <= i < j <= 2):
        raise ValueError(f"parts_signed_axes needs points (V, N, 3), part_label (V, N) and two ranks i < j in "
                         f"0..2; got {pts.shape}, {lab.shape}, {pair}")
    if not np.isfinite(pts).all():
        raise ValueError("parts_signed_axes got NaN or infinite points; drop them before predicting")
    k = 3 - i - j
    E = np.tile(np.eye(3), (len(pts), 1, 1))
    ok = np.zeros(len(pts), dtype=bool)
    for n, (v, off, found) in enumerate(_signed_candidates(pts, lab, slot, min_points, axes)):
        if not found or off[i] == 0 or off[j] == 0:
            continue
        e = v * np.sign(off)[None]
        e[:, k] = np.cross(e[:, (k + 1) % 3], e[:, (k + 2) % 3])
        E[n], ok[n] = e, True
    return E, ok
