"""Least-squares point-set registration: Umeyama (numpy), weighted Kabsch (torch, batched) and
Umeyama inside RANSAC, shared by the methods (NPCS-style part poses, EAP-style joints) and models.
"""

from __future__ import annotations

import numpy as np
import torch

from scapo.ops.rigid import as_transform

EPS = 1e-9


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, float]:
    """Least-squares similarity/rigid transform mapping ``src (N, 3)`` onto ``dst (N, 3)``.

    Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", TPAMI 1991. Returns ``(T (4, 4), scale)`` with ``dst ~ scale * R src + t``
    (the scale is folded into ``T[:3, :3]`` when ``with_scale`` is True).

    Raises ValueError for fewer than 3 points or mismatched shapes.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (N>=3, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    scale = 1.0
    if with_scale:
        var_s = (xs**2).sum() / len(src)
        scale = float(np.trace(np.diag(S) @ D) / max(var_s, 1e-18))
    t = mu_d - scale * R @ mu_s
    return as_transform(scale * R, t), scale


def kabsch(src: torch.Tensor, dst: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted least-squares rigid transform with ``R src + t ~ dst`` (Kabsch / Umeyama, no scale).

    ``src, dst (Q, n, 3)`` corresponding points, ``w (Q, n)`` non-negative weights ->
    ``R (Q, 3, 3)`` (proper rotations), ``t (Q, 3)``. Rows with zero total weight give the identity.
    Differentiable (SVD); any float dtype and device.
    """
    ws = w / (w.sum(1, keepdim=True) + EPS)
    cs = (ws.unsqueeze(-1) * src).sum(1)
    cd = (ws.unsqueeze(-1) * dst).sum(1)
    H = torch.einsum("qn,qni,qnj->qij", ws, src - cs[:, None], dst - cd[:, None])
    U, _, Vh = torch.linalg.svd(H + EPS * torch.eye(3, dtype=H.dtype, device=H.device))
    V = Vh.transpose(1, 2)
    d = torch.sign(torch.det(V @ U.transpose(1, 2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), torch.where(d == 0, 1.0, d)], -1))
    R = V @ D @ U.transpose(1, 2)
    return R, cd - (R @ cs.unsqueeze(-1)).squeeze(-1)


def ransac_umeyama(src: np.ndarray, dst: np.ndarray, threshold: float, with_scale: bool = True,
                   iterations: int = 128, sample: int = 4, rng: np.random.Generator | None = None
                   ) -> tuple[np.ndarray, float, np.ndarray]:
    """Similarity (or rigid) transform ``dst ~ s R src + t`` robust to outlier correspondences.

    Umeyama on ``iterations`` random minimal sets of ``sample`` correspondences; the hypothesis with
    the most inliers (``|s R src + t - dst| < threshold``, in ``dst`` units; ties broken by the
    smaller inlier residual) is refitted on its inliers. This is the pose step of NPCS (Wang et al.,
    CVPR 2019, Sec. 4.3) and of ANCSH's NPCS baseline (Li et al., CVPR 2020).

    Args:
        src, dst: ``(N, 3)`` corresponding points, N >= 3 (float64 internally).
        threshold: inlier distance (same unit as ``dst``, > 0).
        with_scale: estimate the scale ``s`` (NPCS -> camera); False gives a rigid fit.
        iterations, sample: hypotheses and their minimal-set size (>= 3).
        rng: randomness of the minimal sets (default: a fixed seed, so the result is deterministic).

    Returns:
        ``(T (4, 4) with s R in its rotation block, s, inlier mask (N,) bool)``.

    Raises:
        ValueError: mismatched shapes, N < 3, threshold <= 0 or sample < 3.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"ransac_umeyama needs two (N>=3, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    if threshold <= 0 or sample < 3:
        raise ValueError(f"ransac_umeyama needs threshold > 0 and sample >= 3, got {threshold}, {sample}")
    rng = np.random.default_rng(0) if rng is None else rng
    n = len(src)
    k = min(sample, n)
    best = (-1, np.inf, None)
    for _ in range(iterations):
        idx = rng.choice(n, size=k, replace=False)
        try:
            T, _ = umeyama(src[idx], dst[idx], with_scale=with_scale)
        except np.linalg.LinAlgError:
            continue
        res = np.linalg.norm(src @ T[:3, :3].T + T[:3, 3] - dst, axis=1)
        inl = res < threshold
        cnt, err = int(inl.sum()), float(res[inl].sum())
        if cnt > best[0] or (cnt == best[0] and err < best[1]):
            best = (cnt, err, inl)
    inliers = best[2] if best[2] is not None and best[0] >= 3 else np.ones(n, dtype=bool)
    T, s = umeyama(src[inliers], dst[inliers], with_scale=with_scale)
    res = np.linalg.norm(src @ T[:3, :3].T + T[:3, 3] - dst, axis=1)
    return T, s, res < threshold
