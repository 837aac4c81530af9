"""Branch correction of the stage-1 frames during stage 2 (an addition to the paper).

Stage 1 (paper Sec. 3.1) canonicalises each cloud by an SE(3)-equivariant auto-encoder. On shapes
whose largest part is near-symmetric its frames are bimodal: measured on the val split
(``results/scapo_upright_choice/`` (at 9a79e15)), a laptop's frame takes a half turn that swaps base and screen
on about 40 % of the views and eyeglasses are turned upside down on about 60 %. Stage 2 then fits
one template, one part split and one set of joints to canonical clouds that come in two
orientations, and the part split it finds mixes them (eyeglasses: a lens with the opposite temple).

This module makes the canonical clouds seen by stage 2 consistent, without labels, from the same
cue as the test-time upright prior (:func:`scapo.models.refine.upright_direction`): objects stand
on a support and the cameras look at them with little roll, so the camera's up ``v`` (camera
frame) expressed in a view's canonical frame, ``u_i = R_i^T v``, clusters around one canonical
direction ``d`` on the majority branch and around another, ``e``, on the other branch.

- fit (:func:`fit_branch`, once, at the start of stage 2, on the training clouds): ``d, v`` from
  ``upright_direction``; ``e`` by two-centre clustering of the ``u_i`` on the sphere (``d``'s centre
  fixed); the correction ``F`` (3, 3) takes ``e`` to (near) ``d``: among ``Rot(d, psi) F0`` (``F0`` the
  smallest rotation taking ``e`` to ``d``, ``psi`` on a grid) and the half turns taking ``e`` within
  45 deg of ``d``, the one whose corrected minority clouds ``F S_i`` lie closest (trimmed Chamfer) to
  the majority clouds. Inactive (``F = I``) when the
  minority branch is under ``min_fraction`` of the views or its centre within ``min_angle_deg`` of ``d``.
- apply (:func:`apply_branch`, in every stage-2 forward pass and at inference): a view whose ``u``
  is closer to ``e`` than to ``d`` gets the frame ``R F^T`` (its canonical cloud becomes ``F S``).

Frames: ``R (B, 3, 3)`` maps canonical to (normalised) camera coordinates; clouds ``S (B, n, 3)``
are canonical. Buffers of :class:`~scapo.models.scapo_model.SCAPOModel`: ``branch (3, 3)`` rows
``d, e, v`` (all zero: inactive) and ``branch_flip (3, 3)`` = ``F``.
"""

from __future__ import annotations

import math

import torch

from scapo.models.part_init import fibonacci_hemisphere
from scapo.ops.chamfer import trimmed_one_sided_chamfer
from scapo.ops.so3 import exp_so3

EPS = 1e-12


def rotation_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The smallest rotation ``(3, 3)`` taking unit vector ``a (3,)`` to unit vector ``b (3,)``; for
    antiparallel vectors a half turn about an axis perpendicular to ``a``."""
    a = a / a.norm().clamp_min(EPS)
    b = b / b.norm().clamp_min(EPS)
    k = torch.linalg.cross(a, b)
    if float(k.norm()) < 1e-9 and float(a @ b) < 0:  # antiparallel: any perpendicular axis
        k = torch.linalg.cross(a, torch.eye(3, dtype=a.dtype)[int(torch.argmin(a.abs()))])
    elif float(k.norm()) < 1e-9:
        return torch.eye(3, dtype=a.dtype)
    angle = torch.atan2(torch.linalg.cross(a, b).norm(), a @ b)
    return exp_so3(k / k.norm(), angle)


def axis_rotation(axis: torch.Tensor, angle: float) -> torch.Tensor:
    """Rotation ``(3, 3)`` by ``angle`` (rad) about ``axis (3,)`` (any length; Rodrigues, ``exp_so3``)."""
    return exp_so3(axis / axis.norm().clamp_min(EPS), torch.tensor(float(angle), dtype=axis.dtype))


def branch_of(R: torch.Tensor, branch: torch.Tensor) -> torch.Tensor:
    """Which views took the minority branch: ``R (B, 3, 3)`` frames, ``branch (3, 3)`` rows ``d, e, v``
    -> bool ``(B,)`` (``R^T v`` closer to ``e`` than to ``d``; all False when ``branch`` is zero)."""
    if not bool(branch.abs().sum() > 0):
        return torch.zeros(R.shape[0], dtype=torch.bool, device=R.device)
    d, e, v = branch.to(R)
    u = torch.einsum("bji,j->bi", R, v)
    return (u @ e) > (u @ d)


def apply_branch(R: torch.Tensor, branch: torch.Tensor, flip: torch.Tensor) -> torch.Tensor:
    """Corrected frames ``(B, 3, 3)``: ``R F^T`` for the minority-branch views (:func:`branch_of`),
    ``R`` otherwise. Differentiable in ``R``."""
    wrong = branch_of(R.detach(), branch)
    if not bool(wrong.any()):
        return R
    return torch.where(wrong[:, None, None], R @ flip.to(R).T, R)


def fit_branch(R: torch.Tensor, clouds: torch.Tensor, min_fraction: float = 0.05, min_angle_deg: float = 45.0,
               angles: int = 36, half_turns: int = 200, max_offset_deg: float = 45.0, pairs: int = 128,
               keep: float = 0.7, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Fit the branch correction from the stage-1 frames of training views.

    Args:
        R: (M, 3, 3) canonical -> camera frames of the views (no labels).
        clouds: (M, n, 3) the same views' canonical clouds ``R^T (x - t)`` (normalised units).
        min_fraction, min_angle_deg: the correction stays off when the minority branch holds fewer
            views or its centre is closer to ``d``.
        angles: grid of ``psi`` over [0, 2 pi). half_turns: axes (hemisphere grid) of the half turns
            also scored, those taking ``e`` within ``max_offset_deg`` of ``d`` (the branches of a
            near-symmetric shape are related by a half turn that need not map ``e`` exactly onto ``d``).
            pairs: (minority, majority) cloud pairs scored per candidate. keep: trimmed Chamfer fraction.

    Returns:
        (``branch (3, 3)`` rows ``d, e, v`` or zeros when off, ``F (3, 3)``, info dict: ``active``,
        ``minority_fraction``, ``angle_deg`` between the centres, ``candidates``, ``kind`` of the chosen
        one, ``offset_deg`` (angle between ``F e`` and ``d``), ``score`` and ``score_identity`` (the
        trimmed Chamfer of the chosen correction and of none)).

    Raises:
        ValueError: fewer than two views, or shapes that do not match.
    """
    from scapo.models.refine import upright_direction

    if R.dim() != 3 or R.shape[1:] != (3, 3) or clouds.dim() != 3 or clouds.shape[0] != R.shape[0]:
        raise ValueError(f"fit_branch needs R (M, 3, 3) and clouds (M, n, 3), got {tuple(R.shape)}, "
                         f"{tuple(clouds.shape)}")
    if R.shape[0] < 2:
        raise ValueError("fit_branch needs at least two views")
    Rd, S = R.double(), clouds.double()
    dv, _ = upright_direction(Rd)
    d, v = dv[0], dv[1]
    u = torch.einsum("bji,j->bi", Rd, v)
    far = u @ d < math.cos(math.radians(min_angle_deg))
    eye = torch.eye(3, dtype=R.dtype)
    off = torch.zeros(3, 3, dtype=R.dtype)
    info = {"active": False, "minority_fraction": 0.0, "angle_deg": float("nan")}
    if not bool(far.any()):
        return off, eye, info
    e = u[far].mean(0)
    e = e / e.norm().clamp_min(EPS)
    for _ in range(20):  # two-centre clustering on the sphere, the majority centre held at d
        wrong = (u @ e) > (u @ d)
        if not bool(wrong.any()):
            break
        e_new = u[wrong].mean(0)
        e_new = e_new / e_new.norm().clamp_min(EPS)
        if torch.allclose(e_new, e, atol=1e-10):
            break
        e = e_new
    wrong = (u @ e) > (u @ d)
    fraction = float(wrong.double().mean())
    angle = math.degrees(math.acos(max(-1.0, min(1.0, float(e @ d)))))
    info.update(minority_fraction=round(fraction, 4), angle_deg=round(angle, 2))
    if fraction < min_fraction or angle < min_angle_deg or int((~wrong).sum()) == 0:
        return off, eye, info
    g = torch.Generator().manual_seed(seed)
    iw, ir = torch.nonzero(wrong).squeeze(1), torch.nonzero(~wrong).squeeze(1)
    a = iw[torch.randint(len(iw), (pairs,), generator=g)]
    b = ir[torch.randint(len(ir), (pairs,), generator=g)]
    A, B = S[a].float(), S[b].float()  # scores only rank the candidates: single precision suffices

    def score(F: torch.Tensor) -> float:
        AF = A @ F.T.float()
        return float((trimmed_one_sided_chamfer(AF, B, keep) + trimmed_one_sided_chamfer(B, AF, keep)).mean())

    F0 = rotation_between(e, d)
    cands = [axis_rotation(d, 2.0 * math.pi * k / angles) @ F0 for k in range(angles)]
    for axis in fibonacci_hemisphere(half_turns, torch.float64):  # half turns taking e near d
        H = 2.0 * torch.outer(axis, axis) - torch.eye(3, dtype=torch.float64)
        if float((H @ e) @ d) >= math.cos(math.radians(max_offset_deg)):
            cands.append(H)
    scores = [score(F) for F in cands]
    k = min(range(len(cands)), key=scores.__getitem__)
    F = cands[k]
    offset = math.degrees(math.acos(max(-1.0, min(1.0, float((F @ e) @ d)))))
    info.update(active=True, candidates=len(cands), kind="half turn" if k >= angles else "e to d",
                offset_deg=round(offset, 2), score=scores[k], score_identity=score(torch.eye(3, dtype=S.dtype)))
    return torch.stack([d, e, v]).to(R.dtype), F.to(R.dtype), info
