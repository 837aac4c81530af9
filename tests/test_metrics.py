"""Metric functions against hand cases and naive loop references (SPEC section 8)."""

import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.eval.metrics import (
    axis_error_deg,
    iou_matrix,
    joint_state_error,
    line_distance,
    match_parts,
    origin_offset_difference,
    precision_under,
    relabel,
    rotation_error_deg,
    segmentation_iou,
)


# ----------------------------------------------------------------- naive references
def naive_rotation_error(Rp, Rg):
    U, _, Vt = np.linalg.svd(Rp)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    Rp = U @ D @ Vt
    c = (np.trace(Rg @ Rp.T) - 1) / 2
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def naive_line_distance(p1, d1, p2, d2):
    # minimise |p1 + s d1 - p2 - u d2| over a fine grid + local refinement (brute force)
    from scipy.optimize import minimize

    f = lambda x: np.linalg.norm(p1 + x[0] * d1 - p2 - x[1] * d2)  # noqa: E731
    return min(minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12}).fun
               for x0 in ([0, 0], [5, -5], [-5, 5]))


def naive_iou(pred, gt, p):
    inter = sum(1 for a, b in zip(pred, gt) if a == p and b == p)
    union = sum(1 for a, b in zip(pred, gt) if a == p or b == p)
    return inter / union if union else float("nan")


# ----------------------------------------------------------------- hand cases
def test_rotation_error_hand_cases():
    assert rotation_error_deg(np.eye(3), np.eye(3)) == pytest.approx(0.0, abs=1e-6)
    R = Rotation.from_rotvec([0, 0, math.radians(37)]).as_matrix()
    assert rotation_error_deg(R, np.eye(3)) == pytest.approx(37.0)
    assert rotation_error_deg(np.eye(3), R) == pytest.approx(37.0)
    R180 = Rotation.from_rotvec([math.pi, 0, 0]).as_matrix()
    assert rotation_error_deg(R180, np.eye(3)) == pytest.approx(180.0)
    # a scaled, noisy prediction is projected to SO(3) first
    assert rotation_error_deg(2.0 * R, R) == pytest.approx(0.0, abs=1e-6)


def test_rotation_error_matches_naive_reference():
    Rs = Rotation.random(20, random_state=0).as_matrix()
    Rg = Rotation.random(20, random_state=1).as_matrix()
    noisy = Rs + 0.05 * np.random.default_rng(0).normal(size=Rs.shape)
    got = rotation_error_deg(noisy, Rg)
    ref = [naive_rotation_error(a, b) for a, b in zip(noisy, Rg)]
    np.testing.assert_allclose(got, ref, atol=1e-6)


def test_axis_error_hand_cases():
    assert axis_error_deg([0, 0, 1.0], [0, 0, 1.0]) == pytest.approx(0.0)
    assert axis_error_deg([0, 0, -2.0], [0, 0, 1.0]) == pytest.approx(0.0)  # sign flip ignored
    assert axis_error_deg([1.0, 0, 0], [0, 0, 1.0]) == pytest.approx(90.0)
    assert axis_error_deg([1.0, 1.0, 0], [1.0, 0, 0]) == pytest.approx(45.0)


def test_line_distance_hand_cases_and_reference():
    # parallel lines: point-to-line distance
    assert line_distance([0, 0, 0], [0, 0, 1], [0.3, 0.4, 5.0], [0, 0, -1]) == pytest.approx(0.5)
    # identical line, different points and sign
    assert line_distance([0, 0, 2], [0, 0, -1], [0, 0, -7], [0, 0, 1]) == pytest.approx(0.0, abs=1e-12)
    # skew lines: x-axis and a y-parallel line at z = 2
    assert line_distance([0, 0, 0], [1, 0, 0], [3, 0, 2], [0, 1, 0]) == pytest.approx(2.0)
    rng = np.random.default_rng(0)
    for _ in range(10):
        p1, d1, p2, d2 = rng.normal(size=(4, 3))
        d1 /= np.linalg.norm(d1)
        d2 /= np.linalg.norm(d2)
        assert line_distance(p1, d1, p2, d2) == pytest.approx(naive_line_distance(p1, d1, p2, d2), abs=1e-5)


def test_segmentation_iou_matches_naive():
    rng = np.random.default_rng(0)
    gt = rng.integers(-1, 3, 200)
    pred = rng.integers(-1, 3, 200)
    got = segmentation_iou(pred, gt, 3)
    np.testing.assert_allclose(got, [naive_iou(pred, gt, p) for p in range(3)])
    np.testing.assert_allclose(segmentation_iou(gt, gt, 3), [1.0, 1.0, 1.0])
    assert math.isnan(segmentation_iou(np.zeros(5, int), np.zeros(5, int), 2)[1])


def test_iou_matrix_and_hungarian_matching_against_brute_force():
    rng = np.random.default_rng(1)
    for _ in range(5):
        gt = rng.integers(0, 3, 300)
        perm = rng.permutation(3)
        pred = perm[gt].copy()
        flip = rng.random(300) < 0.2
        pred[flip] = rng.integers(0, 3, flip.sum())
        M = iou_matrix(pred, gt, 3, 3)
        for s, p in itertools.product(range(3), range(3)):
            assert M[s, p] == pytest.approx(naive_iou(np.where(pred == s, 0, 1), np.where(gt == p, 0, 1), 0))
        slots = match_parts(pred, gt, 3)
        best = max(itertools.permutations(range(3)), key=lambda q: sum(M[q[p], p] for p in range(3)))
        assert tuple(slots) == best
        np.testing.assert_array_equal(slots, perm)
        np.testing.assert_array_equal(relabel(perm[gt], slots), gt)


def test_joint_state_error_units_and_precision():
    err = joint_state_error([0.1, 0.05], [0.0, 0.0], [0, 1])
    np.testing.assert_allclose(err, [math.degrees(0.1), 5.0])
    assert precision_under([1, 6, 2], [1, 1, 20], 5, 10) == pytest.approx(1 / 3)
    assert precision_under([np.nan], [0], 5, 5) == 0.0


def test_symmetry_aware_rotation_error_equals_a_brute_force_minimum_over_the_symmetry():
    """BOP-style: the error against the best symmetric ground truth. A part turned half a turn about its declared
    axis of symmetry scores 0; the same turn about another axis still scores 180; a continuous symmetry
    (a round door about its axis), discretised in 5 deg steps, forgives any turn about it to within 2.5 deg."""
    from scipy.spatial.transform import Rotation

    from scapo.eval.metrics import rotation_error_deg, symmetric_rotation_error_deg, symmetry_rotations

    R_gt = Rotation.random(20, random_state=3).as_matrix()
    half_z = Rotation.from_rotvec([0, 0, np.pi]).as_matrix()
    half_x = Rotation.from_rotvec([np.pi, 0, 0]).as_matrix()
    syms = symmetry_rotations(discrete=[half_z])
    assert syms.shape == (2, 3, 3)
    np.testing.assert_allclose(symmetric_rotation_error_deg(R_gt @ half_z, R_gt, syms), 0.0, atol=1e-6)
    np.testing.assert_allclose(symmetric_rotation_error_deg(R_gt @ half_x, R_gt, syms), 180.0, atol=1e-6)
    np.testing.assert_allclose(symmetric_rotation_error_deg(R_gt @ half_x, R_gt, syms[:1]),
                               rotation_error_deg(R_gt @ half_x, R_gt))  # identity only: the strict error
    # continuous: brute force over a fine sampling of turns about z agrees, and forgives any such turn
    cont = symmetry_rotations(continuous=[[0, 0, 1]], max_step_deg=5.0)
    assert len(cont) == 72
    R_pred = R_gt @ Rotation.from_rotvec(np.c_[np.zeros((20, 2)), np.linspace(0, 6, 20)]).as_matrix() \
        @ Rotation.from_rotvec([0.2, 0, 0]).as_matrix()
    fine = np.stack([Rotation.from_rotvec([0, 0, a]).as_matrix() for a in np.linspace(0, 2 * np.pi, 3601)])
    brute = np.min([rotation_error_deg(R_pred, R_gt @ S) for S in fine], axis=0)
    ours = symmetric_rotation_error_deg(R_pred, R_gt, cont)
    assert np.all(ours >= brute - 1e-6) and np.all(ours - brute < 2.6)
    np.testing.assert_allclose(brute, np.degrees(0.2), atol=0.2)  # only the tilt about x is left
    with pytest.raises(ValueError):
        symmetry_rotations(discrete=[2 * np.eye(3)])


def test_eaps_pivot_error_compares_distances_to_the_origin_even_when_the_predicted_axis_differs():
    """Hand case of the EAP protocol's pivot error (:func:`origin_offset_difference`): the centroid at the origin, the
    true axis the line x = 1 along z (distance 1); a predicted axis through (0, 2, 0) along x (distance 2, and 90 deg
    off) scores |2 - 1| = 1; one through (0, -1, 0) along x, just as wrong in direction, scores 0, since it lies as far
    from the centroid as the true one: the error reads distances to the centroid only, not where the lines lie."""
    o = np.zeros(3)
    gt_p, gt_d = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    assert origin_offset_difference(o, np.array([0, 2.0, 0]), np.array([1.0, 0, 0]), gt_p, gt_d) == pytest.approx(1.0)
    assert origin_offset_difference(o, np.array([0, -1.0, 0]), np.array([1.0, 0, 0]), gt_p, gt_d) == \
        pytest.approx(0.0, abs=1e-12)
    # the line-to-line error (SCAPO's protocol) of the second: the two lines are 1 apart (skew, perpendicular)
    assert line_distance(np.array([0, -1.0, 0]), np.array([1.0, 0, 0]), gt_p, gt_d) == pytest.approx(1.0)


def test_line_distance_of_nearly_parallel_lines_pinned_intersecting_and_skew():
    """The usual case of a good prediction, pinned by hand: axes 1 deg apart. Skew (the lines in the parallel planes
    z = 0 and z = 0.05) they are 0.05 apart whatever the angle; coplanar (offset 0.05 within the plane) they cross
    about 2.9 m away, so the line-to-line distance is 0 although the pivots are 0.05 apart near the object (a property
    of the metric, as ANCSH defines it); exactly parallel lines fall back to the point-to-line distance, 0.05."""
    eps = np.radians(1.0)
    d1, d2 = np.array([1.0, 0, 0]), np.array([np.cos(eps), np.sin(eps), 0])
    assert line_distance([0, 0, 0], d1, [0, 0, 0.05], d2) == pytest.approx(0.05, abs=1e-12)
    assert line_distance([0, 0, 0], d1, [0, 0.05, 0], d2) == pytest.approx(0.0, abs=1e-12)
    assert line_distance([0, 0, 0], d1, [0, 0.05, 0], d1) == pytest.approx(0.05, abs=1e-12)
    tiny = np.array([1.0, 1e-9, 0])  # below the parallel threshold: the parallel case's answer
    assert line_distance([0, 0, 0], d1, [0, 0.05, 0], tiny) == pytest.approx(0.05, abs=1e-9)
