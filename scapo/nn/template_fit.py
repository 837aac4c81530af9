"""Fitting an articulated template to an observed cloud: the optimisation shared by SCAPO's test-time refinement
(:mod:`scapo.models.refine`) and the method-independent one (:mod:`scapo.steps.refine`).

A template ``rest (B, M, 3)`` with skinning weights ``(B, M, P)`` (one-hot for rigid parts), its joints
``pivot, axis (B, J, 3)`` in the rest frame, is posed by joint states and moved by a rigid frame
(:class:`TemplatePoser`); :func:`fit_template` fits the frame increment and the joint states by Adam to the
one-sided Chamfer term from the observed points to the posed template. :class:`RefineConfig` holds the settings.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from scapo.nn.skinning import root_joint
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
    stage2_starts: str = "off"
    """A hypothesis set of stage 2's starting frame in one-pass prediction, for a model trained with
    ``TrainConfig.stage2_frame = "parts"`` (:meth:`scapo.models.scapo_model.SCAPOModel.passes`; an addition to the
    paper, applied whatever ``steps`` is): "off" the stage-1 frame alone; "D2" the stage-1 frame and its three
    half turns about its own axes (:func:`scapo.ops.groups.half_turns`); "T", "O", "I" a rotation group's turns of it.
    Each start runs the prediction passes, and each view keeps the one whose template, posed as the view, lies nearest
    to its points (the one-sided Chamfer distance from the input, as OP-Align's and EAP's anchor choice). Not part
    of a run: an inference setting, like the rest of this config."""

    def __post_init__(self):
        import math

        if not all(math.isfinite(v) for v in (self.lr, self.margin, self.upright_deg)):
            raise ValueError(f"invalid refinement settings: lr {self.lr}, margin {self.margin} and upright_deg "
                             f"{self.upright_deg} must be finite numbers")
        if self.steps < 0 or self.lr <= 0 or self.points < 8:
            raise ValueError(f"invalid refinement settings: steps {self.steps} (>= 0), lr {self.lr} (> 0), "
                             f"points {self.points} (>= 8)")
        if self.starts not in START_SETS:
            raise ValueError(f"unknown refinement starts {self.starts!r}; known: {', '.join(START_SETS)}")
        check_stage2_starts(self.stage2_starts)
        if not 0.0 <= self.upright_deg <= 180.0:
            raise ValueError(f"upright_deg must be in [0, 180], got {self.upright_deg}")
        if self.screen_steps < 1 or self.screen_points < 8 or not 0.0 <= self.margin < 1.0:
            raise ValueError(f"invalid refinement screening: screen_steps {self.screen_steps} (>= 1), "
                             f"screen_points {self.screen_points} (>= 8), margin {self.margin} (in [0, 1))")


START_SETS = ("network", "octahedral")
#: The hypothesis sets of :attr:`RefineConfig.stage2_starts` ("off": the stage-1 frame alone; the one spelling).
STAGE2_STARTS = ("off", "D2", "T", "O", "I")


def check_stage2_starts(value) -> str:
    """``value`` when it names a hypothesis set of :attr:`RefineConfig.stage2_starts` (:data:`STAGE2_STARTS`): the
    one check of the setting, made by the config, the prediction option and the model alike.

    Raises:
        ValueError: another value (names the known ones)."""
    if value not in STAGE2_STARTS:
        raise ValueError(f"unknown stage2_starts {value!r}; use one of {', '.join(STAGE2_STARTS)}")
    return value


def refine_from_dict(stored: dict | None) -> RefineConfig:
    """The :class:`RefineConfig` a run stored (``run.json``'s ``preset.refine``; {} or None for a run from before
    the refinement existed: the defaults, off), with the old spelling translated: ``stage2_starts`` "" (off, before
    "off" was its one spelling) reads as "off".

    Raises:
        ValueError: a stored value :class:`RefineConfig` refuses; TypeError: an unknown field."""
    return RefineConfig(**current_refine_names(stored))


def current_refine_names(stored: dict | None) -> dict:
    """Stored refinement settings (a dict of :class:`RefineConfig` fields, e.g. a record's ``info["inference"]``) in
    today's spelling: ``stage2_starts`` "" reads as "off". The one translation of old names."""
    d = dict(stored or {})
    if d.get("stage2_starts") == "":
        d["stage2_starts"] = "off"
    return d


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


def fit_template(cfg, X, rest, weights, pivot, axis, R0, t0, state0, root0, steps: int, lr: float, points: int,
                 seed: int, repeat_obs: int = 1, segment: bool = True) -> dict:
    """Adam fit of the posed template (:class:`TemplatePoser`) to observed points, one start per row.

    Args:
        cfg: the kinematic tree: ``joint_types``, ``joint_parts`` (parent part first; part 0 the base),
            ``num_parts``.
        X: (B, N, 3) observed points (any consistent units; the settings assume clouds of about unit size).
        rest: (B', M, 3) template rest points; weights: (B', M, P) their skinning weights (one-hot: rigid parts).
        pivot, axis: (B', J, 3) joints in the rest frame. R0: (B', 3, 3), t0: (B', 3) start frame.
        state0: (B', J) start joint states; root0: (B',) start root state or None (no root motion).
        steps, lr: Adam steps (cosine-decayed to 5 % of ``lr``). points: observed points per view used (a fixed
            random subset drawn with ``seed``).
        repeat_obs: ``B' = k B``: the starts come in groups of ``k`` rows per view of ``X``.
        segment: also give every observed point the weights of its nearest fitted template point.

    Returns:
        dict of detached tensors: ``R (B', 3, 3)``, ``t (B', 3)`` (fitted frame), ``state (B', J)``, ``root``
        (``(B',)`` or None), ``T (B', P, 4, 4)`` (bone transforms, rest -> posed, before the frame), ``pivot``,
        ``axis`` (as given), ``weights (B', N, P)`` (None without ``segment``), ``residual (B',)`` (final mean
        squared distance, observed point to nearest template point) and ``residual_start (B',)`` (at the start).
    """
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
