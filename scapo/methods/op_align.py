"""OP-Align-style self-supervised baseline (object-level, then part-level alignment).

Follows OP-Align (Che, Furukawa and Kanezaki, "OP-Align: Object-level and Part-level Alignment for
Self-supervised Category-level Articulated Object Pose Estimation", ECCV 2024; public code
YC-Che/OP-Align, ``SPConvNets/models/art_so3net_pn.py``, ``art_encoder.py``, ``art_metric.py``):

1. Object level: a backbone lifted over a finite rotation group gives, per group element (anchor)
   ``G_g``, a residual rotation, a translation and an attention logit, and an invariant global
   feature. A decoder reconstructs the canonical shape ``Y`` from the invariant feature. The anchor
   whose pose brings the input closest to ``Y`` (mean nearest-neighbour distance, no gradient) is
   selected; the attention head learns to predict it. ``S = R^T X - t`` is the input in the canonical
   frame.
2. Part level: one point network, run on ``S`` and on ``Y``, predicts a soft segmentation and, per
   joint, a pivot, a direction and two articulation states (one per side of the joint). Each side's
   part of ``S`` is moved onto ``Y`` by aligning the joint directions and rotating about the axis by
   the difference of the states (translating along it for prismatic joints).
3. Losses, reconstruction only: a rigid Chamfer term ``CD(S, Y)`` whose weight halves on a schedule
   while the segmentation-weighted part-alignment term takes over; regularisers keep every part
   populated, pivots near the shape, the canonical shape's joints the same across instances, the
   object translation small, and the attention on the selected anchor. No labels are used.

What differs (and why):

- Backbone: OP-Align uses E2PN (an SE(3)-equivariant point convolution over the 60 icosahedral
  anchors, a compiled extension). Here a ResNet-PointNet with shared weights is run on the input
  rotated into every anchor frame (group lifting: exactly equivariant to the group, approximately to
  SO(3) through the residual rotation), pure PyTorch. The ``cpu`` preset uses the 24 cube rotations,
  ``paper`` the 60 icosahedral ones.
- Chamfer distances are density-aware as OP-Align's (``1 - exp(-alpha d)`` per nearest squared distance,
  batched matrix products instead of pytorch3d's kNN); no colour channel (the datasets are depth only); the
  canonical shape is a learnable category template plus an MLP-decoded per-instance offset.
- Parts that appear on several joints (the base of a star) are aligned once per joint, with a consistency term as
  in OP-Align's three-part case.
- Outputs for the evaluator: the part pose of part ``p`` maps the canonical frame (scaled to metres
  by the cloud's normalisation) to the camera through the inverse of its part alignment and the
  object pose; ``T_cam_obj`` is the base part's pose (the root of the kinematic tree), the dataset's
  convention, as OP-Align itself evaluates part poses (``art_metric.py`` 133-141): the object-level
  rotation alone is a rigid fit of the whole articulated shape and turns with the joint state. Joint
  axes and pivots are the input-side predictions mapped to the camera; the state is the input's
  relative state minus the canonical shape's.

Fidelity (read against YC-Che/OP-Align at f3323dd; "same" = same component and rule, "simplified" = the
component's role kept with a different form, "absent" = not implemented; a gap is closed or stated, never silent):

=========================================  ==============================================  ==========================
component                                  original (file: lines)                          ours
=========================================  ==============================================  ==========================
SE(3)-equivariant backbone over 60 anchors ``art_so3net_pn.py`` 21-45, E2PN                simplified: PointResNet on
                                           (``vgtk``, CUDA), ``--kanchor 60``               the cloud rotated into each
                                                                                           anchor (24 in ``cpu``, 60
                                                                                           in ``paper``)
input points                               ``options.py`` 28 (``--input-num 1024``)        ``cpu``: 256, and 96 to the
                                                                                           anchor backbone; ``paper``:
                                                                                           1024 / 1024
residual rotation per anchor, bounded      ``art_so3net_pn.py`` 273-278 (angle within      same: unit axis x angle
                                           +-pi/10 of the anchor)                          within +-18 deg
anchor chosen by Chamfer, no gradient      ``art_so3net_pn.py`` 101-142                    same (mean nearest distance)
attention on the chosen anchor             ``art_metric.py`` 99, 184-187 (attention x      same (``attention =
                                           distance)                                       "expected"``)
learnable category shape ``y_base`` plus   ``art_so3net_pn.py`` 305-357 (``y_base`` 340,  same (``template_prior``;
a per-instance offset                      offset 349)                                     an MLP decoder, no BN)
variance penalty on the offset             ``art_metric.py`` 83, 302-307                   same (weight 10, alpha 60)
density-aware Chamfer (``1 - exp(-a d)``)  ``art_metric.py`` 77-78, 169-178, 234-239       same (alpha 30 / 120) in
                                                                                           the rigid and part terms
local-density term on the canonical shape  ``art_metric.py`` 82, 241-254                   same (weight 200, k 64)
canonical shape centred                    ``art_metric.py`` 84, 295-300                   same
rigid term halving on a schedule           ``art_metric.py`` 72-74 (every 5000 iters)      same rule: every quarter
                                                                                           of training (``paper``:
                                                                                           5,000 iterations)
part-level network on S and on Y, joint    ``art_so3net_pn.py`` 52-55 (``ResnetPointnet``) same outline
pivot, direction and two states per side
segmentation-weighted part alignment       ``art_metric.py`` 78, 189-232                   same: each moved part
                                                                                           against all of Y, weighted
                                                                                           by each side's segmentation
canonical joints fixed across instances    ``art_metric.py`` 86, 256-265: states to 0,     same (weight 10)
                                           directions to their batch mean, pivots free
pivot near the shape                       ``art_metric.py`` 87-88, 267-274: mean distance  same (weight 0.1 each on
                                           to the 8 nearest points of the detached shape,  S and Y)
                                           ``1 - exp(-30 d^2)``
part populated / probability floor         ``art_metric.py`` 101, 317-325; ``options.py``   same: 0.05 on the
                                           74 (``--prob-threshold 0.05``)                  canonical shape, floor
                                                                                           0.01 on both, weight 10
joint-direction noise in training          ``art_encoder.py`` 134-140 (uniform, width      same
                                           0.01, renormalised)
cloud normalisation                        ``LightDataset.py`` 45-50: centroid, mean        same (0.25)
                                           centroid distance 0.25
object frame reported                      part poses evaluated (``art_metric.py``         ``T_cam_obj`` = the base
                                           133-141)                                        part's pose
translation offset small                   ``art_metric.py`` 100                           same
colour channel                             ``art_metric.py`` 78 (``color_w``)              absent (depth only)
schedule                                   ``options.py`` 89-127: 20,000 iterations,       ``paper``: same; ``cpu``:
                                           batch 16, lr 1e-4 halved every 5,000            20 epochs (about 1,300
                                                                                           iterations), lr 1e-3
evaluation: half-turn forgiven on laptop   ``art_metric.py`` 391-455, 513-545              our ``op-align`` protocol
and eyeglasses                                                                             (``scapo.eval.protocols``)
=========================================  ==============================================  ==========================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from scapo.errors import ConfigError
from scapo.losses.supervised import joint_loss, seg_nll
from scapo.methods.learned import LearnedPreset, LearnedSpec, register_learned
from scapo.methods.nets import PointResNet, mlp
from scapo.ops.chamfer import nearest_sq_dist, pairwise_sq_dist
from scapo.ops.groups import rotation_group
from scapo.ops.so3 import rotation_from_rotvec as exp_so3
from scapo.registry import Registry


@dataclass(frozen=True)
class OPAlignPreset(LearnedPreset):
    """Preset of the OP-Align-style baseline."""

    group: str = "O"
    """Anchors: a finite rotation group ("O": 24 cube rotations, "I": 60 icosahedral)."""
    anchor_points: int = 256
    """Points fed to the anchor-lifted object-level backbone (a subsample)."""
    width: int = 96
    blocks: int = 2
    part_width: int = 128
    template_points: int = 512
    """Points of the reconstructed canonical shape."""
    max_residual_deg: float = 18.0
    """Largest residual rotation per anchor: a unit axis times an angle within +-this (OP-Align:
    ``(sigmoid - 0.5) pi / 5``, +-18 deg, ``art_so3net_pn.py`` 273-278)."""
    template_prior: bool = True
    """Canonical shape = a learnable category template ``y_base`` plus a decoded per-instance offset
    (``art_so3net_pn.py`` 340-349); False: the decoder gives the shape itself."""
    var_weight: float = 10.0
    """Weight of the offset's variance penalty ``mean(1 - exp(-var_alpha |offset|^2))`` (``art_metric.py`` 83,
    302-307); used with ``template_prior``."""
    var_alpha: float = 60.0
    density_alpha: float = 30.0
    """Density-aware Chamfer: each nearest squared distance ``d`` counts as ``1 - exp(-alpha d)``, the direction
    from the canonical shape with ``density_alpha_inv`` and weight ``alpha / alpha_inv`` (``art_metric.py``
    77-78, 169-178, 234-239); 0: plain squared Chamfer."""
    density_alpha_inv: float = 120.0
    gather_weight: float = 200.0
    """Weight of the canonical shape's local-density term: the variance over its points of the distance to the
    k-th nearest neighbour, averaged over k = 1..``gather_k`` (``art_metric.py`` 82, 241-254)."""
    gather_k: int = 64
    center_weight: float = 1.0
    """Weight of ``|mean(Y)|^2``, the canonical shape centred (``art_metric.py`` 84, 295-300)."""
    attention: str = "expected"
    """Attention term: ``"expected"`` the anchors' softmax times their Chamfer distances, summed (OP-Align,
    ``art_metric.py`` 99, 184-187); ``"ce"`` cross-entropy on the chosen anchor."""
    rotation_range_deg: float = 180.0
    """Range of each articulation state (revolute; a prismatic state spans range / 180 cloud scales)."""
    rigid_weight: float = 0.5
    rigid_halve: float = 0.25
    """The rigid term's weight halves every this fraction of training (OP-Align: every 5,000 of its 20,000
    iterations, ``art_metric.py`` 72-74, ``options.py`` 89)."""
    prob_threshold: float = 0.05
    """Smallest mean segmentation probability of a part of the canonical shape before the balance term acts
    (OP-Align: ``--prob-threshold 0.05``, ``options.py`` 74, on ``I_seg`` alone, ``art_metric.py`` 101, 317-325)."""
    prob_floor: float = 0.01
    """Every point's smallest part probability is pulled up to this, on the input and the canonical shape
    (``min_prob = 1e-2``, ``art_metric.py`` 101, 321-323)."""
    drct_noise: float = 0.01
    """Training only: each predicted joint direction gets uniform noise of this width per component before it is
    renormalised (``art_encoder.py`` 134-140)."""
    supervision: str = ""
    """Labels training may use (:mod:`scapo.losses.supervised`): "" self-supervised (the paper's Table 1 row),
    "SJ" the paper's "OP-Align (SJ)" row of Table 2; preset suffix ``/sj``."""
    sup_weight: float = 1.0
    """Weight of the supervised terms."""

    def __post_init__(self):
        super().__post_init__()
        from scapo.losses.supervised import check_supervision

        if self.attention not in ("expected", "ce"):
            raise ConfigError(f"preset {self.name!r}: attention must be 'expected' or 'ce', got {self.attention!r}")
        if not 0 < self.max_residual_deg <= 180 or self.density_alpha < 0 or self.density_alpha_inv < 0 \
                or self.gather_k < 1 or not 0 <= self.prob_threshold < 1 or not 0 <= self.prob_floor < 1 \
                or self.drct_noise < 0 or not 0 < self.rigid_halve <= 1:
            raise ConfigError(f"preset {self.name!r}: needs 0 < max_residual_deg <= 180, density alphas >= 0, "
                              "gather_k >= 1, 0 <= prob_threshold < 1, 0 <= prob_floor < 1, drct_noise >= 0, "
                              "0 < rigid_halve <= 1")

        if check_supervision(self.supervision) != self.supervision:
            raise ConfigError(f"preset {self.name!r}: write supervision as one of '', 'S', 'J', 'SJ', got "
                              f"{self.supervision!r}")


PRESETS: Registry[OPAlignPreset] = Registry("op-align preset")
# cpu: the tables' equal training budget (15 minutes of training per cell on one core, the tables' 840 training clouds);
# the epochs fill it at the speed measured by scapo bench perf --what train --data
# (results/perf/train_cpu_laptop_i150_v8_s1_op-align.md)
PRESETS.add("cpu", OPAlignPreset(name="cpu", epochs=28, batch_size=16, lr=1e-3, points=256, max_steps_per_epoch=100,
                                 anchor_points=96, width=64, part_width=96, template_points=256))
# paper: the original's schedule (options.py 28, 89-127: 1024 points, 20,000 iterations of batch 16, lr 1e-4 halved
# every 5,000; the 60 icosahedral anchors), the rigid term halving every 5,000 iterations (art_metric.py 72-74)
PRESETS.add("paper", OPAlignPreset(name="paper", batch_size=16, lr=1e-4, points=1024, group="I",
                                   anchor_points=1024, width=128, blocks=3, part_width=256, template_points=1024,
                                   iterations=20000, lr_schedule="step", lr_decay=0.5, lr_decay_steps=5000))
PRESETS.add("test", OPAlignPreset(name="test", epochs=2, batch_size=4, points=128, anchor_points=64, width=32,
                                  blocks=2, part_width=32, template_points=64, max_steps_per_epoch=2, group="T"))


#: Mean distance of the normalised cloud's points from its centroid (OP-Align's synthetic loader,
#: ``LightDataset.py`` 45-50); its density terms' constants (alpha 30 / 120 / 60) were set at this scale.
CLOUD_SCALE = 0.25


def normalize_op_align(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """OP-Align's normalisation: ``points (B, N, 3)`` metres -> (``(points - c) / s``, centre ``c (B, 3)``, scale
    ``s (B,)`` metres per unit) with ``c`` the centroid and ``s`` the mean centroid distance over
    :data:`CLOUD_SCALE`, so the normalised cloud's mean centroid distance is 0.25."""
    c = points.mean(1)
    x = points - c[:, None]
    s = (x.norm(dim=-1).mean(-1) / CLOUD_SCALE).clamp_min(1e-6)
    return x / s[:, None, None], c, s


def pivot_near(pivot: torch.Tensor, shape: torch.Tensor, k: int = 8, alpha: float = 30.0) -> torch.Tensor:
    """OP-Align's pivot-near-shape term (``art_metric.py`` 87-88, 267-274): per pivot the mean distance to its
    ``k`` nearest points of ``shape`` (detached: the term moves the pivots, not the shape), as
    ``1 - exp(-alpha d^2)``, averaged; ``pivot (B, J, 3)``, ``shape (B, M, 3)`` -> scalar."""
    d = pairwise_sq_dist(pivot, shape.detach()).topk(min(k, shape.shape[1]), dim=-1, largest=False).values
    mean_d = d.clamp_min(1e-12).sqrt().mean(-1)
    return (1.0 - torch.exp(-alpha * mean_d ** 2)).mean()


def direction_rotation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The smallest rotation taking unit vectors ``a`` onto ``b`` (``(..., 3)`` -> ``(..., 3, 3)``)."""
    v = torch.cross(a, b, dim=-1)
    c = (a * b).sum(-1, keepdim=True).clamp(-1 + 1e-6, 1.0)
    s = v.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    angle = torch.atan2(s, c)
    return exp_so3(v / s * angle)


def _density(d: torch.Tensor, alpha: float) -> torch.Tensor:
    """Density-aware distance ``1 - exp(-alpha d)`` of squared nearest distances ``d``; ``d`` itself for 0."""
    return 1.0 - torch.exp(-alpha * d) if alpha > 0 else d


def _inv_weight(alpha: float, alpha_inv: float) -> float:
    """Weight of the direction from the canonical shape: ``alpha / alpha_inv`` (OP-Align), 1 for plain Chamfer."""
    return alpha / alpha_inv if alpha > 0 and alpha_inv > 0 else 1.0


def density_chamfer(a: torch.Tensor, b: torch.Tensor, alpha: float, alpha_inv: float) -> torch.Tensor:
    """OP-Align's density-aware Chamfer distance (``art_metric.py`` 169-178, 234-239) per batch element ``(B,)``:
    ``mean_a (1 - exp(-alpha d_a)) + alpha / alpha_inv mean_b (1 - exp(-alpha_inv d_b))`` with ``d`` the squared
    distance to the nearest point of the other cloud; ``a (B, N, 3)`` the input side, ``b (B, M, 3)`` the
    canonical shape. ``alpha = 0``: the plain squared Chamfer distance. Each term lies in [0, 1): a far outlier
    costs at most 1, so the loss follows the density of the matched points rather than their extremes."""
    da, db = nearest_sq_dist(a, b, both=True)
    return _density(da, alpha).mean(-1) + _inv_weight(alpha, alpha_inv) * \
        _density(db, alpha_inv if alpha > 0 else 0.0).mean(-1)


def local_density(Y: torch.Tensor, k: int) -> torch.Tensor:
    """OP-Align's local-density term of a point set ``Y (B, M, 3)`` (``art_metric.py`` 241-254) per batch element
    ``(B,)``: for each k' = 1..k the variance over the points of the distance to their k'-th nearest neighbour,
    averaged over k'. 0 for evenly spread points; it keeps the canonical shape from clumping."""
    k = min(int(k), Y.shape[1] - 1)
    d = pairwise_sq_dist(Y, Y).clamp_min(1e-12).sqrt()
    knn = d.topk(k + 1, dim=-1, largest=False).values[..., 1:]  # (B, M, k), self excluded
    return knn.var(dim=1).mean(-1)


def offset_variance(offset: torch.Tensor, alpha: float) -> torch.Tensor:
    """OP-Align's penalty on the per-instance offset of the category template (``art_metric.py`` 302-307) per
    batch element ``(B,)``: ``mean_m (1 - exp(-alpha |offset_m|^2))``; ``offset (B, M, 3)``."""
    return (1.0 - torch.exp(-alpha * (offset ** 2).sum(-1))).mean(-1)


class OPAlignNet(nn.Module):
    """The two-level network (see the module docstring). Points are rows: ``x' = x R^T + t``."""

    def __init__(self, num_parts: int, joint_types, joint_parts, preset: OPAlignPreset):
        super().__init__()
        self.P, self.pc = num_parts, preset
        self.joint_types = [int(t) for t in joint_types]
        self.joint_parts = [tuple(int(x) for x in p) for p in joint_parts]
        self.J = len(self.joint_types)
        self.register_buffer("anchors", torch.from_numpy(np.array(rotation_group(preset.group))).float())
        w = preset.width
        self.obj = PointResNet(3, w, preset.blocks)
        self.anchor_head = mlp([w, w, 3 + 1 + 3 + 1])  # residual axis, angle, translation, attention logit
        self.decoder = mlp([w, 2 * w, 4 * w, 3 * preset.template_points])
        # the learnable category template y_base (OP-Align: Xavier-initialised); the decoder gives its offset
        self.y_base = nn.Parameter(nn.init.xavier_uniform_(torch.zeros(preset.template_points, 3))) \
            if preset.template_prior else None
        self.part = PointResNet(3, preset.part_width, preset.blocks + 1)
        self.seg = mlp([preset.part_width, preset.part_width // 2, num_parts])
        self.joint = mlp([preset.part_width, preset.part_width, 8 * self.J])
        # (joint, side) -> part: side 0 is the parent part, side 1 the child part
        self.sides = [(j, a, self.joint_parts[j][a]) for j in range(self.J) for a in range(2)]
        # the base part: the root of the kinematic tree (a parent that is no joint's child), part 0 without joints
        children = {c for _, c in self.joint_parts}
        self.base = next((p for p, _ in self.joint_parts if p not in children), 0)

    # ---------------------------------------------------------------- object level
    def object_level(self, X: torch.Tensor) -> dict:
        """Per-anchor poses and the canonical shape for normalised ``X (B, N, 3)``."""
        B, N, _ = X.shape
        G = self.anchors.to(X)  # (A, 3, 3)
        A = G.shape[0]
        n = min(self.pc.anchor_points, N)
        sub = X[:, torch.linspace(0, N - 1, n, device=X.device).long()]
        Xa = torch.einsum("bni,aij->banj", sub, G).reshape(B * A, n, 3)  # points in each anchor frame: G^T x
        _, f = self.obj(Xa)
        f = f.view(B, A, -1)
        h = self.anchor_head(f)
        rmax = np.radians(self.pc.max_residual_deg)
        angle = 2 * rmax * (torch.sigmoid(h[..., 3:4]) - 0.5)  # within +-rmax
        res = exp_so3(F.normalize(h[..., :3] + 1e-8, dim=-1) * angle)
        R = G.unsqueeze(0) @ res  # (B, A, 3, 3)
        t = 0.5 * torch.tanh(h[..., 4:7])  # canonical-frame translation of the aligned cloud
        out = self.decoder(f.max(1).values).view(B, -1, 3)
        if self.y_base is None:
            return {"R": R, "t": t, "attn": h[..., 7], "Y": out, "offset": None}
        return {"R": R, "t": t, "attn": h[..., 7], "Y": self.y_base.unsqueeze(0) + out, "offset": out}

    def select(self, X: torch.Tensor, o: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """Index (B,) of the anchor whose pose brings ``X`` closest to ``Y``, and every anchor's distance (B, A):
        the mean squared distance of the input to ``Y`` (no gradient; ``art_so3net_pn.py`` 101-142)."""
        with torch.no_grad():
            B, A = o["R"].shape[:2]
            n = min(256, X.shape[1])
            sub = X[:, torch.linspace(0, X.shape[1] - 1, n, device=X.device).long()]
            S = torch.einsum("bni,baij->banj", sub, o["R"]) - o["t"][:, :, None]
            d = pairwise_sq_dist(S.reshape(B * A, n, 3), o["Y"].detach().repeat_interleave(A, 0)).min(-1).values
            dist = d.mean(-1).view(B, A)
            return dist.argmin(1), dist

    # ---------------------------------------------------------------- part level
    def part_level(self, P: torch.Tensor) -> dict:
        """Segmentation and joints of clouds ``P (B, N, 3)`` in the canonical frame."""
        h, g = self.part(P)
        seg = torch.softmax(self.seg(h), -1)  # (B, N, P)
        j = self.joint(g).view(-1, self.J, 8)
        drct = F.normalize(j[..., 3:6] + 1e-6, dim=-1)
        if self.training and self.pc.drct_noise > 0:  # art_encoder.py 134-140
            drct = F.normalize(drct + self.pc.drct_noise * (torch.rand_like(drct) - 0.5), dim=-1)
        rng = np.radians(self.pc.rotation_range_deg)
        state = rng * (torch.sigmoid(j[..., 6:8]) - 0.5)  # (B, J, 2)
        return {"seg": seg, "pivot": j[..., :3], "drct": drct, "state": state}

    def side_motion(self, src: dict, dst: dict, j: int, a: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Rigid motion ``(R (B, 3, 3), t (B, 3))`` moving side ``a`` of joint ``j`` from ``src`` to ``dst``:
        to the pivot, align the directions, move by the state difference, back to ``dst``'s pivot."""
        Rd = direction_rotation(src["drct"][:, j], dst["drct"][:, j])
        delta = dst["state"][:, j, a] - src["state"][:, j, a]
        d = dst["drct"][:, j]
        if self.joint_types[j] == 0:
            R = exp_so3(d * delta[:, None]) @ Rd
            t = dst["pivot"][:, j] - (R @ src["pivot"][:, j, :, None]).squeeze(-1)
        else:
            R = Rd
            t = dst["pivot"][:, j] - (R @ src["pivot"][:, j, :, None]).squeeze(-1) + d * delta[:, None] / np.pi
        return R, t

    def forward(self, X: torch.Tensor) -> dict:
        o = self.object_level(X)
        idx, dist = self.select(X, o)
        ar = torch.arange(X.shape[0], device=X.device)
        R, t = o["R"][ar, idx], o["t"][ar, idx]
        S = X @ R - t[:, None]  # R^T x - t
        return {**o, "idx": idx, "anchor_dist": dist, "R_sel": R, "t_sel": t, "S": S, "s": self.part_level(S),
                "y": self.part_level(o["Y"])}

    # ---------------------------------------------------------------- training
    def losses(self, batch: dict, progress: float) -> tuple[dict, torch.Tensor]:
        """Training terms and total (the module docstring; weights as ``art_metric.py`` 75-101)."""
        X, _, _ = normalize_op_align(batch["points"].float())
        out = self(X)
        S, Y, s, y = out["S"], out["Y"], out["s"], out["y"]
        pc = self.pc
        a, a_inv = pc.density_alpha, pc.density_alpha_inv
        rigid = density_chamfer(S, Y, a, a_inv).mean()
        # each part's side of S moved onto Y (a part on several joints: the mean of its copies, as OP-Align's
        # eyeglasses case), then matched against the whole of Y, weighted by the segmentations (art_metric 189-232)
        moved, copies = {}, []
        for j, side, p in self.sides:
            R, t = self.side_motion(s, y, j, side)
            Sp = S @ R.transpose(1, 2) + t[:, None]
            if p in moved:
                copies.append(((Sp - moved[p][0]) ** 2).sum(-1).mean())
            moved.setdefault(p, []).append(Sp)
        parts = sorted(moved)
        Sm = {p: torch.stack(moved[p]).mean(0) for p in parts}
        near_p = [nearest_sq_dist(Sm[p], Y, both=True) for p in parts]
        d_fwd = torch.stack([_density(df, a) for df, _ in near_p], -1)  # (B, N, P')
        d_inv = torch.stack([_density(di, a_inv) for _, di in near_p], -1)  # (B, M, P')
        ws, wy = s["seg"][..., parts], y["seg"][..., parts]
        art = (d_fwd * ws).sum(-1).mean(-1) + _inv_weight(a, a_inv) * (d_inv * wy).sum(-1).mean(-1)
        art = art.mean()
        w_rigid = pc.rigid_weight * 0.5 ** int(progress / pc.rigid_halve)
        # every part of the canonical shape populated, every point some probability of every part (art_metric 317-325)
        balance = F.relu(pc.prob_threshold - y["seg"].mean(1)).mean() + sum(
            F.relu(pc.prob_floor - o["seg"].min(-1).values).mean() for o in (s, y))
        near = pivot_near(s["pivot"], S) + pivot_near(y["pivot"], Y)
        # the canonical shape's states at 0 and its directions at their batch mean; its pivots free (art_metric
        # 256-265: the pivot term is commented out there)
        cano = (y["state"] ** 2).mean() + ((y["drct"] - y["drct"].mean(0, keepdim=True)) ** 2).sum(-1).mean()
        if pc.attention == "expected":  # the attention's expected Chamfer distance over the anchors
            attn = (torch.softmax(out["attn"], -1) * out["anchor_dist"]).sum(-1).mean()
        else:
            attn = F.cross_entropy(out["attn"], out["idx"])
        toff = (out["t_sel"] ** 2).sum(-1).mean()
        terms = {"rigid": rigid, "art": art, "balance": balance, "pivot_near": near, "cano_joint": cano,
                 "attn": attn, "t_offset": toff}
        total = 10 * (w_rigid * rigid + (1 - w_rigid) * art) + 10 * balance + 0.1 * near + 10 * cano + attn + toff
        if pc.gather_weight > 0:
            terms["density"] = local_density(Y, pc.gather_k).mean()
            total = total + pc.gather_weight * terms["density"]
        if pc.center_weight > 0:
            terms["center"] = (Y.mean(1) ** 2).sum(-1).mean()
            total = total + pc.center_weight * terms["center"]
        if out["offset"] is not None and pc.var_weight > 0:
            terms["shape_var"] = offset_variance(out["offset"], pc.var_alpha).mean()
            total = total + pc.var_weight * terms["shape_var"]
        if copies:
            terms["same_part"] = sum(copies) / len(copies)
            total = total + 10 * terms["same_part"]
        if pc.supervision:  # the semi-supervised setting (Table 2's "OP-Align (SJ)")
            extra = {}
            if "part_label" in batch:
                extra["sup_seg"] = seg_nll(s["seg"], batch["part_label"])
            if "joint_axis" in batch and self.J:
                R, t = out["R_sel"], out["t_sel"]
                _, c, sc = normalize_op_align(batch["points"].float())
                axis = (R[:, None] @ s["drct"][..., None]).squeeze(-1)
                pivot = (R[:, None] @ (s["pivot"] + t[:, None])[..., None]).squeeze(-1)
                gt_pivot = (batch["joint_pivot"].to(X) - c[:, None]) / sc[:, None, None]
                extra["sup_joint"] = joint_loss(axis, pivot, batch["joint_axis"].to(X), gt_pivot, self.joint_types)
            terms.update(extra)
            total = total + pc.sup_weight * sum(extra.values())
        return terms, total

    # ---------------------------------------------------------------- inference
    @torch.no_grad()
    def infer(self, points: torch.Tensor) -> dict:
        """Predictions for ``points (B, N, 3)`` metres (camera frame); numpy arrays (see Predictions), and the
        decoded canonical shape as the whole-object model of :mod:`scapo.steps.refine`: ``template (B, M, 3)``
        (``sc Y``, metres, the canonical frame, which every part pose maps to the camera) and
        ``template_label (B, M)`` (the part-level network's segmentation of ``Y``).

        Canonical coordinates are the network's, times the cloud's scale ``sc`` (metres):
        ``x_cam = sc R (S + t) + c`` and part ``p``'s alignment maps ``S`` onto ``Y``.
        """
        X, c, sc = normalize_op_align(points.float())
        out = self(X)
        B = X.shape[0]
        R, t, s, y = out["R_sel"], out["t_sel"], out["s"], out["y"]
        eye = torch.eye(4, dtype=X.dtype, device=X.device)
        poses = eye.repeat(B, self.P, 1, 1)
        done = set()
        for j, a, p in self.sides:
            if p in done:
                continue
            done.add(p)
            Ra, ta = self.side_motion(s, y, j, a)  # S -> Y; its inverse maps Y -> S
            Rinv = Ra.transpose(1, 2)
            tinv = -(Rinv @ ta[:, :, None]).squeeze(-1)
            poses[:, p, :3, :3] = R @ Rinv
            poses[:, p, :3, 3] = sc[:, None] * (R @ (tinv + t)[:, :, None]).squeeze(-1) + c
        T_obj = poses[:, self.base]  # the dataset's object frame: the base part's pose (docs/usage.md)
        axis = (R[:, None] @ s["drct"][..., None]).squeeze(-1)
        pivot = sc[:, None, None] * (R[:, None] @ (s["pivot"] + t[:, None])[..., None]).squeeze(-1) + c[:, None]
        rel_s = s["state"][..., 1] - s["state"][..., 0]
        rel_y = y["state"][..., 1] - y["state"][..., 0]
        state = rel_s - rel_y
        pr = torch.tensor([jt == 1 for jt in self.joint_types], device=X.device)
        state = torch.where(pr[None], state / np.pi * sc[:, None], state)
        return {"part_label": s["seg"].argmax(-1).cpu().numpy(), "part_pose": poses.double().cpu().numpy(),
                "joint_axis": F.normalize(axis, dim=-1).double().cpu().numpy(),
                "joint_pivot": pivot.double().cpu().numpy(), "joint_state": state.double().cpu().numpy(),
                "T_cam_obj": T_obj.double().cpu().numpy(),
                "template": (sc[:, None, None] * out["Y"]).double().cpu().numpy(),
                "template_label": y["seg"].argmax(-1).cpu().numpy()}


def _build(card: dict, preset: OPAlignPreset) -> OPAlignNet:
    return OPAlignNet(len(card["part_names"]), card["joint_type"], card["joint_parts"], preset)


SPEC = LearnedSpec(method="op-align", presets=PRESETS, fields=("points",), build=_build)
make_op_align = register_learned(SPEC, display="OP-Align-style", supervision={"pose": False, "segmentation": False,
                                                                              "joint": False},
                                 needs_alignment=True, summary="self-supervised object- then part-level alignment "
                                 "to a reconstructed canonical shape (Che et al., ECCV 2024)", refinable=True,
                                 paper_row="OP-Align")
