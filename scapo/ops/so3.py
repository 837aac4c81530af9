"""Rotations and rigid transforms in torch (differentiable, batched over leading dimensions); the numpy
counterparts are in :mod:`scapo.ops.rigid`.

Conventions: a rotation ``R (..., 3, 3)`` acts on column vectors (``x' = R x``); a rigid transform
``T (..., 4, 4)`` is ``[[R, t], [0, 1]]``; angles are radians; a rotation vector ``w (..., 3)`` is
``angle * unit axis`` (scipy's ``Rotation.from_rotvec``). Every function keeps the dtype and device of its
input.
"""

from __future__ import annotations

import torch

EPS = 1e-8


def skew(v: torch.Tensor) -> torch.Tensor:
    """The hat map: skew-symmetric matrices ``[v]_x (..., 3, 3)`` of vectors ``v (..., 3)`` (``[v]_x u = v x u``)."""
    z = torch.zeros_like(v[..., 0])
    return torch.stack([
        torch.stack([z, -v[..., 2], v[..., 1]], -1),
        torch.stack([v[..., 2], z, -v[..., 0]], -1),
        torch.stack([-v[..., 1], v[..., 0], z], -1),
    ], -2)


def exp_so3(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """``ExpSO3([d]_x a)`` by Rodrigues' formula: unit ``axis (..., 3)``, ``angle (...)`` rad -> ``(..., 3, 3)``."""
    K = skew(axis)
    s = torch.sin(angle)[..., None, None]
    c = torch.cos(angle)[..., None, None]
    eye = torch.eye(3, dtype=axis.dtype, device=axis.device).expand(K.shape)
    return eye + s * K + (1 - c) * (K @ K)


def rotation_from_rotvec(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors ``w (..., 3)`` (rad) -> rotations ``(..., 3, 3)``; smooth (and differentiable) at ``w = 0``."""
    angle = torch.sqrt((w * w).sum(-1) + 1e-20)
    return exp_so3(w / angle.unsqueeze(-1), angle)


def log_so3(R: torch.Tensor) -> torch.Tensor:
    """Rotation vectors ``(..., 3)`` (rad, angle in [0, pi]) of rotations ``R (..., 3, 3)``: the inverse of
    :func:`rotation_from_rotvec`. Near a half turn the axis comes from the symmetric part of ``R`` (where the
    skew part vanishes); near the identity from the first-order term."""
    tr = R.diagonal(dim1=-2, dim2=-1).sum(-1)
    cos = ((tr - 1) / 2).clamp(-1.0, 1.0)
    angle = torch.arccos(cos)
    vee = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = torch.sin(angle)
    small = sin.abs() < 1e-4
    # generic and near-identity: w = angle / (2 sin angle) * vee, with angle / sin -> 1 at 0
    scale = torch.where(small, torch.full_like(angle, 0.5), angle / (2 * torch.where(small, torch.ones_like(sin), sin)))
    w = scale[..., None] * vee
    # near a half turn: R + I = 2 d d^T (1 - cos) / ... -> d from the largest column of (R + I) / 2
    half = small & (cos < 0)
    if bool(half.any()):
        B = (R + torch.eye(3, dtype=R.dtype, device=R.device)) / 2
        col = B.diagonal(dim1=-2, dim2=-1).argmax(-1)
        d = torch.gather(B, -1, col[..., None, None].expand(*B.shape[:-1], 1)).squeeze(-1)
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(EPS)
        sign = torch.where((d * vee).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(R.dtype)
        w = torch.where(half[..., None], sign * d * angle[..., None], w)
    return w


def rotation_from_6d(v1: torch.Tensor, v2: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Gram-Schmidt rotation (Zhou et al., CVPR 2019, the 6D representation): rotations ``(..., 3, 3)`` whose
    columns are ``v1`` normalised, ``v2`` made orthogonal to it and normalised, and their cross product; from
    two vectors ``(..., 3)`` each; equivariant under SO(3) (``R v1, R v2 -> R @ result``). Norms below ``eps``
    are clamped to it."""
    u1 = v1 / v1.norm(dim=-1, keepdim=True).clamp_min(eps)
    w = v2 - (v2 * u1).sum(-1, keepdim=True) * u1
    u2 = w / w.norm(dim=-1, keepdim=True).clamp_min(eps)
    return torch.stack([u1, u2, torch.cross(u1, u2, dim=-1)], dim=-1)


def rotation_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Smallest rotations ``R (..., 3, 3)`` with ``R a = b`` for unit vectors ``a, b (..., 3)``.

    Rodrigues with axis ``a x b``; for (nearly) opposite vectors the limit is a half turn, about an axis
    perpendicular to ``a``.
    """
    v = torch.cross(a, b, dim=-1)
    c = (a * b).sum(-1).clamp(-1.0, 1.0)
    s = v.norm(dim=-1)
    angle = torch.atan2(s, c)
    axis = v / (s.unsqueeze(-1) + EPS)
    helper = torch.where((a[..., :1].abs() < 0.9), torch.tensor([1.0, 0.0, 0.0], dtype=a.dtype, device=a.device),
                         torch.tensor([0.0, 1.0, 0.0], dtype=a.dtype, device=a.device))
    perp = torch.cross(a, helper, dim=-1)
    perp = perp / (perp.norm(dim=-1, keepdim=True) + EPS)
    axis = torch.where((s < 1e-6).unsqueeze(-1) & (c < 0).unsqueeze(-1), perp, axis)
    return exp_so3(axis, angle)


def make_transform(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Rigid transforms ``(..., 4, 4)`` from rotations ``R (..., 3, 3)`` and translations ``t (..., 3)``."""
    T = torch.zeros(R.shape[:-2] + (4, 4), dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T: torch.Tensor) -> torch.Tensor:
    """Inverses of rigid transforms ``T (..., 4, 4)`` (``[[R^T, -R^T t], [0, 1]]``)."""
    Rt = T[..., :3, :3].transpose(-1, -2)
    return make_transform(Rt, -(Rt @ T[..., :3, 3:4]).squeeze(-1))


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``T (B, 4, 4)`` applied to ``points (B, N, 3)`` -> ``(B, N, 3)``."""
    return points @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]
