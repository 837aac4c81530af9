"""Joints from part poses, shared by the methods that derive joints after the fact (ICP, NPCS-style,
EAP-style): the relative motion of a child part against its parent gives the axis, pivot and state.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from scapo.ops.rigid import invert_transform, relative_motion_to_joint


def rest_joints(a: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rest-state joints of a category in its object frame, pooled (median) over training samples.

    Args:
        a: training arrays with ``part_pose (M, P, 4, 4)``, ``joint_axis, joint_pivot (M, J, 3)`` (camera
            frame), ``joint_parts (M, J, 2)``, ``joint_type (M, J)`` and ``bbox_diag (M,)``.

    Returns:
        ``joint_parts (J, 2)``, ``joint_type (J,)``, unit ``rest_axis (J, 3)`` in the parent part's
        rest frame (the object frame), ``rest_pivot (J, 3)`` in the object frame divided by the
        instance's bbox diagonal (multiply by a scale to use it).
    """
    jp = np.asarray(a["joint_parts"][0])
    parent_inv = invert_transform(a["part_pose"][:, jp[:, 0]])
    axis_obj = np.einsum("mjik,mjk->mji", parent_inv[..., :3, :3], a["joint_axis"])
    pivot_obj = np.einsum("mjik,mjk->mji", parent_inv[..., :3, :3], a["joint_pivot"]) + parent_inv[..., :3, 3]
    axis = np.median(axis_obj, 0)
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    pivot = np.median(pivot_obj / np.asarray(a["bbox_diag"])[:, None, None], 0)
    return jp, np.asarray(a["joint_type"][0]), axis, pivot


def joint_from_part_poses(T_parent: np.ndarray, T_child: np.ndarray, joint_type: int, rest_axis: np.ndarray,
                          rest_pivot: np.ndarray, min_angle_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Joint axis and pivot (camera frame) and state of one joint from the poses of its two parts.

    The child's motion relative to its parent, ``M = T_parent^-1 T_child`` (both poses map the
    method's canonical frame to the camera), gives the axis and angle of the relative rotation and the
    pivot from ``(I - R) c = t`` (revolute), or the translation direction and length (prismatic), in
    the canonical frame (:func:`~scapo.ops.rigid.relative_motion_to_joint`). The sign is chosen to
    agree with ``rest_axis``, which also stands in when the motion is too small to define an axis
    (rotation under ``min_angle_deg``); the state is then the motion's component along it.

    Args:
        T_parent, T_child: ``(4, 4)`` part poses (canonical -> camera, metres).
        joint_type: 0 revolute, 1 prismatic.
        rest_axis, rest_pivot: ``(3,)`` the joint at rest in the canonical frame (unit axis; metres).

    Returns:
        ``(axis (3,), pivot (3,), state)`` with axis and pivot in the camera frame; state in rad or m.
    """
    M_rel = invert_transform(T_parent) @ T_child
    try:
        ax, pv, st = relative_motion_to_joint(M_rel, joint_type)
        if joint_type == 0 and np.degrees(st) < min_angle_deg:
            raise ValueError("small motion")
    except ValueError:
        ax, pv = rest_axis, rest_pivot
        if joint_type == 1:
            st = float(M_rel[:3, 3] @ rest_axis)
        else:
            st = float(Rotation.from_matrix(M_rel[:3, :3]).as_rotvec() @ rest_axis)
    if ax @ rest_axis < 0:
        ax, st = -ax, -st
    if joint_type == 1:
        pv = rest_pivot
    R, t = T_parent[:3, :3], T_parent[:3, 3]
    return R @ ax, R @ pv + t, float(st)
