"""SCAPO losses: Chamfer distance, stage-1 and stage-2 terms, and their weighted sums."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from scapo.losses.scapo_losses import (
    augmentation_consistency_loss,
    candidate_rotations,
    canonical_consistency_loss,
    consensus_rotation_loss,
    cross_instance_alignment_loss,
    cross_space_loss,
    cycle_loss,
    dir_align_loss,
    joint_boundary_loss,
    joint_prox_loss,
    kp_seg_loss,
    orthonormality_loss,
    reconstruction_loss,
    seg_loss,
    shape_var_loss,
    template_loss,
)
from scapo.nn.outputs import SCAPOOutput, Stage1Output
from scapo.ops.chamfer import chamfer_distance, pairwise_sq_dist

#: Regularisers that can be switched off (Table 3 ablations and more).
REGULARISERS = ("kp_seg", "seg", "shape_var", "dir_align", "joint_prox", "joint_boundary")


@dataclass(frozen=True)
class LossConfig:
    """Loss weights (paper Sec. 4, implementation details) and switches."""

    rec: float = 1.0
    ortho: float = 0.1
    aug_consist: float = 0.1
    can_consist: float = 0.1
    align: float = 10.0
    """Cross-instance canonical alignment in stage 1 (an addition to the paper; 0 switches it off)."""
    align_in_stage2: bool = False
    """Keep the cross-instance alignment during stage 2. Off: it holds the whole-object frame and, on
    a laptop, tilts the learned hinge axis (see results/cpu_preset_history.md)."""
    template: float = 0.0
    """Weight of ``L_template`` in stage 1 (:func:`~scapo.losses.scapo_losses.template_loss`): every decoded canonical
    shape is pulled to one learnable category template in metres (``SCAPOModel.template_s1``), from the first step, so
    that a persistent shape, not each view's own decoding, decides the frame (an addition to the paper, testing
    the hypothesis that stage 2's template arrives after the frame is fixed; 0 switches it off)."""
    consensus: float = 0.0
    """Batch-consensus frame pseudo-label in stage 1 (an addition to the paper; 0 switches it off)."""
    consensus_small_deg: float = 25.0
    """Angle of the small candidate rotations of the consensus search."""
    cycle: float = 10.0
    recon: float = 10.0
    kp_seg: float = 1.0
    seg: float = 1.0
    shape_var: float = 10.0
    dir_align: float = 0.1
    joint_prox: float = 1.0
    joint_boundary: float = 3.0
    disabled: tuple[str, ...] = ()
    """Regularisers switched off, a subset of REGULARISERS."""
    lambda_var: float = 60.0
    """Scale of the shape-variance term."""
    lambda_prox: float = 30.0
    """Scale of the joint-proximity term."""
    kp_min_support: float = 0.02
    """tau of L_kp-seg as a fraction of the points."""
    boundary_temperature: float = 0.1
    """Temperature (normalised units) of the pivot-to-point attention of L_joint-boundary."""
    seg_fixed_centres: bool = True
    """``L_seg`` shapes the bones (orientations, scales) but does not move their centres (nor the points
    it is evaluated on). Through the centres, sharpening the weights rotates the split plane towards
    the long direction of the part boundary, i.e. it cuts a laptop across its hinge (an addition to
    the paper; False: the gradient reaches the centres too)."""
    stage1_in_stage2: float = 1.0
    """Multiplier of the stage-1 terms while training stage 2 end to end (0 freezes nothing but drops them)."""
    def __post_init__(self):
        from scapo.config import check_settings

        weights = [f.name for f in dataclasses.fields(self) if isinstance(getattr(self, f.name), float)]
        check_settings(self, non_negative=weights)  # every weight and scale finite and >= 0
        if self.boundary_temperature <= 0:
            raise ValueError(f"boundary_temperature must be > 0, got {self.boundary_temperature!r}")
        unknown = set(self.disabled) - set(REGULARISERS)
        if unknown:
            raise ValueError(f"unknown regularisers {sorted(unknown)}; known: {', '.join(REGULARISERS)}")

    def weight(self, name: str) -> float:
        return 0.0 if name in self.disabled else float(getattr(self, name))


def stage1_terms(model, X: torch.Tensor, s1: Stage1Output, cfg: LossConfig | None = None, align: bool = True,
                 scale: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Unweighted stage-1 loss terms (the two consistency terms use half of the batch, for speed).
    ``align`` False leaves out the cross-instance alignment term; ``consensus`` and ``template`` are computed when
    ``cfg`` gives them a positive weight (``scale (B,)``: the clouds' normalisation, which ``template`` needs)."""
    terms = {
        "rec": reconstruction_loss(X, s1.X_rec),
        "ortho": orthonormality_loss(s1.enc.R_raw),
        "aug_consist": augmentation_consistency_loss(model, X, s1, max_batch=max(2, X.shape[0] // 2)),
        "can_consist": canonical_consistency_loss(model, s1.S_dec[: max(2, X.shape[0] // 2)]),
    }
    if align:
        terms["align"] = cross_instance_alignment_loss(X, s1.enc.t, s1.enc.R)
    if cfg is not None and cfg.weight("template") > 0:
        if scale is None:
            raise ValueError("stage1_terms: L_template needs the clouds' scale (B,)")
        terms["template"] = template_loss(s1.S_dec, scale, model.template_s1)
    if cfg is not None and cfg.weight("consensus") > 0:
        enc = s1.enc
        terms["consensus"], _ = consensus_rotation_loss(X, enc.t, enc.R_raw, enc.R,
                                                        candidate_rotations(cfg.consensus_small_deg, X.dtype))
    return terms


def stage2_terms(model, X: torch.Tensor, out: SCAPOOutput, cfg: LossConfig) -> dict[str, torch.Tensor]:
    """Unweighted stage-2 loss terms (cycle, cross-space, regularisers); disabled ones are skipped."""
    mc = model.cfg
    jt, jp = mc.joint_types, mc.joint_parts
    terms = {
        "cycle": cycle_loss(X, out.X_hat) + cycle_loss(out.Y, out.Y_hat),
        "recon": cross_space_loss(out.S_x2y, out.Y, out.S_y2x, out.S_obj),
    }
    on = [r for r in REGULARISERS if r not in cfg.disabled]
    if "kp_seg" in on:
        terms["kp_seg"] = (kp_seg_loss(out.S_obj, out.w, out.K, cfg.kp_min_support)
                           + kp_seg_loss(out.Y, out.w_y, out.K_y, cfg.kp_min_support)
                           + kp_seg_loss(out.S_star, out.w_star, out.K_star, cfg.kp_min_support))
    if "seg" in on:
        if cfg.seg_fixed_centres:
            from scapo.nn.skinning import skinning_weights

            V, ls, g = out.V, out.log_scale, mc.gamma
            w = skinning_weights(out.S_obj.detach(), out.K.detach(), V, ls, g)[0]
            w_star = skinning_weights(out.S_star.detach(), out.K_star.detach(), V, ls, g)[0]
        else:
            w, w_star = out.w, out.w_star
        terms["seg"] = seg_loss(out.S_obj, w, out.K) + seg_loss(out.S_star, w_star, out.K_star)
    if "shape_var" in on:
        terms["shape_var"] = shape_var_loss(out.delta, cfg.lambda_var)
    if "dir_align" in on:
        terms["dir_align"] = (dir_align_loss(out.S_star, out.w_star, out.axis_x, jt, jp)
                              + dir_align_loss(out.Y, out.w_y, out.axis_y, jt, jp))
    if "joint_prox" in on:
        terms["joint_prox"] = (joint_prox_loss(out.S_star, out.pivot_x, jt, cfg.lambda_prox)
                               + joint_prox_loss(out.Y, out.pivot_y, jt, cfg.lambda_prox))
    if "joint_boundary" in on:
        terms["joint_boundary"] = (joint_boundary_loss(out.S_star, out.w_star, out.pivot_x, jt,
                                                       cfg.boundary_temperature)
                                   + joint_boundary_loss(out.Y, out.w_y, out.pivot_y, jt,
                                                         cfg.boundary_temperature))
    return terms


def weighted_total(terms: dict[str, torch.Tensor], cfg: LossConfig, stage: int) -> torch.Tensor:
    """Weighted sum of ``terms``; stage-1 terms are scaled by ``stage1_in_stage2`` during stage 2."""
    total = 0.0
    for name, value in terms.items():
        w = cfg.weight(name)
        if stage == 2 and name in ("rec", "ortho", "aug_consist", "can_consist", "align", "consensus", "template"):
            w *= cfg.stage1_in_stage2
        total = total + w * value
    return total


__all__ = ["LossConfig", "REGULARISERS", "chamfer_distance", "pairwise_sq_dist", "stage1_terms", "stage2_terms",
           "weighted_total"]
