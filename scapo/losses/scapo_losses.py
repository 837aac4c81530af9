"""Losses of SCAPO (paper Sec. 3.1 and 3.3). Each returns a scalar tensor (batch mean).

Stage 1: :func:`reconstruction_loss`, :func:`orthonormality_loss`,
:func:`augmentation_consistency_loss`, :func:`canonical_consistency_loss`.
Stage 2: :func:`cycle_loss`, :func:`cross_space_loss`, and the regularisers
:func:`kp_seg_loss`, :func:`seg_loss`, :func:`shape_var_loss`, :func:`dir_align_loss`,
:func:`joint_prox_loss`, :func:`joint_boundary_loss`.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from scapo.nn.encoder import EncoderOutput
from scapo.nn.outputs import Stage1Output
from scapo.ops.chamfer import chamfer_distance, nearest_sq_dist, pairwise_sq_dist, trimmed_one_sided_chamfer
from scapo.ops.groups import random_rotation, rotation_group

EPS = 1e-8


# ------------------------------------------------------------------------------ stage 1
def reconstruction_loss(X: torch.Tensor, X_rec: torch.Tensor) -> torch.Tensor:
    """``L_rec``: Chamfer distance between the input ``X (B, N, 3)`` and ``R S_dec + t (B, M, 3)`` (paper Eq. 1)."""
    return chamfer_distance(X, X_rec).mean()


def template_loss(S_dec: torch.Tensor, scale: torch.Tensor, template: torch.Tensor) -> torch.Tensor:
    """``L_template``: the Chamfer distance between each decoded canonical shape and one shared category template (an
    addition to the paper, switch ``LossConfig.template``). The template is in metres (the clouds' normalised units
    differ from view to view: ``scale`` is each partial view's own 2 x RMS radius), so it is brought into each view's
    units as ``template / scale_b`` and the distance is in those units, as ``L_rec``'s.

    Args:
        S_dec: ``(B, M, 3)`` decoded canonical shapes, normalised units. scale: ``(B,)`` metres per unit.
        template: ``(K, 3)`` metres.

    Returns:
        A scalar (normalised units squared).

    Raises:
        ValueError: shapes that do not match."""
    if S_dec.dim() != 3 or template.dim() != 2 or scale.shape != S_dec.shape[:1]:
        raise ValueError(f"template_loss needs S_dec (B, M, 3), scale (B,), template (K, 3); got "
                         f"{tuple(S_dec.shape)}, {tuple(scale.shape)}, {tuple(template.shape)}")
    T = template.unsqueeze(0) / scale[:, None, None]
    return chamfer_distance(S_dec, T).mean()


def orthonormality_loss(R_raw: torch.Tensor) -> torch.Tensor:
    """``L_ortho = ||R R^T - I||_F^2`` of the raw equivariant rotation estimate ``(B, 3, 3)``."""
    eye = torch.eye(3, dtype=R_raw.dtype, device=R_raw.device)
    return ((R_raw @ R_raw.transpose(1, 2) - eye) ** 2).sum((1, 2)).mean()


def augmentation_consistency_loss(model, X: torch.Tensor, s1: Stage1Output, keep: float = 0.75,
                                  max_batch: int | None = None) -> torch.Tensor:
    """``L_aug_consist``: a re-sampled (a random ``keep`` fraction of the points), randomly rotated
    and translated copy ``X' = Q X_sub + u`` must give the same canonical shape and the
    correspondingly moved pose: ``CD(S, S') + ||R' - Q R||^2 + ||t' - (Q t + u)||^2``.
    ``max_batch`` limits the term to the first clouds of the batch (cost)."""
    if max_batch is not None and max_batch < X.shape[0]:
        enc = s1.enc
        s1 = Stage1Output(EncoderOutput(enc.t[:max_batch], enc.R_raw[:max_batch], enc.R[:max_batch],
                                        enc.code[:max_batch]), s1.S_dec[:max_batch], s1.F_x[:max_batch],
                          s1.X_rec[:max_batch])
        X = X[:max_batch]
    B, N, _ = X.shape
    n = max(16, int(keep * N))
    idx = torch.rand(B, N, device=X.device).argsort(dim=1)[:, :n]
    sub = X.gather(1, idx.unsqueeze(-1).expand(B, n, 3))
    Q = random_rotation(B, X.dtype).to(X.device)
    u = 0.2 * torch.randn(B, 3, dtype=X.dtype, device=X.device)
    aug = sub @ Q.transpose(1, 2) + u[:, None]
    a1 = model.stage1(aug)
    e, ea = s1.enc, a1.enc
    loss = chamfer_distance(s1.S_dec, a1.S_dec)
    loss = loss + ((ea.R_raw - Q @ e.R_raw) ** 2).sum((1, 2))
    loss = loss + ((ea.t - ((Q @ e.t.unsqueeze(-1)).squeeze(-1) + u)) ** 2).sum(-1)
    return loss.mean()


def cross_instance_alignment_loss(X: torch.Tensor, t: torch.Tensor, R: torch.Tensor, points: int = 96,
                                   keep: float = 0.7) -> torch.Tensor:
    """Cross-instance canonical alignment (an addition to the paper's stage-1 losses).

    Every pair of clouds in the batch, brought into the canonical frame (``S_b = R_b^T (X_b - t_b)``),
    should overlap: the mean over ordered pairs (b != b') of the trimmed one-sided Chamfer distance
    (the ``keep`` fraction of smallest nearest-neighbour distances, which tolerates partial views
    and articulation). Equivariance makes each frame a function of the shape; this term makes those
    functions agree across instances, views and states, i.e. one category-level canonical frame.
    ``X (B, N, 3)``, ``t (B, 3)``, ``R (B, 3, 3)``; ``points`` of every cloud are used.
    """
    B, N, _ = X.shape
    n = min(points, N)
    S = (X[:, :: max(1, N // n)][:, :n] - t[:, None]) @ R  # (B, n, 3)
    A = S.unsqueeze(1).expand(B, B, n, 3).reshape(B * B, n, 3)
    Bt = S.unsqueeze(0).expand(B, B, n, 3).reshape(B * B, n, 3)
    d = trimmed_one_sided_chamfer(A, Bt, keep).reshape(B, B)
    off = ~torch.eye(B, dtype=torch.bool, device=X.device)
    return d[off].mean() if B > 1 else d.sum() * 0.0


def candidate_rotations(small_deg: float = 25.0, dtype=torch.float32) -> torch.Tensor:
    """Rotations searched by :func:`consensus_rotation_loss`: the 24 rotations of the cube
    (octahedral group, identity first) and rotations by +-``small_deg`` about x, y and z; ``(30, 3, 3)``."""
    return torch.tensor(_candidate_rotations(float(small_deg)), dtype=dtype)


@functools.lru_cache(maxsize=8)
def _candidate_rotations(small_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    small = Rotation.from_rotvec(np.deg2rad(small_deg) * np.concatenate([np.eye(3), -np.eye(3)])).as_matrix()
    out = np.concatenate([rotation_group("O"), small])
    out.setflags(write=False)
    return out


def consensus_rotation_loss(X: torch.Tensor, t: torch.Tensor, R_raw: torch.Tensor, R: torch.Tensor,
                            candidates: torch.Tensor, points: int = 64, keep: float = 0.7,
                            margin: float = 0.05) -> tuple[torch.Tensor, torch.Tensor]:
    """Batch-consensus pseudo-label for the canonical frame (an addition to the paper's stage-1 losses).

    Gradient descent on :func:`cross_instance_alignment_loss` cannot leave a wrong basin (a laptop
    canonicalised back to front, or off by tens of degrees). Here every canonical cloud
    ``S_b = R_b^T (X_b - t_b)`` (detached) is rotated by each candidate ``G_g`` (``candidates (C, 3, 3)``,
    identity first) and scored by the median over the other clouds of the trimmed one-sided Chamfer
    distance; where the best candidate beats the identity by more than the relative ``margin``, the
    frame's target becomes ``R_b G_g^T``, otherwise ``R_b``. Loss: ``||R_raw - target||_F^2`` (batch
    mean). ``X (B, N, 3)``, ``t (B, 3)``, ``R_raw, R (B, 3, 3)``. Returns ``(loss, fraction of clouds
    re-labelled)``.
    """
    B, N, _ = X.shape
    if B < 3:
        return R_raw.sum() * 0.0, R_raw.new_zeros(())
    n = min(points, N)
    G = candidates.to(X)
    C = G.shape[0]
    with torch.no_grad():
        S = (X[:, :: max(1, N // n)][:, :n] - t[:, None]) @ R  # (B, n, 3)
        SG = torch.einsum("bni,gji->bgnj", S, G)  # S_b G_g^T: (B, C, n, 3)
        A = SG.unsqueeze(2).expand(B, C, B, n, 3).reshape(-1, n, 3)
        T = S.unsqueeze(0).unsqueeze(0).expand(B, C, B, n, 3).reshape(-1, n, 3)
        d = trimmed_one_sided_chamfer(A, T, keep).reshape(B, C, B)
        self_pair = torch.eye(B, dtype=torch.bool, device=X.device)[:, None, :]  # (B, 1, B)
        score = d.masked_fill(self_pair, float("nan")).nanmedian(dim=-1).values  # (B, C): over the others
        best = score.argmin(dim=1)
        better = score.gather(1, best[:, None]).squeeze(1) < (1.0 - margin) * score[:, 0]
        g = torch.where(better, best, torch.zeros_like(best))
        target = R @ G[g].transpose(1, 2)
    loss = ((R_raw - target) ** 2).sum((1, 2)).mean()
    return loss, better.float().mean()


def canonical_consistency_loss(model, S_dec: torch.Tensor) -> torch.Tensor:
    """``L_can_consist``: the decoded canonical shape, encoded again, has identity pose:
    ``||R(S) - I||^2 + ||t(S)||^2`` (the canonical frame is a fixed point of the encoder; with a hypothesis set of
    frames, ``ModelConfig.anchors``, of the encoder and its anchor choice)."""
    enc = model.frame(S_dec.detach())
    eye = torch.eye(3, dtype=S_dec.dtype, device=S_dec.device)
    return (((enc.R_raw - eye) ** 2).sum((1, 2)) + (enc.t ** 2).sum(-1)).mean()


# ------------------------------------------------------------------------------ stage 2
def cycle_loss(X: torch.Tensor, X_hat: torch.Tensor) -> torch.Tensor:
    """``L_cycle = ||X^ - X||_1``: per-point L1 distance after backward + forward deformation."""
    return (X_hat - X).abs().sum(-1).mean()


def cross_space_loss(S_x2y: torch.Tensor, Y: torch.Tensor, S_y2x: torch.Tensor, S_obj: torch.Tensor) -> torch.Tensor:
    """``L_recon + L_recon^Y = CD(S^{x2y}, Y_X) + CD(S^{y2x}, S_obj)`` (cross-space alignment)."""
    return (chamfer_distance(S_x2y, Y) + chamfer_distance(S_y2x, S_obj)).mean()


def soft_centroids(points: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``m_p = sum_i w_i^p s_i / N_p`` and ``N_p = sum_i w_i^p``: ``(B, P, 3), (B, P)``."""
    Np = w.sum(1)
    m = torch.einsum("bnp,bni->bpi", w, points) / (Np.unsqueeze(-1) + EPS)
    return m, Np


def kp_seg_loss(points: torch.Tensor, w: torch.Tensor, K: torch.Tensor, min_support: float) -> torch.Tensor:
    """``L_kp-seg = 1/P sum_p 1(N_p > tau) ||k_p - m_p||^2`` (keypoints at their parts' soft centroids).

    ``min_support`` is ``tau`` as a fraction of the number of points.
    """
    m, Np = soft_centroids(points, w)
    mask = (Np > min_support * points.shape[1]).to(points.dtype)
    return (mask * ((K - m) ** 2).sum(-1)).mean()


def seg_loss(points: torch.Tensor, w: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """``L_seg = 1/N sum_i ||w_i - y_i||^2`` with ``y_i`` the one-hot of the nearest keypoint (paper Sec. 3.3).
    ``points (B, N, 3)``, ``w (B, N, P)``, ``K (B, P, 3)``."""
    labels = pairwise_sq_dist(points, K).argmin(-1)
    y = torch.nn.functional.one_hot(labels, K.shape[1]).to(w.dtype)
    return ((w - y) ** 2).sum(-1).mean()


def shape_var_loss(delta: torch.Tensor, lam: float = 60.0) -> torch.Tensor:
    """``L_shape-var = 1 - exp(-lambda_var ||Delta S||^2)`` with the squared norm averaged over points."""
    return (1.0 - torch.exp(-lam * (delta ** 2).sum(-1).mean(-1))).mean()


def entropy(w: torch.Tensor) -> torch.Tensor:
    """Per-point segmentation entropy ``H_i = -sum_p w_i^p log w_i^p``: ``(B, N, P) -> (B, N)``."""
    return -(w * torch.log(w.clamp_min(EPS))).sum(-1)


def boundary_direction(points: torch.Tensor, w: torch.Tensor, parent: int, child: int, top: float = 0.1
                       ) -> torch.Tensor:
    """Principal direction ``d~ (B, 3)`` (PCA) of the boundary points between two parts.

    Boundary points are the ``top`` fraction of points with the highest two-part entropy score
    ``4 w_parent w_child``; the direction is the eigenvector of their weighted covariance with
    the largest eigenvalue. Returned without gradient (it is a target).
    """
    with torch.no_grad():
        score = 4.0 * w[..., parent] * w[..., child]
        k = max(8, int(top * points.shape[1]))
        sel = score.topk(k, dim=1).indices
        p = points.gather(1, sel.unsqueeze(-1).expand(-1, k, 3))
        s = score.gather(1, sel).unsqueeze(-1) + EPS
        mu = (s * p).sum(1, keepdim=True) / s.sum(1, keepdim=True)
        cov = torch.einsum("bni,bnj->bij", s * (p - mu), p - mu)
        return torch.linalg.eigh(cov).eigenvectors[..., -1]


def dir_align_loss(points: torch.Tensor, w: torch.Tensor, axis: torch.Tensor, joint_types, joint_parts) -> torch.Tensor:
    """``L_dir-align = mean (1 - |cos(d_j, d~_j)|)`` over revolute joints (boundary PCA direction)."""
    terms = []
    for j, ((pa, ch), jt) in enumerate(zip(joint_parts, joint_types)):
        if jt != 0:
            continue
        d_t = boundary_direction(points, w, pa, ch)
        terms.append(1.0 - torch.nn.functional.cosine_similarity(axis[:, j], d_t, dim=-1).abs())
    return torch.stack(terms).mean() if terms else axis.sum() * 0.0


def joint_prox_loss(points: torch.Tensor, pivot: torch.Tensor, joint_types, lam: float = 30.0) -> torch.Tensor:
    """``L_joint-prox = 1 - exp(-lambda_prox E_j[min_i ||c_j - s_i||^2])`` over revolute joints."""
    rev = [j for j, t in enumerate(joint_types) if t == 0]
    if not rev:
        return pivot.sum() * 0.0
    d = nearest_sq_dist(pivot[:, rev], points)  # (B, J_rev)
    return (1.0 - torch.exp(-lam * d.mean(-1))).mean()


def joint_boundary_loss(points: torch.Tensor, w: torch.Tensor, pivot: torch.Tensor, joint_types,
                        temperature: float = 0.1) -> torch.Tensor:
    """``L_joint-boundary = -1/J sum_j sum_i alpha_ji H_i`` over revolute joints, with
    ``alpha_j = softmax_i(-||c_j - s_i|| / temperature)`` (pivots attracted to high-entropy points).

    The entropy is a fixed cue here (no gradient), so the term moves pivots towards part
    boundaries rather than blurring the segmentation around them; the temperature (in normalised
    units) makes the attention local.
    """
    rev = [j for j, t in enumerate(joint_types) if t == 0]
    if not rev:
        return pivot.sum() * 0.0
    dist = (pairwise_sq_dist(pivot[:, rev], points) + EPS).sqrt()  # (B, J, N)
    alpha = torch.softmax(-dist / temperature, dim=-1)
    return -(alpha * entropy(w).detach().unsqueeze(1)).sum(-1).mean()
