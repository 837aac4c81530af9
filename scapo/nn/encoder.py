"""SE(3)-equivariant auto-encoder of SCAPO stage 1 (paper Sec. 3.1).

The encoder first estimates the translation ``t_g`` with VNT layers (translation and rotation
equivariant), then runs VN layers on the centred cloud to estimate the rotation ``R_g``
(three equivariant vectors) and an SE(3)-invariant code ``Z_x`` (coordinates of the pooled
features in the frame ``R_g``). The decoder maps ``Z_x`` to a canonical shape ``S_dec`` so that
``X ~ S_dec R_g^T + t_g`` (points as rows; paper: ``X = S_obj R_g + 1 t_g^T`` with its ``R_g`` being
our ``R_g^T``). Local geometry enters through k-nearest-neighbour edge features as in VN-DGCNN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from scapo.nn.vn import (
    VNLinear,
    VNLinearLeakyReLU,
    VNTLinear,
    VNTLinearLeakyReLU,
    gather_neighbours,
    knn_indices,
)
from scapo.ops.so3 import rotation_from_6d, rotation_from_rotvec


@dataclass(frozen=True)
class EncoderConfig:
    """Sizes of the SE(3) auto-encoder."""

    k: int = 16
    """Neighbours of the edge features."""
    trans_channels: tuple[int, ...] = (16, 32)
    """VNT channels of the translation branch."""
    rot_channels: tuple[int, ...] = (32, 64, 96)
    """VN channels of the rotation branch."""
    code_dim: int = 256
    """Size of the invariant code Z_x."""
    decoder_hidden: tuple[int, int] = (512, 512)
    """Decoder MLP widths; the last one is the feature map F_x fed to the shape-residual head."""
    decoder_points: int = 512
    """Points of the decoded canonical shape S_dec."""
    attention_points: int = 8
    """Soft keypoints (attention-weighted means of the centred points) feeding the rotation head."""
    frame: str = "regressed"
    """How ``R_g`` is read: "regressed" (the paper: Gram-Schmidt of two equivariant vectors of the rotation head) or
    "principal" (an addition to the paper: the principal axes of the centred cloud, :func:`principal_frame`). A
    shape with a two-fold rotation symmetry (a laptop's base and lid exchanged by a half-turn about the bisector of
    its opening) forces every pooled equivariant vector onto the symmetry axis, so the regressed frame's turn about
    that axis is decided by sampling noise (``scapo bench ladder``'s resampling column); principal axes stay defined
    up to signs and order, which a hypothesis set (``ModelConfig.anchors = "O"``) resolves. "weighted" (an addition
    to the paper): the principal axes of the cloud under learned per-point weights (a softmax over the points of an
    invariant score of each point's rotation-branch features, zero-initialised so that training starts from the
    "principal" frame; the gradient reaches the scores through the eigenvectors). The axes of the whole cloud turn
    with the joint state and with what a view shows; weights can single out what does not (e.g. the base part).
    Like "principal", a second-moment frame is defined under a two-fold symmetry, where a pooled equivariant vector
    is not."""

    residual_deg: float = 0.0
    """With ``frame="principal"``: a learned turn of the principal frame, at most this many degrees about each axis
    (a rotation vector ``residual_deg * tanh(W code)`` from the invariant code, zero at the start; OP-Align's
    anchors carry a learned residual of at most 18 deg the same way, ``models/art_so3net_pn.py``); 0: none."""

    def __post_init__(self):
        from scapo.config import check_settings

        check_settings(self, minimum={"k": 2, "code_dim": 1, "decoder_points": 16, "attention_points": 1},
                       positive_tuples=("trans_channels", "rot_channels", "decoder_hidden"))
        if len(self.decoder_hidden) != 2:
            raise ValueError(f"invalid decoder_hidden: give two widths (the MLP's and the feature map's), got "
                             f"{self.decoder_hidden!r}")
        if not 0.0 <= self.residual_deg <= 90.0:
            raise ValueError(f"encoder residual_deg must be in [0, 90], got {self.residual_deg!r}")
        if self.frame not in ("regressed", "principal", "weighted"):
            raise ValueError(f"encoder frame must be 'regressed', 'principal' or 'weighted', got {self.frame!r}")


@dataclass
class EncoderOutput:
    """t (B, 3) translation; R_raw (B, 3, 3) equivariant columns (not orthonormal); R (B, 3, 3)
    Gram-Schmidt rotation; code (B, D) invariant; inv (B, C, 3) invariant pooled coordinates."""

    t: torch.Tensor
    R_raw: torch.Tensor
    R: torch.Tensor
    code: torch.Tensor


def principal_frame(points: torch.Tensor, weights: torch.Tensor | None = None, min_gap: float = 1e-3) -> torch.Tensor:
    """Rotations ``(B, 3, 3)`` (columns: the principal axes of ``points (B, N, 3)`` about their centroid, largest
    variance first) with equivariant signs: each of the first two axes points to the side of positive third moment
    of the points' coordinates along it, the third completes a right-handed frame. ``R(Q X + u) = Q R(X)`` for
    every rotation ``Q`` and translation ``u`` where the variances and third moments are distinct from zero and each
    other; otherwise the order or signs are ambiguous (a hypothesis set over the 24 signed permutations resolves
    them).

    ``weights (B, N)`` (non-negative, summing to 1 over the points; ``EncoderConfig.frame="weighted"``): the weighted
    centroid, covariance and third moments instead, with the gradient reaching the weights (and the points) through
    the eigenvectors, except for a cloud whose eigenvalues are closer than ``min_gap`` times the largest (there the
    eigenvectors' derivative, ``1 / (lambda_i - lambda_j)``, is unbounded, and that cloud's frame gets no gradient).
    Without weights: no gradient (the axes of equal variances have none that is finite)."""
    if weights is None:
        with torch.no_grad():
            xc = points - points.mean(1, keepdim=True)
            return _axes_frame(xc, (xc.transpose(1, 2) @ xc / points.shape[1]).double(), lambda p: (p ** 3).mean(1))
    w = weights.unsqueeze(-1)  # (B, N, 1)
    xc = points - (w * points).sum(1, keepdim=True)
    cov = ((w * xc).transpose(1, 2) @ xc).double()
    with torch.no_grad():
        lam = torch.linalg.eigvalsh(cov)  # ascending
        gap = torch.minimum(lam[:, 1] - lam[:, 0], lam[:, 2] - lam[:, 1]) / lam[:, 2].abs().clamp_min(1e-30)
    cov = torch.where((gap > min_gap)[:, None, None], cov, cov.detach())
    return _axes_frame(xc, cov, lambda p: (w * p ** 3).sum(1))


def _axes_frame(xc: torch.Tensor, cov: torch.Tensor, third_moment) -> torch.Tensor:
    """:func:`principal_frame` from centred points ``xc (B, N, 3)`` and their covariance ``cov (B, 3, 3)`` (float64):
    eigenvectors, largest variance first, the first two signed by ``third_moment(projections (B, N, 3)) -> (B, 3)``
    (no gradient through the signs), the third completing a right-handed frame."""
    _, vec = torch.linalg.eigh(cov)  # ascending
    vec = vec.flip(-1).to(xc.dtype)  # (B, 3, 3) columns, largest first
    with torch.no_grad():
        sign = torch.where(third_moment(xc @ vec) >= 0, 1.0, -1.0).to(xc.dtype)  # (B, 3)
    e1, e2 = vec[..., 0] * sign[:, :1], vec[..., 1] * sign[:, 1:2]
    return torch.stack([e1, e2, torch.cross(e1, e2, dim=-1)], dim=-1)


class SE3Encoder(nn.Module):
    """``points (B, N, 3)`` -> :class:`EncoderOutput` (equivariant t, R; invariant code)."""

    def __init__(self, cfg: EncoderConfig):
        super().__init__()
        self.cfg = cfg
        c_t = cfg.trans_channels
        self.t_edge = VNTLinearLeakyReLU(2, c_t[0])
        self.t_layers = nn.ModuleList(VNTLinearLeakyReLU(a, b) for a, b in zip(c_t[:-1], c_t[1:]))
        self.t_out = VNTLinear(c_t[-1], 1)
        c_r = cfg.rot_channels
        self.r_edge = VNLinearLeakyReLU(3, c_r[0])
        self.r_layers = nn.ModuleList(VNLinearLeakyReLU(a, b) for a, b in zip(c_r[:-1], c_r[1:]))
        self.attn = nn.Sequential(nn.Linear(c_r[-1], 64), nn.LeakyReLU(0.2), nn.Linear(64, cfg.attention_points))
        self.r_head = VNLinearLeakyReLU(c_r[-1] + cfg.attention_points, c_r[-1], batchnorm=False)
        self.r_out = VNLinear(c_r[-1], 3)
        self.code = nn.Sequential(nn.Linear((c_r[-1] + cfg.attention_points) * 3, cfg.code_dim), nn.LeakyReLU(0.2),
                                  nn.Linear(cfg.code_dim, cfg.code_dim))
        if cfg.frame == "principal" and cfg.residual_deg > 0:
            self.frame_residual = nn.Linear(cfg.code_dim, 3)
            nn.init.zeros_(self.frame_residual.weight)
            nn.init.zeros_(self.frame_residual.bias)
        if cfg.frame == "weighted":  # per-point frame scores from invariant features; zero: uniform weights at start
            self.frame_scores = nn.Linear(c_r[-1], 1)
            nn.init.zeros_(self.frame_scores.weight)
            nn.init.zeros_(self.frame_scores.bias)

    def forward(self, points: torch.Tensor) -> EncoderOutput:
        B, N, _ = points.shape
        idx = knn_indices(points, self.cfg.k)  # translation/rotation invariant, shared by both branches
        x = points.transpose(1, 2).unsqueeze(1)  # (B, 1, 3, N)
        nb = gather_neighbours(x, idx)  # (B, 1, 3, N, k)
        f = self.t_edge.edge_pool(torch.cat([x.unsqueeze(-1).expand_as(nb), nb], dim=1))  # vn_mean_pool(t_edge(.))
        for layer in self.t_layers:
            f = layer(f)
        t = self.t_out(f.mean(-1, keepdim=True)).reshape(B, 3)
        xc = x - t.reshape(B, 1, 3, 1)
        nbc = nb - t.reshape(B, 1, 3, 1, 1)
        xe = xc.unsqueeze(-1).expand_as(nbc)
        edge = torch.cat([nbc - xe, xe, torch.cross(nbc, xe, dim=2)], dim=1)  # (B, 3, 3, N, k)
        g = self.r_edge.edge_pool(edge)  # = vn_mean_pool(self.r_edge(edge)), without (B, C, 3, N, k) tensors
        for layer in self.r_layers:
            g = layer(g)
        # invariant per-point scores (norms of the VN features) -> attention-weighted points: equivariant
        # "soft keypoints" that anchor the frame to parts of the shape
        # (the norm written as sqrt(sum(g^2)): Tensor.norm over this middle dimension is ~50x slower on CPU)
        norms = (g * g).sum(2).clamp_min(1e-24).sqrt()  # (B, C, N)
        scores = self.attn(norms.transpose(1, 2)).softmax(dim=1)  # (B, N, K)
        keypts = torch.einsum("bnk,bin->bki", scores, xc[:, 0])  # (B, K, 3), relative to t
        pooled = torch.cat([g.mean(-1), keypts], dim=1)  # (B, C + K, 3)
        v = self.r_out(self.r_head(pooled.unsqueeze(-1))).squeeze(-1)  # (B, 3, 3): three vectors (rows)
        R_raw = v.transpose(1, 2)  # columns are the vectors
        if self.cfg.frame == "principal":
            R = R_raw = principal_frame(points)
        elif self.cfg.frame == "weighted":
            R = R_raw = principal_frame(points, self.frame_scores(norms.transpose(1, 2)).squeeze(-1).softmax(dim=1))
        else:
            R = rotation_from_6d(v[:, 0], v[:, 1])
        inv = torch.einsum("bci,bij->bcj", pooled, R)  # coordinates in the frame R: invariant
        code = self.code(inv.reshape(B, -1))
        if self.cfg.frame == "principal" and self.cfg.residual_deg > 0:
            w = math.radians(self.cfg.residual_deg) * torch.tanh(self.frame_residual(code))  # invariant
            R = R_raw = R @ rotation_from_rotvec(w)
        return EncoderOutput(t, R_raw, R, code)


class ShapeDecoder(nn.Module):
    """Invariant code ``(B, D)`` -> canonical shape ``S_dec (B, M, 3)`` and feature map ``F_x (B, H)``."""

    def __init__(self, cfg: EncoderConfig):
        super().__init__()
        h1, h2 = cfg.decoder_hidden
        self.hidden = nn.Sequential(nn.Linear(cfg.code_dim, h1), nn.LeakyReLU(0.2), nn.Linear(h1, h2),
                                    nn.LeakyReLU(0.2))
        self.out = nn.Linear(h2, cfg.decoder_points * 3)
        self.m = cfg.decoder_points

    def forward(self, code: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        feat = self.hidden(code)
        return self.out(feat).reshape(-1, self.m, 3), feat
