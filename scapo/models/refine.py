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

from dataclasses import dataclass

import torch

from scapo.nn.outputs import SCAPOOutput
from scapo.nn.skinning import blend, bone_transforms, root_joint
from scapo.ops.groups import octahedral_rotations
from scapo.ops.so3 import skew


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the test-time refinement (part of a preset; ``steps = 0`` turns it off)."""

    steps: int = 0
    """Adam steps per batch of views (0: no refinement, the paper's one-pass prediction)."""
    lr: float = 0.02
    """Adam learning rate (normalised units and radians), cosine-decayed to 5 % of it."""
    points: int = 384
    """Observed points per view used by the objective (a fixed random subset; all when fewer)."""
    seed: int = 0
    """Seed of the point subset."""
    starts: str = "network"
    """``"network"``: one fit from the network's frame. ``"octahedral"``: also screen the 23 other
    rotations of the cube group applied in the canonical frame (``R_g C``), each by ``screen_steps``
    steps on ``screen_points`` points, fully refine the best of them beside the network's start, and
    keep it only when its residual is ``margin`` below the network start's."""
    screen_steps: int = 5
    """Adam steps of the screening fit of every start (``starts = "octahedral"``)."""
    screen_points: int = 128
    """Observed points per view in the screening fit."""
    margin: float = 0.3
    """Relative residual margin an alternative start needs to replace the network's (0: the best wins)."""
    upright_deg: float = 0.0
    """Upright prior (``starts = "octahedral"``; 0 turns it off): a start is eligible only when the
    run's upright camera direction ``v``, expressed in its canonical frame, lies within this angle of
    the run's upright direction ``d`` (:func:`upright_direction`, from the training views). A network start
    outside that cone is replaced by the best eligible start without the margin. It resolves the
    two-fold ambiguity of shapes whose largest part is near-symmetric (a laptop's base and screen
    swapped by a half turn about their bisector, eyeglasses turned upside down), which the residual
    cannot: the capture setup (objects standing on a support, cameras above them with little roll) is
    the cue, no label is used. An addition to the paper."""

    def __post_init__(self):
        if self.steps < 0 or self.lr <= 0 or self.points < 8:
            raise ValueError(f"invalid refinement settings: steps {self.steps} (>= 0), lr {self.lr} (> 0), "
                             f"points {self.points} (>= 8)")
        if self.starts not in START_SETS:
            raise ValueError(f"unknown refinement starts {self.starts!r}; known: {', '.join(START_SETS)}")
        if not 0.0 <= self.upright_deg <= 180.0:
            raise ValueError(f"upright_deg must be in [0, 180], got {self.upright_deg}")
        if self.screen_steps < 1 or self.screen_points < 8 or not 0.0 <= self.margin < 1.0:
            raise ValueError(f"invalid refinement screening: screen_steps {self.screen_steps} (>= 1), "
                             f"screen_points {self.screen_points} (>= 8), margin {self.margin} (in [0, 1))")


START_SETS = ("network", "octahedral")

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


class TemplatePoser:
    """The posed template of :func:`posed_template` as a function of one flat parameter vector, with
    everything that does not depend on it computed once (the refinement's inner loop is bound by the
    number of tensor operations at batch 1, not by arithmetic).

    Parameters ``theta (B, 6 + J [+ 1])``: ``w (3)`` rotation vector of the frame increment
    (``R = R0 exp([w]_x)``), ``dt (3)`` (``t = t0 + dt``), the joint states ``a (J)`` and, with a root
    motion, the root state ``b``. A revolute joint's transform is ``E + sin(a) [K | -K c] + (1 - cos a)
    [K^2 | -K^2 c]`` with ``K = [d]_x`` (Rodrigues, about the line through ``c``); a prismatic one's is
    ``E + a [0 | d]``. Equal to :func:`posed_template` (tested).

    Args:
        joint_types, joint_parts, num_parts: the category's kinematic tree (``ModelConfig``).
        template_rest: (B, M, 3) rest points; weights: (B, M, P) skinning weights.
        pivot, axis: (B, J, 3) the joints (rest frame); R0: (B, 3, 3), t0: (B, 3) the start frame.
        root: whether ``theta`` carries a root state (``ModelConfig.root_motion``).

    Raises:
        ValueError: (when called) a joint type other than 0 (revolute) or 1 (prismatic).
    """

    def __init__(self, joint_types, joint_parts, num_parts: int, template_rest: torch.Tensor,
                 weights: torch.Tensor, pivot: torch.Tensor, axis: torch.Tensor, R0: torch.Tensor,
                 t0: torch.Tensor, root: bool):
        B, M, P = weights.shape
        dtype, dev = template_rest.dtype, template_rest.device
        self.jt, self.jp, self.P, self.B = tuple(joint_types), tuple(joint_parts), num_parts, B
        self.J = len(self.jt)
        self.root = root_joint(joint_parts) if root else None
        self.R0, self.t0 = R0, t0
        homo = torch.cat([template_rest, torch.ones_like(template_rest[..., :1])], -1)  # (B, M, 4)
        self.Yw = (weights.unsqueeze(-1) * homo.unsqueeze(2)).reshape(B, M, P * 4)  # (B, M, 4P)
        self.E = torch.eye(4, dtype=dtype, device=dev).expand(B, 4, 4)
        self.E3 = torch.eye(3, dtype=dtype, device=dev).expand(B, 3, 3)
        # rows of the skew matrix of a vector: [w]_x = (w @ L).reshape(3, 3)
        self.L = skew(torch.eye(3, dtype=dtype, device=dev)).reshape(3, 9)
        self.C1, self.C2, self.D = [], [], []
        for j in range(self.J):
            K = skew(axis[:, j])
            K2 = K @ K
            c = pivot[:, j].unsqueeze(-1)
            z = torch.zeros(B, 1, 4, dtype=dtype, device=dev)
            self.C1.append(torch.cat([torch.cat([K, -(K @ c)], -1), z], 1))
            self.C2.append(torch.cat([torch.cat([K2, -(K2 @ c)], -1), z], 1))
            D = torch.zeros(B, 4, 4, dtype=dtype, device=dev)
            D[:, :3, 3] = axis[:, j]
            self.D.append(D)

    def joint(self, j: int, a: torch.Tensor) -> torch.Tensor:
        """Transform ``(B, 4, 4)`` of joint ``j`` at states ``a (B,)``."""
        a = a[:, None, None]
        if self.jt[j] == 0:
            return self.E + torch.sin(a) * self.C1[j] + (1 - torch.cos(a)) * self.C2[j]
        if self.jt[j] == 1:
            return self.E + a * self.D[j]
        raise ValueError(f"joint_type must be 0 (revolute) or 1 (prismatic), got {self.jt[j]}")

    def __call__(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``theta (B, D)`` -> posed points ``(B, M, 3)``, bone transforms ``T (B, P, 4, 4)``, frame
        ``R (B, 3, 3)``, ``t (B, 3)``."""
        B, J = self.B, self.J
        w = theta[:, :3]
        angle = torch.sqrt((w * w).sum(-1) + 1e-20)[:, None, None]
        W = (w @ self.L).reshape(B, 3, 3) / angle
        R = self.R0 @ (self.E3 + torch.sin(angle) * W + (1 - torch.cos(angle)) * (W @ W))
        t = self.t0 + theta[:, 3:6]
        T = [self.joint(self.root, theta[:, 6 + J]) if self.root is not None else self.E] + [None] * (self.P - 1)
        for j, (pa, ch) in enumerate(self.jp):
            T[ch] = T[pa] @ self.joint(j, theta[:, 6 + j])
        T = torch.stack(T, 1)  # (B, P, 4, 4)
        A = R.unsqueeze(1) @ T[:, :, :3, :]  # (B, P, 3, 4): rest -> frame, without t
        model = self.Yw @ A.transpose(2, 3).reshape(B, self.P * 4, 3) + t[:, None]
        return model, T, R, t


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


def _fit(cfg, X, rest, weights, pivot, axis, R0, t0, state0, root0, steps: int, lr: float, points: int, seed: int,
         repeat_obs: int = 1, segment: bool = True) -> dict:
    """Adam fit of the posed template from one start per row (see :func:`refine_articulation`); with
    ``repeat_obs = k`` the starts come in groups of ``k`` rows per view of ``X (B, N, 3)``; ``segment``:
    also transfer the fitted template's weights to every observed point (``weights``, else None)."""
    has_root = root0 is not None
    poser = TemplatePoser(cfg.joint_types, cfg.joint_parts, cfg.num_parts, rest, weights, pivot, axis, R0, t0,
                          has_root)
    N = X.shape[1]
    J = len(cfg.joint_types)
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(N, generator=g)[:points].to(X.device)
    obs = X[:, idx].repeat_interleave(repeat_obs, 0)
    B = obs.shape[0]
    zeros = torch.zeros(B, 6, dtype=X.dtype, device=X.device)
    theta = torch.cat([zeros, state0] + ([root0[:, None]] if has_root else []), 1).requires_grad_(True)
    opt = torch.optim.Adam([theta], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=0.05 * lr)

    def objective():
        model, T, R, t = poser(theta)
        with torch.no_grad():  # nearest model point of each observed point (the Chamfer term's argmin)
            nn_idx = torch.cdist(obs, model).argmin(dim=2, keepdim=True).expand(-1, -1, 3)
        d = obs - torch.gather(model, 1, nn_idx)
        return (d * d).sum(-1).mean(dim=1), R, t, T, model

    with torch.enable_grad():
        start = None
        for _ in range(steps):
            loss = objective()[0]
            if start is None:
                start = loss.detach()
            opt.zero_grad(set_to_none=True)
            loss.sum().backward()
            opt.step()
            sched.step()
    with torch.no_grad():
        loss, R, t, T, model = objective()
        point_weights = None
        if segment:  # over all observed points
            nearest = torch.cdist(X.repeat_interleave(repeat_obs, 0), model).argmin(dim=2)
            point_weights = torch.gather(weights, 1, nearest.unsqueeze(-1).expand(-1, -1, weights.shape[-1]))
    theta = theta.detach()
    return {"R": R, "t": t, "state": theta[:, 6:6 + J], "root": theta[:, 6 + J] if has_root else None, "T": T,
            "pivot": pivot, "axis": axis, "weights": point_weights, "residual": loss, "residual_start": start}
