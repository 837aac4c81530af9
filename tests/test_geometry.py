import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.ops.align import umeyama
from scapo.ops.rigid import (
    R_CV_GL,
    as_transform,
    closest_point_on_line,
    invert_transform,
    joint_motion,
    look_at,
    project_to_so3,
    relative_motion_to_joint,
    rotation_about_axis,
    transform_points,
)


def test_invert_and_transform_points():
    rng = np.random.default_rng(0)
    T = as_transform(Rotation.random(random_state=1).as_matrix(), rng.normal(size=3))
    p = rng.normal(size=(10, 3))
    np.testing.assert_allclose(transform_points(invert_transform(T), transform_points(T, p)), p, atol=1e-12)
    np.testing.assert_allclose(invert_transform(T) @ T, np.eye(4), atol=1e-12)


def test_rotation_about_axis_right_hand_rule():
    R = rotation_about_axis(np.array([0, 0, 1.0]), np.pi / 2)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_joint_motion_revolute_keeps_pivot_fixed_and_prismatic_translates():
    axis, pivot = np.array([0, 1.0, 0]), np.array([0.3, -0.2, 0.1])
    M = joint_motion(0, axis, pivot, 0.7)
    np.testing.assert_allclose(transform_points(M, pivot[None])[0], pivot, atol=1e-12)
    np.testing.assert_allclose(transform_points(M, (pivot + axis)[None])[0], pivot + axis, atol=1e-12)
    M = joint_motion(1, axis, pivot, 0.25)
    np.testing.assert_allclose(M[:3, 3], [0, 0.25, 0])
    with pytest.raises(ValueError):
        joint_motion(2, axis, pivot, 0.0)


@pytest.mark.parametrize("jt", [0, 1])
def test_relative_motion_to_joint_inverts_joint_motion(jt):
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    pivot = closest_point_on_line(np.array([0.2, 0.1, 0.4]), axis)
    M = joint_motion(jt, axis, pivot, 0.9 if jt == 0 else 0.3)
    a, p, s = relative_motion_to_joint(M, jt)
    np.testing.assert_allclose(a, axis, atol=1e-9)
    assert s == pytest.approx(0.9 if jt == 0 else 0.3)
    if jt == 0:
        np.testing.assert_allclose(p, pivot, atol=1e-9)
    with pytest.raises(ValueError):
        relative_motion_to_joint(np.eye(4), jt)


def test_project_to_so3_and_umeyama():
    R = Rotation.random(random_state=3).as_matrix()
    noisy = R + 1e-3 * np.random.default_rng(0).normal(size=(3, 3))
    Rp = project_to_so3(noisy)
    np.testing.assert_allclose(Rp @ Rp.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rp) == pytest.approx(1.0)
    src = np.random.default_rng(1).normal(size=(50, 3))
    T = as_transform(R, [0.1, 0.2, 0.3])
    T_est, s = umeyama(src, 2.0 * src @ R.T + T[:3, 3], with_scale=True)
    assert s == pytest.approx(2.0)
    T_est, _ = umeyama(src, transform_points(T, src))
    np.testing.assert_allclose(T_est, T, atol=1e-10)


def test_look_at_opencv_convention():
    T = look_at(np.array([-2.0, 0, 0]), np.zeros(3))
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)  # +z looks at the target
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # +y is down
    np.testing.assert_allclose(T[:3, 0], [0, -1, 0], atol=1e-12)  # +x is right (world -y seen from -x)
    np.testing.assert_allclose(R_CV_GL @ [0, 1, -1], [0, -1, 1])


def test_umeyama_returns_the_best_rotation_when_the_best_orthogonal_map_is_a_reflection():
    """``dst`` the mirror image of ``src`` through the plane of its least spread (``diag(1, 1, -1)``): the best
    orthogonal map is that reflection, the best rotation (Umeyama's sign correction, 1991, eq. 39) flips nothing, the
    identity, with the mirrored points' centroid as translation; a fit without the correction would return the
    reflection (det -1)."""
    src = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-0.5, 0.5) for z in (-0.1, 0.1)])  # a box's corners
    dst = src * [1.0, 1.0, -1.0] + [0.3, -0.2, 1.0]
    T, s = umeyama(src, dst)
    assert s == 1.0 and np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(T[:3, 3], [0.3, -0.2, 1.0], atol=1e-9)
