"""Typed outputs of SCAPO's forward pass (:class:`scapo.models.scapo_model.SCAPOModel`), read by the losses
(:mod:`scapo.losses`), the trainer and the test-time refinement (:mod:`scapo.models.refine`). They live
below the losses (in :mod:`scapo.nn`) so that the losses can name them.

Shapes: ``B`` clouds of ``N`` points, ``P`` parts, ``J`` joints, ``M`` template points, ``D`` the encoder's
code width; every point set is in units of the normalised cloud (``SCAPOModel.normalize``: 2 x RMS radius),
float32 unless the input was float64. Frames: "camera" is the normalised input's frame; "canonical" the
stage-1 canonical frame (``S_obj = R^T (X - t)``); "rest" the canonical rest state (joints at zero);
"template" the category template's space (``Y``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from scapo.nn.encoder import EncoderOutput


@dataclass(frozen=True)
class Stage1Output:
    """Stage 1 (canonicalisation, the paper's Sec. 3.1).

    Attributes:
        enc: the encoder's :class:`~scapo.nn.encoder.EncoderOutput` (rotation ``R (B, 3, 3)`` canonical -> camera,
            translation ``t (B, 3)``, invariant ``code (B, D)``).
        S_dec: ``(B, N, 3)`` the decoded canonical shape. F_x: ``(B, F)`` the decoder's last hidden features.
        X_rec: ``(B, N, 3)`` the reconstruction in the camera frame (``S_dec R^T + t``).
    """

    enc: EncoderOutput
    S_dec: torch.Tensor
    F_x: torch.Tensor
    X_rec: torch.Tensor

    def __getitem__(self, name: str):
        """``out["S_star"]`` is ``out.S_star``: read access by name, for code written against the dict outputs
        of earlier versions (raises KeyError for an unknown name)."""
        try:
            return getattr(self, name)
        except AttributeError:
            raise KeyError(name) from None


@dataclass(frozen=True)
class SCAPOOutput(Stage1Output):
    """Stages 1 and 2 (joint-aware blend skinning with a learnable template, Sec. 3.2-3.3).

    Attributes (besides :class:`Stage1Output`'s):
        R: ``(B, 3, 3)`` the frame used by stage 2 (the stage-1 rotation, branch-corrected).
        S_obj: ``(B, N, 3)`` the input in the canonical frame.
        K, V, log_scale: ``(B, P, 3)``, ``(B, P, 3, 3)``, ``(B, P, 3)`` keypoints, orientations and log scales of
            the parts' Gaussian influence (canonical frame).
        w, W: ``(B, N, P)`` skinning weights of ``S_obj`` (normalised) and their unnormalised densities.
        Y: ``(B, M, 3)`` the template (``y_base + delta``); delta: ``(B, M, 3)`` the per-instance residual.
        pivot_x, axis_x, state_x, root_x: the input's joints: ``(B, J, 3)`` pivots and unit axes (canonical),
            ``(B, J)`` states (rad or normalised units), ``(B,)`` root state (None without ``root_motion``).
        pivot_y, axis_y, state_y, root_y: the same for the template.
        T_x, T_y: ``(B, P, 4, 4)`` bone transforms rest -> canonical of the input and the template.
        T_xy: ``(B, P, 4, 4)`` cross-space transforms input -> template.
        S_star, K_star, w_star: ``(B, N, 3)``, ``(B, P, 3)``, ``(B, N, P)``: the input carried to the rest state
            (backward deformation), its keypoints and weights.
        S_hat, X_hat: ``(B, N, 3)`` the rest-state input deformed forward again (canonical) and in the camera frame.
        K_y, w_y: the keypoints carried into template space and the template's weights.
        Y_star, K_ystar, w_ystar, Y_hat: the template at rest, its keypoints and weights, and deformed back.
        S_x2y, S_y2x: ``(B, N, 3)``, ``(B, M, 3)`` the cross-space maps of input and template.
    """

    R: torch.Tensor
    S_obj: torch.Tensor
    K: torch.Tensor
    V: torch.Tensor
    log_scale: torch.Tensor
    w: torch.Tensor
    W: torch.Tensor
    Y: torch.Tensor
    delta: torch.Tensor
    pivot_x: torch.Tensor
    axis_x: torch.Tensor
    state_x: torch.Tensor
    pivot_y: torch.Tensor
    axis_y: torch.Tensor
    state_y: torch.Tensor
    root_x: torch.Tensor | None
    root_y: torch.Tensor | None
    T_x: torch.Tensor
    T_y: torch.Tensor
    T_xy: torch.Tensor
    S_star: torch.Tensor
    K_star: torch.Tensor
    w_star: torch.Tensor
    S_hat: torch.Tensor
    X_hat: torch.Tensor
    K_y: torch.Tensor
    w_y: torch.Tensor
    Y_star: torch.Tensor
    K_ystar: torch.Tensor
    w_ystar: torch.Tensor
    Y_hat: torch.Tensor
    S_x2y: torch.Tensor
    S_y2x: torch.Tensor
