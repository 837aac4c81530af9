"""Test-time articulated refinement of a SCAPO prediction (an addition to the paper).

The network's pose comes from one forward pass; its part rotations carry the error of the stage-1
frame and of the predicted joint state. This step fits the network's own posed template to the
observed cloud, view by view, using nothing but that cloud (no labels), as an articulated ICP
started from the network's answer:

- model of the observation: the template in its rest state ``Y* (B, M, 3)`` with its skinning weights
  ``w_Y* (B, M, P)``, posed by the bone transforms of the template's own joints (pivot ``c_Y``, axis
  ``d_Y``) at the input's joint states ``a`` (and root state ``b`` with ``ModelConfig.root_motion``),
  then carried into the (normalised) camera frame by the stage-1 frame ``R_g exp([w]_x), t_g + dt``;
- objective per view: the mean squared distance from each observed point to its nearest model point
  (the one-sided Chamfer term ``X -> model``; the template is a whole shape and the observation a
  partial view, so the other direction would pull hidden template points onto visible ones);
- optimised over ``w, dt (B, 3)``, ``a (B, J)`` and ``b (B,)`` by Adam with a cosine schedule; the
  views of a batch are independent (the loss is a sum over views);
- segmentation: each observed point takes the part weights of its nearest point of the fitted template.
- starts (``RefineConfig.starts = "octahedral"``): the stage-1 frame of some views is 60-90 deg off,
  which a local fit does not undo; the 24 rotations ``C`` of the cube group, applied in the canonical
  frame (``R_g C``), are screened by a short fit each, the best is refined fully beside the network's
  start, and it replaces it only when its residual is lower by ``margin`` (180-degree flips of a
  laptop fit nearly as well as the truth, so the network's start keeps the benefit of the doubt).

Why these choices (posing with the template's own joints, no 180-degree flip starts, a margin for
alternative starts) and what each measured are recorded in ``results/cpu_preset_history.md``: a
laptop's two slabs fit nearly as well upside down, so a flipped start must not win on residual alone.

Speed: at batch 1 the loop is bound by the number of tensor operations, so the posed template is a
:class:`TemplatePoser` (constants precomputed, one bmm per step for blend and frame, all parameters in
one tensor) and the nearest neighbours are found without autograd; ``scapo bench perf --what model``
measures it (``results/perf/model_cpu.md``).
"""

from __future__ import annotations

import torch

from scapo.nn.outputs import SCAPOOutput
from scapo.nn.skinning import blend, bone_transforms
from scapo.nn.template_fit import (
    STAGE2_STARTS,
    RefineConfig,
    TemplatePoser,
    check_stage2_starts,
    fit_template,
    refine_from_dict,
)
from scapo.ops.groups import octahedral_rotations

__all__ = ["STAGE2_STARTS", "RefineConfig", "TemplatePoser", "camera_direction_in_frame", "check_stage2_starts",
           "posed_template", "refine_articulation", "refine_from_dict", "upright_direction"]
_fit = fit_template  # the fit, shared with scapo.steps.refine (scapo.nn.template_fit)


def camera_direction_in_frame(R: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """A camera-frame direction ``v (3,)`` in canonical frames ``R (..., 3, 3)`` (canonical -> camera): ``R^T v``."""
    return torch.einsum("...ji,j->...i", R, v.to(R.dtype).to(R.device))


def upright_direction(R: torch.Tensor, radius_deg: float = 45.0, iterations: int = 100) -> tuple[torch.Tensor, float]:
    """The upright prior of a run from the canonical frames ``R (M, 3, 3)`` of its training views.

    The capture setup holds one direction nearly fixed in both the camera and the object frames (the
    world's up: objects stand on a support, cameras look down at them with little roll). It is found
    without labels as the pair (camera direction ``v``, canonical direction ``d``) maximising the
    axial agreement ``mean_i (d . R_i^T v)^2`` (alternating top eigenvectors, from ``v`` = the camera's
    up, ``-y``); axial, so the views whose frame took the other, half-turned branch of a symmetric
    shape (``R_i^T v`` near ``-d``) support the same axis instead of cancelling it. The sign of ``d`` is
    that of the majority branch, then ``d`` is the mean of the ``R_i^T v`` within ``radius_deg`` of it.

    Returns:
        (``(2, 3)`` rows ``d`` (canonical frame) and ``v`` (camera frame), fraction of views whose
        ``R_i^T v`` lies within ``radius_deg`` of ``d``).

    Raises:
        ValueError: no frames.
    """
    if R.shape[0] == 0:
        raise ValueError("upright_direction needs at least one frame")
    Rd = R.reshape(-1, 3, 3).double()
    v = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)  # the camera's up (OpenCV camera frame)
    for _ in range(iterations):
        u = camera_direction_in_frame(Rd, v)
        d = torch.linalg.eigh(u.T @ u)[1][:, -1]
        w = Rd @ d  # d in each camera frame
        v_new = torch.linalg.eigh(w.T @ w)[1][:, -1]
        v_new = v_new if float(v_new @ v) >= 0 else -v_new
        if torch.allclose(v_new, v, atol=1e-10):
            break
        v = v_new
    u = camera_direction_in_frame(Rd, v)
    d = torch.linalg.eigh(u.T @ u)[1][:, -1]
    if float(((u @ d) >= 0).double().mean()) < 0.5:
        d = -d
    cos = torch.cos(torch.deg2rad(torch.tensor(float(radius_deg), dtype=u.dtype)))
    near = (u @ d) >= cos
    if near.any():
        d = u[near].mean(0)
        d = d / d.norm().clamp_min(1e-12)
    support = float(((u @ d) >= cos).double().mean())
    return torch.stack([d, v]).to(R.dtype), support


def posed_template(joint_types, joint_parts, num_parts: int, template_rest: torch.Tensor, weights: torch.Tensor,
                   pivot: torch.Tensor, axis: torch.Tensor, state: torch.Tensor, root: torch.Tensor | None,
                   R: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The template posed at joint states ``state (B, J)`` (and ``root (B,)``) and moved by ``R (B, 3, 3)``,
    ``t (B, 3)``: ``(points (B, M, 3), bone transforms (B, P, 4, 4))`` in the model's normalised units."""
    T = bone_transforms(joint_types, joint_parts, axis, pivot, state, num_parts, root)
    S = blend(template_rest, weights, T)
    return S @ R.transpose(1, 2) + t[:, None], T


def refine_articulation(cfg, X: torch.Tensor, out: SCAPOOutput, rc: RefineConfig,
                        upright: torch.Tensor | None = None) -> dict:
    """Fit the posed template of a SCAPO forward pass to the observed cloud (see module docstring).

    Args:
        cfg: the network's :class:`~scapo.models.scapo_model.ModelConfig`.
        X: (B, N, 3) float observed points, normalised units (``SCAPOModel.normalize``), camera frame.
        out: the outputs of ``SCAPOModel.forward(X, stage=2)``.
        rc: the settings; ``rc.steps`` must be positive.
        upright: ``(2, 3)`` the run's upright prior (:func:`upright_direction`), used when
            ``rc.upright_deg > 0`` and ``rc.starts == "octahedral"``; None: no upright prior.

    Returns:
        dict of detached tensors: ``R (B, 3, 3)``, ``t (B, 3)`` (the refined frame), ``state (B, J)``,
        ``root (B,)`` or None, ``T (B, P, 4, 4)`` (bone transforms, canonical rest -> aligned),
        ``pivot, axis (B, J, 3)`` (the template's joints, canonical frame), ``weights (B, N, P)`` (each
        observed point takes the skinning weights of its nearest point of the fitted template; their
        argmax is the refined segmentation), ``residual (B,)`` (the final
        objective: mean squared distance, normalised units) and ``residual_start (B,)`` (before).

    Raises:
        ValueError: ``rc.steps`` is 0.
    """
    if rc.steps <= 0:
        raise ValueError("refine_articulation needs rc.steps > 0")
    enc = out.enc
    R0, t0 = getattr(out, "R", enc.R).detach(), enc.t.detach()  # the stage-2 frame (branch-corrected)
    state0 = out.state_x.detach()
    root0 = out.root_x.detach() if out.root_x is not None else None
    rest, weights = out.Y_star.detach(), out.w_ystar.detach()
    pivot, axis = out.pivot_y.detach(), out.axis_y.detach()
    X = X.detach()
    if rc.starts == "network":
        return _fit(cfg, X, rest, weights, pivot, axis, R0, t0, state0, root0, rc.steps, rc.lr, rc.points, rc.seed)
    B = X.shape[0]
    C = octahedral_rotations(X.dtype, X.device)  # (K, 3, 3), identity first
    K = C.shape[0]

    def rep(v, k):  # (B, ...) -> (B * k, ...), each view's copies together
        return None if v is None else v.repeat_interleave(k, 0)

    # screen every start briefly, on fewer points
    screen = _fit(cfg, X, rep(rest, K), rep(weights, K), rep(pivot, K), rep(axis, K),
                  rep(R0, K) @ C.repeat(B, 1, 1), rep(t0, K), rep(state0, K), rep(root0, K), rc.screen_steps,
                  rc.lr, rc.screen_points, rc.seed, repeat_obs=K, segment=False)["residual"].reshape(B, K)
    eligible = torch.ones(B, K, dtype=torch.bool, device=X.device)
    if upright is not None and rc.upright_deg > 0:
        up = upright.to(X.dtype).to(X.device)
        u = camera_direction_in_frame(R0.unsqueeze(1) @ C.unsqueeze(0), up[1])  # (B, K, 3) in each start's frame
        cos = torch.cos(torch.deg2rad(torch.tensor(float(rc.upright_deg), dtype=X.dtype)))
        eligible = (u @ up[0]) >= cos
        # views with no eligible start at all keep the plain rule
        eligible = torch.where(eligible.any(1, keepdim=True), eligible, torch.ones_like(eligible))
    masked = torch.where(eligible[:, 1:], screen[:, 1:], torch.full_like(screen[:, 1:], float("inf")))
    alt = 1 + masked.argmin(dim=1)  # (B,) the best (eligible) start other than the network's
    # refine the network's start and the best alternative fully; the alternative must win by the margin
    Rs = torch.stack([R0, R0 @ C[alt]], 1).reshape(2 * B, 3, 3)
    r = _fit(cfg, X, rep(rest, 2), rep(weights, 2), rep(pivot, 2), rep(axis, 2), Rs, rep(t0, 2), rep(state0, 2),
             rep(root0, 2), rc.steps, rc.lr, rc.points, rc.seed, repeat_obs=2)
    res = r["residual"].reshape(B, 2)
    alt_ok = eligible.gather(1, alt[:, None])[:, 0]
    wins = res[:, 1] < (1.0 - rc.margin) * res[:, 0]
    pick = ((wins | ~eligible[:, 0]) & alt_ok).long()  # 1: the alternative start
    sel = torch.arange(B, device=X.device) * 2 + pick
    r = {k: (v[sel] if torch.is_tensor(v) else v) for k, v in r.items()}
    r["start"] = torch.where(pick.bool(), alt, torch.zeros_like(alt))
    return r
