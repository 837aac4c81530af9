"""The SCAPO network: SE(3) canonicalisation (stage 1) and joint-aware blend skinning (stage 2).

Shapes: ``B`` batch, ``N`` input points, ``M`` template points, ``P`` parts (slot 0 is the base),
``J`` joints. Inputs are camera-frame points in metres; the model works in normalised units
``X = points / scale`` with ``scale = 2 * RMS distance of the points to their centroid`` (an
SE(3)-invariant quantity, so equivariance is kept) and reports metric outputs.

Stage 1 (Sec. 3.1): ``t_g, R_g, Z_x = Theta_E(X)``; ``S_dec, F_x = Theta_D(Z_x)``;
``X ~ R_g S_dec + t_g`` with ``R_g`` the Gram-Schmidt rotation of the raw equivariant estimate.

Stage 2 (Sec. 3.2-3.3):
``S_obj = R_g^T (X - t_g)`` (aligned input; ``R_g`` branch-corrected when the run fitted a correction,
:mod:`scapo.models.branch`, an addition to the paper); keypoints ``K`` and bone shapes from ``Theta_K(Z_x)``;
template ``Y_X = Y_base + Theta_Delta(F_x)``; joints ``(c, d, a)_x = Theta_J(S_obj)`` and
``(c, d, a)_y = Theta_J(Y_X)``; bone transforms ``T^p`` (canonical -> aligned); backward
``S* = D^{o->c}(S_obj)``, forward ``S_obj^ = D^{c->o}(S*)``, ``X^ = R_g S_obj^ + t_g``; the same
cycle on ``Y_X``; cross-space maps ``S_obj -> Y`` and ``Y_X -> X``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch
from torch import nn

from scapo.models.branch import apply_branch
from scapo.models.refine import RefineConfig, check_stage2_starts, refine_articulation
from scapo.nn.encoder import EncoderConfig, EncoderOutput, SE3Encoder, ShapeDecoder
from scapo.nn.outputs import SCAPOOutput, Stage1Output
from scapo.nn.skinning import (
    apply_per_part,
    blend,
    bone_transforms,
    cross_space_transforms,
    skinning_weights,
)
from scapo.ops.chamfer import nearest_sq_dist
from scapo.ops.so3 import invert_transform, rotation_from_6d


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the SCAPO network for one category's kinematic structure."""

    num_parts: int
    """P, part slots (slot 0 is the base)."""
    joint_types: tuple[int, ...]
    """Per joint: 0 revolute, 1 prismatic."""
    joint_parts: tuple[tuple[int, int], ...]
    """Per joint: (parent slot, child slot), parents listed first."""
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    template_points: int = 512
    """M, points of the learnable template Y_base."""
    gamma: float = 0.1
    """Temperature of the skinning softmax."""
    joint_widths: tuple[int, ...] = (64, 128, 256)
    """PointNet widths of the joint head Theta_J."""
    head_width: int = 256
    """Hidden width of the keypoint and residual heads."""
    root_motion: bool = False
    """Let the base part move about (along) the root joint by a predicted root state (an addition
    to the paper; see :func:`scapo.nn.skinning.bone_transforms`). The stage-1 frame of a
    two-slab object such as a laptop settles between its two parts, so with the base pinned to that
    frame the learned joint states come out as a fraction of the true ones (measurements in
    results/cpu_preset_history.md)."""

    anchors: str = ""
    """A hypothesis set of frames in stage 1 (an addition to the paper; "" off): the name of a finite rotation group
    of :func:`scapo.ops.groups.rotation_group` ("T" 12, "O" 24, "I" 60 rotations). Each cloud's frame is
    ``R G_k`` for the anchor ``G_k`` whose reconstruction ``S_dec G_k^T R^T + t`` is nearest to the input (one-sided
    Chamfer from the input, no gradient through the choice), so a shape whose regressed frame lands in another
    discrete orientation is not pulled towards it by the gradient (EPN-style anchors with a minimum over hypotheses
    as in OP-Align's ``models/art_so3net_pn.py`` around lines 259-275 and Li et al.'s equi-pose)."""

    stage1_template: bool = False
    """A learnable category template in metres for stage 1 (``template_s1 (M, 3)``, an addition to the paper): the
    decoded shapes of every training view are pulled to it (``LossConfig.template``,
    :func:`scapo.losses.scapo_losses.template_loss`), so that one persistent shape, not each view's own decoding,
    decides the frame the encoder registers to. Set by the trainer when ``LossConfig.template > 0``."""

    def __post_init__(self):
        if self.anchors not in ("", "T", "O", "I"):
            raise ValueError(f"anchors must be '', 'T', 'O' or 'I', got {self.anchors!r}")
        if len(self.joint_types) != len(self.joint_parts):
            raise ValueError("joint_types and joint_parts must have one entry per joint")
        if len(self.joint_parts) != self.num_parts - 1:
            raise ValueError("the kinematic structure must be a tree: num_parts - 1 joints")


def _mlp(widths: list[int]) -> nn.Sequential:
    layers = []
    for a, b in zip(widths[:-2], widths[1:-1]):
        layers += [nn.Linear(a, b), nn.LeakyReLU(0.2)]
    layers.append(nn.Linear(widths[-2], widths[-1]))
    return nn.Sequential(*layers)


class KeypointHead(nn.Module):
    """Theta_K: invariant code -> keypoints ``K (B, P, 3)``, bone orientations ``V (B, P, 3, 3)`` and
    log scales ``(B, P, 3)``. Initialised with keypoints spread along x and isotropic bones; the trainer
    moves the keypoints to the most rigid part split before stage 2 (``TrainConfig.part_init``)."""

    def __init__(self, code_dim: int, num_parts: int, width: int):
        super().__init__()
        self.P = num_parts
        self.net = _mlp([code_dim, width, num_parts * (3 + 6 + 3)])
        with torch.no_grad():
            last = self.net[-1]
            last.weight.mul_(0.01)
            bias = torch.zeros(num_parts, 12)
            bias[:, 0] = torch.linspace(-0.25, 0.25, num_parts)
            bias[:, 3:9] = torch.tensor([1.0, 0, 0, 0, 1.0, 0])
            bias[:, 9:] = torch.log(torch.tensor(0.3))
            last.bias.copy_(bias.reshape(-1))

    def forward(self, code: torch.Tensor):
        o = self.net(code).reshape(-1, self.P, 12)
        V = rotation_from_6d(o[..., 3:6].reshape(-1, 3), o[..., 6:9].reshape(-1, 3)).reshape(-1, self.P, 3, 3)
        return o[..., :3], V.transpose(-1, -2), o[..., 9:].clamp(-4.0, 1.0)


class JointHead(nn.Module):
    """Theta_J: a PointNet on an aligned shape ``(B, M, 3)`` -> per joint pivot ``c``, unit axis ``d``
    and state ``a``: ``(B, J, 3), (B, J, 3), (B, J)``, and with ``root`` a root state ``(B,)`` (else
    None; see ``ModelConfig.root_motion``)."""

    def __init__(self, num_joints: int, widths: tuple[int, ...], root: bool = False):
        super().__init__()
        dims = [3, *widths]
        layers = []
        for a, b in zip(dims[:-1], dims[1:]):
            layers += [nn.Conv1d(a, b, 1), nn.LeakyReLU(0.2)]
        self.point_mlp = nn.Sequential(*layers)
        self.out = _mlp([widths[-1], widths[-1] // 2, num_joints * 7 + int(root)])
        self.J = num_joints
        self.root = root
        with torch.no_grad():
            self.out[-1].weight.mul_(0.01)
            bias = torch.zeros(num_joints, 7)
            bias[:, 3:6] = torch.tensor([0.0, 1.0, 0.0])
            self.out[-1].bias.copy_(torch.cat([bias.reshape(-1), torch.zeros(int(root))]))
        # per joint 1 where its axis is held at the bias (TrainConfig.axis_fixed): the axis outputs' weights are zero
        # and their gradients (weights and bias) are zeroed, so the axis is one direction of the canonical frame
        self.register_buffer("axis_frozen", torch.zeros(num_joints))
        self.out[-1].weight.register_hook(lambda g: g * self._axis_mask()[:, None] if self.axis_frozen.any() else g)
        self.out[-1].bias.register_hook(lambda g: g * self._axis_mask() if self.axis_frozen.any() else g)

    def _axis_mask(self) -> torch.Tensor:
        """``(J * 7 + root,)`` 0 at the output rows of frozen axes, else 1."""
        keep = torch.ones(self.J, 7, device=self.axis_frozen.device)
        keep[:, 3:6] = (1.0 - self.axis_frozen)[:, None]
        return torch.cat([keep.reshape(-1), torch.ones(int(self.root), device=keep.device)])

    @torch.no_grad()
    def freeze_axis(self, j: int) -> None:
        """Hold joint ``j``'s axis at its bias from now on (``TrainConfig.axis_fixed``)."""
        self.axis_frozen[j] = 1.0
        self.out[-1].weight[j * 7 + 3: j * 7 + 6] = 0.0

    def joint_bias(self) -> torch.Tensor:
        """View ``(J, 7)`` of the output bias (pivot, axis, state per joint), for initialisation."""
        return self.out[-1].bias[: self.J * 7].view(self.J, 7)

    def forward(self, shape: torch.Tensor):
        f = self.point_mlp(shape.transpose(1, 2)).max(dim=2).values
        raw = self.out(f)
        o = raw[:, : self.J * 7].reshape(-1, self.J, 7)
        d = o[..., 3:6]
        root = raw[:, -1] if self.root else None
        return o[..., :3], d / (d.norm(dim=-1, keepdim=True) + 1e-8), o[..., 6], root


#: ``TrainConfig.stage2_frame = "parts"``: how many times prediction reads the frame from the base stage 2 labels
#: and runs stage 2 again in it (each pass labels the base in a better frame). Chosen on the eyeglasses' paper-rung
#: val split (docs/canonical_ladder.md, "Stage 2 in the parts-signed frame").
PARTS_PASSES = 2


def stage2_start_rotations(name: str) -> torch.Tensor:
    """The rotations ``(K, 3, 3)`` float32 of a hypothesis set of stage 2's first frame
    (:attr:`scapo.models.refine.RefineConfig.stage2_starts`), identity first: "D2" the half turns
    (:func:`scapo.ops.groups.half_turns`), "T", "O", "I" :func:`scapo.ops.groups.rotation_group`.

    Raises:
        ValueError: "off" (no set) or an unknown name (:func:`scapo.models.refine.check_stage2_starts`).
    """
    import numpy as np

    from scapo.ops.groups import half_turns, rotation_group

    if check_stage2_starts(name) == "off":
        raise ValueError("stage2_starts 'off' has no start rotations: the stage-1 frame alone")
    return torch.from_numpy(np.array(half_turns() if name == "D2" else rotation_group(name))).float()


def _where_clouds(take: torch.Tensor, new: SCAPOOutput, old: SCAPOOutput) -> SCAPOOutput:
    """Per cloud (``take (B,)`` bool) the fields of ``new``, else ``old``: every tensor (and the encoder output's)
    whose first dimension is the batch; other fields (None, shared tensors) are ``old``'s."""
    B = take.shape[0]

    def pick(a, b):
        if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) and a.dim() and a.shape[0] == B \
                and a.shape == b.shape:
            return torch.where(take.view(-1, *[1] * (a.dim() - 1)), a, b)
        if dataclasses.is_dataclass(a) and not isinstance(a, type):
            return type(a)(**{f.name: pick(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)})
        return b

    return pick(new, old)


class SCAPOModel(nn.Module):
    """The SCAPO network; see the module docstring for the data flow."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        e = cfg.encoder
        self.encoder = SE3Encoder(e)
        self.decoder = ShapeDecoder(e)
        self.keypoints = KeypointHead(e.code_dim, cfg.num_parts, cfg.head_width)
        self.joints = JointHead(len(cfg.joint_types), cfg.joint_widths, cfg.root_motion)
        self.residual = _mlp([e.decoder_hidden[-1], cfg.head_width, cfg.template_points * 3])
        with torch.no_grad():
            self.residual[-1].weight.mul_(0.01)
            self.residual[-1].bias.zero_()
        g = torch.Generator().manual_seed(0)
        # replaced at the start of stage 2 by canonicalised training points (see the trainer)
        self.y_base = nn.Parameter(0.3 * torch.randn(cfg.template_points, 3, generator=g))
        # stage-2 branch correction of the stage-1 frames (scapo.models.branch; zeros: off), set by the
        # trainer at the start of stage 2 when TrainConfig.branch_flip is on
        self.register_buffer("branch", torch.zeros(3, 3))
        self.register_buffer("branch_flip", torch.eye(3))
        # stage 2 in the frame read from the base's axes signed by the other parts (TrainConfig.stage2_frame =
        # "parts"; zeros: off): the template's signed base axes E_Y (columns) and the two signed ranks, set by the
        # trainer at the start of stage 2
        self.register_buffer("parts_frame", torch.zeros(3, 3))
        self.register_buffer("parts_pair", torch.tensor([1, 2]))
        # how parts_frames finds the base's directions: 0 the principal axes of its points, 1 those on its dominant
        # plane (TrainConfig.parts_axes; scapo.ops.signed_axes.AXES), set by the trainer with parts_frame
        self.register_buffer("parts_plane", torch.tensor(0))
        if cfg.stage1_template:  # own generator: the other parameters' initialisation is unchanged
            g1 = torch.Generator().manual_seed(1)
            self.template_s1 = nn.Parameter(0.1 * torch.randn(cfg.template_points, 3, generator=g1))
        if cfg.anchors:
            from scapo.ops.groups import rotation_group

            self.register_buffer("anchor_rotations", torch.tensor(rotation_group(cfg.anchors), dtype=torch.float32),
                                 persistent=False)

    # ------------------------------------------------------------------ helpers
    def load_checkpoint_state(self, state: dict) -> None:
        """``load_state_dict`` that accepts checkpoints from before the branch correction or the parts frame existed
        (their missing ``branch``/``branch_flip``/``parts_frame``/``parts_pair``/``parts_plane`` buffers keep the "off"
        values)."""
        state = dict(state)
        for name in ("branch", "branch_flip", "parts_frame", "parts_pair", "parts_plane", "joints.axis_frozen"):
            state.setdefault(name, self.get_buffer(name).detach().clone())
        self.load_state_dict(state)

    @staticmethod
    def normalize(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``points (B, N, 3)`` m -> (normalised points, scale (B,)) with ``scale = 2 RMS radius``."""
        c = points.mean(dim=1, keepdim=True)
        scale = 2.0 * ((points - c) ** 2).sum(-1).mean(-1).sqrt().clamp_min(1e-6)
        return points / scale[:, None, None], scale

    @torch.no_grad()
    def frames(self, points: torch.Tensor) -> torch.Tensor:
        """The canonical frames ``(B, 3, 3)`` (canonical -> camera) of camera-frame clouds ``(B, N, 3)``:
        the stage-1 frames, branch-corrected (:mod:`scapo.models.branch`) when the run fitted a correction."""
        was_training = self.training
        self.eval()
        try:
            return apply_branch(self.frame(self.normalize(points)[0]).R, self.branch, self.branch_flip)
        finally:
            self.train(was_training)

    def choose_anchor(self, X: torch.Tensor, enc: EncoderOutput, S_dec: torch.Tensor) -> EncoderOutput:
        """The frame of each cloud under the hypothesis set (``ModelConfig.anchors``): ``enc`` with ``R`` and
        ``R_raw`` turned by the anchor ``G_k (3, 3)`` whose reconstruction ``S_dec (B, M, 3)`` posed by ``R G_k, t``
        is nearest to ``X (B, N, 3)`` (mean squared distance from the input's points, no gradient); ``enc`` itself
        without anchors."""
        if not self.cfg.anchors:
            return enc
        G = self.anchor_rotations.to(X)
        B, K = X.shape[0], G.shape[0]
        with torch.no_grad():
            RG = enc.R.unsqueeze(1) @ G.unsqueeze(0)  # (B, K, 3, 3)
            rec = torch.einsum("bmj,bkij->bkmi", S_dec, RG) + enc.t[:, None, None]  # (B, K, M, 3)
            d = nearest_sq_dist(X.unsqueeze(1).expand(B, K, *X.shape[1:]).reshape(B * K, -1, 3),
                                rec.reshape(B * K, -1, 3)).mean(-1).reshape(B, K)
            Gk = G[d.argmin(1)]  # (B, 3, 3)
        return EncoderOutput(enc.t, enc.R_raw @ Gk, enc.R @ Gk, enc.code)

    def frame(self, X: torch.Tensor) -> EncoderOutput:
        """The stage-1 pose of normalised clouds ``X (B, N, 3)``: the encoder's, with the anchor choice when the model
        has a hypothesis set (which needs the decoded shape; without one the decoder is not run)."""
        enc = self.encoder(X)
        return self.choose_anchor(X, enc, self.decoder(enc.code)[0]) if self.cfg.anchors else enc

    def stage1(self, X: torch.Tensor) -> Stage1Output:
        """Canonicalisation on normalised points ``X (B, N, 3)``."""
        enc = self.encoder(X)
        S_dec, F_x = self.decoder(enc.code)
        enc = self.choose_anchor(X, enc, S_dec)
        X_rec = S_dec @ enc.R.transpose(1, 2) + enc.t[:, None]  # rigid: R in SO(3) (Gram-Schmidt of R_raw)
        return Stage1Output(enc=enc, S_dec=S_dec, F_x=F_x, X_rec=X_rec)

    def stage2(self, X: torch.Tensor, s1: Stage1Output, frame: torch.Tensor | None = None) -> dict:
        """Joint-aware deformation given the stage-1 outputs (see module docstring): the fields of
        :class:`~scapo.nn.outputs.SCAPOOutput` beyond :class:`~scapo.nn.outputs.Stage1Output`'s. ``frame (B, 3, 3)``:
        the frames (canonical -> camera) stage 2 uses instead of stage 1's (branch-corrected) ones, for the clouds whose
        ``frame`` is not all zeros (``TrainConfig.stage2_frame = "parts"``)."""
        cfg = self.cfg
        enc = s1.enc
        R, t = apply_branch(enc.R, self.branch, self.branch_flip), enc.t
        if frame is not None:
            given = (frame.flatten(1).abs().sum(-1) > 0)[:, None, None]
            R = torch.where(given, frame.to(R), R)
        S_obj = (X - t[:, None]) @ R  # R^T (x - t) for row vectors
        K, V, log_s = self.keypoints(enc.code)
        delta = self.residual(s1.F_x).reshape(-1, cfg.template_points, 3)
        Y = self.y_base.unsqueeze(0) + delta
        c_x, d_x, a_x, b_x = self.joints(S_obj)
        c_y, d_y, a_y, b_y = self.joints(Y)
        jt, jp, P = cfg.joint_types, cfg.joint_parts, cfg.num_parts
        T_x = bone_transforms(jt, jp, d_x, c_x, a_x, P, b_x)  # canonical -> aligned input
        T_y = bone_transforms(jt, jp, d_y, c_y, a_y, P, b_y)
        T_x_inv, T_y_inv = invert_transform(T_x), invert_transform(T_y)
        w, W = skinning_weights(S_obj, K, V, log_s, cfg.gamma)
        S_star = blend(S_obj, w, T_x_inv)  # backward D^{o->c}
        K_star = apply_per_part(T_x_inv, K)
        w_star, _ = skinning_weights(S_star, K_star, V, log_s, cfg.gamma)
        S_hat = blend(S_star, w_star, T_x)  # forward D^{c->o}
        X_hat = S_hat @ R.transpose(1, 2) + t[:, None]
        # template cycle (keypoints carried into the template space by the cross-space maps)
        T_xy = cross_space_transforms(jt, jp, P, c_x, d_x, a_x, c_y, d_y, a_y, b_x, b_y)
        K_y = apply_per_part(T_xy, K)
        w_y, _ = skinning_weights(Y, K_y, V, log_s, cfg.gamma)
        Y_star = blend(Y, w_y, T_y_inv)
        K_ystar = apply_per_part(T_y_inv, K_y)
        w_ystar, _ = skinning_weights(Y_star, K_ystar, V, log_s, cfg.gamma)
        Y_hat = blend(Y_star, w_ystar, T_y)
        # cross-space alignment
        S_x2y = blend(S_obj, w, T_xy)
        S_y2x = blend(Y, w_y, invert_transform(T_xy))
        return {
            "R": R, "S_obj": S_obj, "K": K, "V": V, "log_scale": log_s, "w": w, "W": W,
            "Y": Y, "delta": delta, "pivot_x": c_x, "axis_x": d_x, "state_x": a_x,
            "pivot_y": c_y, "axis_y": d_y, "state_y": a_y, "root_x": b_x, "root_y": b_y,
            "T_x": T_x, "T_y": T_y, "T_xy": T_xy,
            "S_star": S_star, "K_star": K_star, "w_star": w_star, "S_hat": S_hat, "X_hat": X_hat,
            "K_y": K_y, "w_y": w_y, "Y_star": Y_star, "K_ystar": K_ystar, "w_ystar": w_ystar, "Y_hat": Y_hat,
            "S_x2y": S_x2y, "S_y2x": S_y2x,
        }

    def forward(self, X: torch.Tensor, stage: int = 2, frame: torch.Tensor | None = None
                ) -> Stage1Output | SCAPOOutput:
        """Normalised points ``X (B, N, 3)`` -> :class:`~scapo.nn.outputs.Stage1Output` (``stage`` 1) or
        :class:`~scapo.nn.outputs.SCAPOOutput` (2: both stages; ``frame`` as :meth:`stage2`)."""
        s1 = self.stage1(X)
        if stage == 1:
            return s1
        return self._both(X, s1, frame)

    def _both(self, X: torch.Tensor, s1: Stage1Output, frame: torch.Tensor | None = None) -> SCAPOOutput:
        """Stage 2 on ``X`` after stage 1's output ``s1``, joined with it into one :class:`SCAPOOutput`."""
        return SCAPOOutput(**{f.name: getattr(s1, f.name) for f in dataclasses.fields(Stage1Output)},
                           **self.stage2(X, s1, frame))

    @property
    def uses_parts_frame(self) -> bool:
        """Whether stage 2 works in the parts-signed frame (``TrainConfig.stage2_frame = "parts"``)."""
        return bool(self.parts_frame.abs().sum() > 0)

    @torch.no_grad()
    def parts_frames(self, X: torch.Tensor, labels: torch.Tensor, min_points: int = 8) -> torch.Tensor:
        """The frames ``(B, 3, 3)`` (canonical -> camera) in which each cloud's base axes signed by its other parts are
        the template's (``TrainConfig.stage2_frame = "parts"``): ``E_i E_Y^T``, with ``E_i`` the signed principal axes
        (:func:`scapo.ops.signed_axes.parts_signed_axes`, ranks :attr:`parts_pair`, the base's directions as
        :attr:`parts_axes` says) of the points of ``X (B, N, 3)`` labelled 0 (the base) by ``labels (B, N)`` int64
        against the others, ``E_Y`` :attr:`parts_frame`. All zeros for a cloud whose axes are not found (fewer than
        ``min_points`` base or other points): :meth:`stage2` then keeps its stage-1 frame."""
        from scapo.ops.signed_axes import parts_signed_axes

        pair = tuple(int(k) for k in self.parts_pair)
        E, ok = parts_signed_axes(X.detach().double().cpu().numpy(), labels.cpu().numpy(), pair, 0, min_points,
                                  self.parts_axes)
        out = torch.from_numpy(E @ self.parts_frame.double().cpu().numpy().T).to(X)
        out[torch.from_numpy(~ok).to(X.device)] = 0.0
        return out

    @property
    def parts_axes(self) -> str:
        """How :meth:`parts_frames` finds the base's directions (``TrainConfig.parts_axes``): "pca" or "plane"."""
        return "plane" if int(self.parts_plane) else "pca"

    @torch.no_grad()
    def passes(self, X: torch.Tensor, starts: str = "off") -> SCAPOOutput:
        """Both stages on normalised points ``X (B, N, 3)`` as prediction runs them (in the module's current mode):
        one pass, then for a model trained with ``TrainConfig.stage2_frame = "parts"`` (:attr:`uses_parts_frame`)
        stage 2 :data:`PARTS_PASSES` more times, each in the frame read from the base the pass before labels
        (:meth:`parts_frames`); the last pass's :class:`~scapo.nn.outputs.SCAPOOutput`. Stage 1 runs once: its
        output does not depend on the frame, so the passes share it (the same outputs as :meth:`forward` per pass).

        ``starts`` (:attr:`scapo.models.refine.RefineConfig.stage2_starts`; such a model only, "off" for any other): a
        hypothesis set of the first pass's frame, ``F_k = R G_k`` with ``R`` stage 1's (branch-corrected) frame and
        ``G_k`` (K, 3, 3) the set's rotations (identity first; "D2": :func:`scapo.ops.groups.half_turns`, else
        :func:`scapo.ops.groups.rotation_group`). Each start runs all the passes, and each cloud keeps the outputs
        of the start whose template posed as the cloud (``S_y2x``) is nearest its points in the canonical frame:
        the one-sided Chamfer distance ``mean_i min_m |S_obj_i - S_y2x_m|^2`` (normalised units), the smallest
        wins, ties to the earlier start. A frame read from a near-symmetric view (a nearly shut laptop) lands on the
        wrong end of an axis, and its passes keep it there; the posed template then fits the points worse. The
        hypothesis choice follows OP-Align's anchor choice by the L1 nearest-neighbour distance from the aligned input
        to the reconstruction (``models/art_so3net_pn.py`` around lines 259-275) and EAP's. Cost: K times the passes.

        Raises:
            ValueError: an unknown ``starts`` (:data:`scapo.models.refine.STAGE2_STARTS`).
        """
        check_stage2_starts(starts)
        s1 = self.stage1(X)
        if starts == "off" or not self.uses_parts_frame:
            return self._passes_from(X, s1)
        G = stage2_start_rotations(starts).to(X)
        R0 = apply_branch(s1.enc.R, self.branch, self.branch_flip)
        best, best_d = None, None
        for g in G:
            out = self._passes_from(X, s1, R0 @ g)
            d = nearest_sq_dist(out.S_obj, out.S_y2x).mean(-1)  # (B,) one-sided: input -> posed template
            if best is None:
                best, best_d = out, d
                continue
            take = d < best_d
            best_d = torch.where(take, d, best_d)
            best = _where_clouds(take, out, best)
        return best

    def _passes_from(self, X: torch.Tensor, s1: Stage1Output, frame: torch.Tensor | None = None) -> SCAPOOutput:
        """:meth:`passes` from one first frame ``(B, 3, 3)`` (None: stage 1's)."""
        out = self._both(X, s1, frame)
        for _ in range(PARTS_PASSES if self.uses_parts_frame else 0):  # stage 2 again, in the frame the base it
            out = self._both(X, s1, self.parts_frames(X, out.w.argmax(-1)))  # found gives
        return out

    # ------------------------------------------------------------------ inference
    @torch.no_grad()
    def predict(self, points: torch.Tensor, refine: RefineConfig | None = None,
                upright: torch.Tensor | None = None) -> dict:
        """Inference on camera-frame points ``(B, N, 3)`` float32, metres (SPEC section 6 outputs).

        The network's passes are :meth:`passes` (in eval mode): a model trained with ``TrainConfig.stage2_frame =
        "parts"`` runs stage 2 :data:`PARTS_PASSES` more times in the frame read from the base it labels; the outputs
        are those of the last pass.

        With ``refine`` (``steps > 0``) the pose, joint states and joints come from the test-time
        articulated refinement (:mod:`scapo.models.refine`, an addition to the paper): the frame and
        states are fitted to the observed points, the joints are the template's (``c_Y, d_Y``) and each
        point's weights are those of its nearest point of the fitted template. ``upright (3,)``: the
        run's upright direction for the refinement's upright prior (``RefineConfig.upright_deg``).

        Returns float32 tensors on the input's device: ``T_cam_obj (B, 4, 4)`` (the base part's pose:
        the stage-1 frame, moved by the root state when ``cfg.root_motion``); ``part_label (B, N)``
        int64 (argmax of the skinning weights) and ``weights (B, N, P)``; ``part_pose (B, P, 4, 4)``
        (canonical rest -> camera, metres); ``joint_axis (B, J, 3)``, ``joint_pivot (B, J, 3)``
        (camera frame, m), ``joint_state (B, J)`` (rad / m from the canonical rest state);
        ``canonical_shape (B, N, 3)`` (``S*`` in metres) and ``template (B, M, 3)``; the template in its rest
        state ``template_rest (B, M, 3)`` (``Y*`` in metres, the canonical rest frame that every ``part_pose``
        maps to the camera) with ``template_label (B, M)`` int64 (argmax of its skinning weights): the
        whole-object model of :mod:`scapo.steps.refine`.
        """
        was_training = self.training
        self.eval()
        try:
            X, scale = self.normalize(points)
            out = self.passes(X, refine.stage2_starts if refine is not None else "off")
        finally:
            self.train(was_training)
        enc = out.enc
        R, t, T, pivot, axis, state = out.R, enc.t, out.T_x, out.pivot_x, out.axis_x, out.state_x
        weights = out.w
        if refine is not None and refine.steps > 0:
            r = refine_articulation(self.cfg, X, out, refine, upright)
            R, t, T, pivot, axis, state = r["R"], r["t"], r["T"], r["pivot"], r["axis"], r["state"]
            weights = r["weights"]
        B = points.shape[0]
        sc = scale[:, None, None]
        G = torch.zeros(B, 4, 4, dtype=points.dtype, device=points.device)
        G[:, :3, :3] = R
        G[:, :3, 3] = t * scale[:, None]
        G[:, 3, 3] = 1.0
        T = T.clone()
        T[..., :3, 3] = T[..., :3, 3] * scale[:, None, None]
        part_pose = G.unsqueeze(1) @ T
        prismatic = torch.tensor(self.cfg.joint_types, device=points.device) == 1
        state = torch.where(prismatic, state * scale[:, None], state)
        return {
            "T_cam_obj": part_pose[:, 0],
            "part_label": weights.argmax(-1),
            "weights": weights,
            "part_pose": part_pose,
            "joint_axis": axis @ R.transpose(1, 2),
            "joint_pivot": (pivot @ R.transpose(1, 2) + t[:, None]) * sc,
            "joint_state": state,
            "canonical_shape": out.S_star * sc,
            "template": out.Y * sc,
            "template_rest": out.Y_star * sc,
            "template_label": out.w_ystar.argmax(-1),
        }
