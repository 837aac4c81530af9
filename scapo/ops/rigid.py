"""Rigid transforms and joint motions (numpy, float64), shared by the simulator, methods and evaluator.

Conventions: 4x4 homogeneous transforms act on column vectors, ``p' = R p + t``; a transform
named ``T_a_b`` maps coordinates in frame ``b`` to frame ``a``. Rotations are 3x3 matrices;
angles are radians. Camera frames are OpenCV (x right, y down, z forward) unless the name says
``gl`` (OpenGL: x right, y up, z backward).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: Maps OpenGL camera coordinates (SAPIEN's ``Position`` picture) to OpenCV camera coordinates.
R_CV_GL = np.diag([1.0, -1.0, -1.0])

#: Rotation from SAPIEN's camera-entity axes (x forward, y left, z up) to OpenCV camera axes:
#: ``R_world_sapiencam = R_world_cvcam @ R_CV_SAPIEN``.
R_CV_SAPIEN = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def as_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack rotations ``R (..., 3, 3)`` and translations ``t (..., 3)`` into ``(..., 4, 4)``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``T (..., 4, 4)`` (uses ``R^T``, so T must be rigid)."""
    T = np.asarray(T, dtype=np.float64)
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    t = -np.einsum("...ij,...j->...i", R, T[..., :3, 3])
    return as_transform(R, t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T (4, 4)`` or ``(..., 4, 4)`` to ``points (..., N, 3)``; returns float64 ``(..., N, 3)``."""
    T = np.asarray(T, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    return np.einsum("...ij,...nj->...ni", T[..., :3, :3], points) + T[..., None, :3, 3]


def normalize(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along the last axis. Raises ValueError for (near-)zero vectors."""
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < eps):
        raise ValueError("cannot normalise a zero-length vector")
    return v / n


def rotation_about_axis(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` by ``angle`` (rad, right-hand rule) about unit ``axis (..., 3)``.

    This is ``ExpSO3([d]_x a)`` of the paper (Sec. 3.2, bone transformation).
    """
    axis = normalize(axis)
    rotvec = axis * np.asarray(angle, dtype=np.float64)[..., None]
    return Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(rotvec.shape[:-1] + (3, 3))


def joint_motion(joint_type: int, axis: np.ndarray, pivot: np.ndarray, state: float) -> np.ndarray:
    """4x4 rigid motion of a child part for one joint, in the frame where ``axis``/``pivot`` live.

    Args:
        joint_type: 0 revolute (rotation by ``state`` rad about the line through ``pivot`` along
            ``axis``) or 1 prismatic (translation by ``state`` m along ``axis``).
        axis: (3,) unit direction. pivot: (3,) a point on the axis (ignored for prismatic).
        state: joint state relative to rest (rad or m).

    Returns:
        (4, 4) float64 transform ``M`` with ``p_moved = M p`` (paper Sec. 3.2: translate to the
        pivot, apply the motion, translate back).
    """
    axis = normalize(axis)
    if joint_type == 0:
        R = rotation_about_axis(axis, state)
        pivot = np.asarray(pivot, dtype=np.float64)
        return as_transform(R, pivot - R @ pivot)
    if joint_type == 1:
        return as_transform(np.eye(3), axis * float(state))
    raise ValueError(f"joint_type must be 0 (revolute) or 1 (prismatic), got {joint_type}")


def project_to_so3(R: np.ndarray) -> np.ndarray:
    """Closest rotation (Frobenius norm) to each ``R (..., 3, 3)``, via SVD with a det(+1) fix."""
    R = np.asarray(R, dtype=np.float64)
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(R.shape[:-2] + (3, 3))
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0, 1.0, d)
    return U @ D @ Vt


def closest_point_on_line(point: np.ndarray, direction: np.ndarray, query: np.ndarray | None = None) -> np.ndarray:
    """Point on the line ``point + s * direction`` closest to ``query`` (default: the origin)."""
    d = normalize(direction)
    p = np.asarray(point, dtype=np.float64)
    q = np.zeros_like(p) if query is None else np.asarray(query, dtype=np.float64)
    s = np.sum((q - p) * d, axis=-1, keepdims=True)
    return p + s * d


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera pose ``T_world_cam (4, 4)`` in the OpenCV convention, looking from ``eye`` at ``target``.

    The camera's +z points at the target and its -y is as close to ``up`` as possible.
    Raises ValueError when ``eye == target`` or the view direction is parallel to ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = normalize(np.asarray(target, dtype=np.float64) - eye)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: view direction is parallel to the up vector")
    x = normalize(x)
    y = np.cross(z, x)
    return as_transform(np.stack([x, y, z], axis=1), eye)


def sapien_camera_pose(T_world_cam: np.ndarray) -> np.ndarray:
    """Convert an OpenCV camera pose to the 4x4 pose of a SAPIEN camera entity (x fwd, y left, z up)."""
    T = np.array(T_world_cam, dtype=np.float64)
    T[:3, :3] = T[:3, :3] @ R_CV_SAPIEN
    return T


def relative_motion_to_joint(M: np.ndarray, joint_type: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Recover (axis, pivot, state) from a relative rigid motion ``M (4, 4)`` of a child part.

    Inverse of :func:`joint_motion`. For revolute joints the axis and angle come from the
    rotation vector of ``M[:3, :3]`` (angle in [0, pi]); the pivot is the least-squares solution
    of ``(I - R) c = t`` with minimum norm, i.e. the point of the axis closest to the origin.
    For prismatic joints ``axis = t / |t|`` and ``state = |t|``, pivot is the origin.

    Raises:
        ValueError: if the motion is (near) identity, where the axis is undefined.
    """
    M = np.asarray(M, dtype=np.float64)
    R, t = project_to_so3(M[:3, :3]), M[:3, 3]
    if joint_type == 0:
        rotvec = Rotation.from_matrix(R).as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        if angle < 1e-6:
            raise ValueError("relative rotation is identity: revolute axis undefined")
        axis = rotvec / angle
        pivot = np.linalg.lstsq(np.eye(3) - R, t, rcond=1e-6)[0]
        return axis, closest_point_on_line(pivot, axis), angle
    if joint_type == 1:
        dist = float(np.linalg.norm(t))
        if dist < 1e-9:
            raise ValueError("relative translation is zero: prismatic axis undefined")
        return t / dist, np.zeros(3), dist
    raise ValueError(f"joint_type must be 0 (revolute) or 1 (prismatic), got {joint_type}")
