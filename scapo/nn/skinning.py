"""Joint-aware blend skinning (paper Sec. 3.2): Gaussian bones, bone transforms, blended deformation.

All functions are batched torch code in the model's normalised canonical units; rigid transforms
are ``(..., 4, 4)`` acting on column vectors.

- :func:`skinning_weights`: ``W_i^p = (s_i - O_p)^T Q_p (s_i - O_p)`` with ``Q_p = V_p^T Lambda_p V_p``
  and ``w_i = softmax(-W_i / gamma)`` (the Mahalanobis skinning field).
- :func:`joint_transform` / :func:`bone_transforms`: a revolute joint moves its child part by
  ``ExpSO3([d]_x a)`` about the line through the pivot ``c`` (translate to the pivot, rotate,
  translate back); a prismatic joint by ``d * a``. The base part (slot 0) stays fixed unless a root
  motion is given (it then moves about / along the root joint, see :func:`root_joint`); parts are
  chained along the kinematic tree.
- :func:`blend`: ``T_i = sum_p w_i^p T^p`` applied to ``[s_i; 1]`` (Eq. 2-4).
- :func:`cross_space_transforms`: ``T_X->Y`` per part (Sec. 3.2, cross-space alignment): the
  input's joint frame is carried onto the template's (``R_r d_x = d_y``, ``c_x -> c_y``), then the
  child rotates (or slides) by the state difference ``a_y - a_x`` about the template's joint.
"""

from __future__ import annotations

import torch

from scapo.ops.so3 import exp_so3, make_transform, rotation_between

EPS = 1e-8


def apply(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``T (B, 4, 4)`` applied to ``points (B, N, 3)``."""
    return points @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]


def apply_per_part(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``T (B, P, 4, 4)`` applied part by part to ``points (B, P, 3)`` (one point per part, e.g. the
    bone centres) -> ``(B, P, 3)``."""
    return torch.einsum("bpij,bpj->bpi", T[..., :3, :3], points) + T[..., :3, 3]


def joint_transform(joint_type: int, axis: torch.Tensor, pivot: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
    """Motion of a child part (paper Sec. 3.2): ``(B, 3), (B, 3), (B,)`` -> ``(B, 4, 4)``.

    Revolute: ``R = ExpSO3([d]_x a)``, ``t = c - R c`` (rotate about the line through ``c``).
    Prismatic: ``R = I``, ``t = d a``.
    """
    if joint_type == 0:
        R = exp_so3(axis, state)
        return make_transform(R, pivot - (R @ pivot.unsqueeze(-1)).squeeze(-1))
    if joint_type == 1:
        eye = torch.eye(3, dtype=axis.dtype, device=axis.device).expand(axis.shape[0], 3, 3)
        return make_transform(eye, axis * state.unsqueeze(-1))
    raise ValueError(f"joint_type must be 0 (revolute) or 1 (prismatic), got {joint_type}")


def root_joint(joint_parts) -> int:
    """Index of the root joint: the first joint whose parent is the base part (slot 0).

    Raises:
        ValueError: no joint has the base as its parent.
    """
    for j, (pa, _) in enumerate(joint_parts):
        if pa == 0:
            return j
    raise ValueError("no joint has the base part (slot 0) as its parent")


def bone_transforms(joint_types, joint_parts, axis: torch.Tensor, pivot: torch.Tensor, state: torch.Tensor,
                    num_parts: int, root: torch.Tensor | None = None) -> torch.Tensor:
    """Per-part transforms ``T^p (B, P, 4, 4)`` from joints ``axis, pivot (B, J, 3)``, ``state (B, J)``.

    The base part 0 is the identity, or, with a root motion ``root (B,)`` (rad / normalised units; an
    addition to the paper, ``ModelConfig.root_motion``), the motion of the root joint
    (:func:`root_joint`) by ``root``: the base then turns about (slides along) the root joint's axis,
    which absorbs a canonical frame that sits between the base and its child. Joint j moves its child
    part (``joint_parts[j] = (parent, child)``) relative to its parent, composed along the tree
    (joints must list parents first).
    """
    B = axis.shape[0]
    eye = torch.eye(4, dtype=axis.dtype, device=axis.device).expand(B, 4, 4)
    if root is not None:
        r = root_joint(joint_parts)
        eye = joint_transform(int(joint_types[r]), axis[:, r], pivot[:, r], root)
    T = [eye] + [None] * (num_parts - 1)
    for j, ((pa, ch), jt) in enumerate(zip(joint_parts, joint_types)):
        if T[pa] is None:
            raise ValueError(f"joint {j}: parent part {pa} has no transform yet (list parents first)")
        T[ch] = T[pa] @ joint_transform(int(jt), axis[:, j], pivot[:, j], state[:, j])
    if any(t is None for t in T):
        raise ValueError("every non-base part must be the child of one joint")
    return torch.stack(T, dim=1)


def skinning_weights(points: torch.Tensor, centers: torch.Tensor, orient: torch.Tensor, log_scale: torch.Tensor,
                     gamma: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Gaussian-bone skinning field.

    Args:
        points: (B, N, 3). centers: (B, P, 3) bone centres ``O_p`` (the keypoints).
        orient: (B, P, 3, 3) bone orientations ``V_p`` (rotation matrices).
        log_scale: (B, P, 3) log standard deviations; ``Lambda_p = diag(exp(-2 log_scale))``.
        gamma: softmax temperature.

    Returns:
        (weights (B, N, P) summing to 1 over P, Mahalanobis distances W (B, N, P)).
    """
    diff = points.unsqueeze(2) - centers.unsqueeze(1)  # (B, N, P, 3)
    local = torch.einsum("bpij,bnpj->bnpi", orient, diff) * torch.exp(-log_scale).unsqueeze(1)
    W = (local * local).sum(-1)
    return torch.softmax(-W / gamma, dim=-1), W


def blend(points: torch.Tensor, weights: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    """Blended rigid deformation ``x_i' = (sum_p w_i^p T^p) [x_i; 1]`` (Eq. 2-4).

    ``points (B, N, 3)``, ``weights (B, N, P)``, ``T (B, P, 4, 4)`` -> ``(B, N, 3)``.
    """
    moved = torch.einsum("bpij,bnj->bnpi", T[:, :, :3, :3], points) + T[:, None, :, :3, 3]  # (B, N, P, 3)
    return (weights.unsqueeze(-1) * moved).sum(2)


def cross_space_transforms(joint_types, joint_parts, num_parts: int, pivot_x, axis_x, state_x, pivot_y, axis_y,
                           state_y, root_x: torch.Tensor | None = None, root_y: torch.Tensor | None = None
                           ) -> torch.Tensor:
    """``T^p_{X->Y} (B, P, 4, 4)`` mapping the aligned input space to the template space.

    For the child of joint j: align the joint frames (``R_r d_x = d_y``; ``c_x -> c_y``), then move
    by the state difference about / along the template's joint: revolute
    ``ExpSO3([d]_x (a_y - a_x))`` about ``c_y``, prismatic ``d_y (a_y - a_x)``. The base part
    stays in place; with root motions ``root_x, root_y (B,)`` (see :func:`bone_transforms`) it is
    undone about the input's root joint and redone about the template's, and the children of the
    base turn (slide) by ``root_y - root_x`` more about the template's root joint. ``T_{Y->X}`` is the per-part inverse.
    """
    B = pivot_x.shape[0]
    eye = torch.eye(4, dtype=pivot_x.dtype, device=pivot_x.device).expand(B, 4, 4)
    base = T0 = None
    if root_x is not None and root_y is not None:
        r = root_joint(joint_parts)
        rt = int(joint_types[r])
        base = joint_transform(rt, axis_y[:, r], pivot_y[:, r], root_y - root_x)  # children: after the align
        T0 = joint_transform(rt, axis_y[:, r], pivot_y[:, r], root_y) @ joint_transform(rt, axis_x[:, r],
                                                                                       pivot_x[:, r], -root_x)
    T = [eye if base is None else T0] + [None] * (num_parts - 1)
    for j, ((pa, ch), jt) in enumerate(zip(joint_parts, joint_types)):
        R_r = rotation_between(axis_x[:, j], axis_y[:, j])
        align = make_transform(R_r, pivot_y[:, j] - (R_r @ pivot_x[:, j].unsqueeze(-1)).squeeze(-1))
        move = joint_transform(int(jt), axis_y[:, j], pivot_y[:, j], state_y[:, j] - state_x[:, j])
        T[ch] = move @ align if base is None or pa != 0 else base @ move @ align
    return torch.stack(T, dim=1)
