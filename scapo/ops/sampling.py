"""Farthest-point sampling: numpy (fpsample's QuickFPS, for data and templates) and batched torch
(for the networks' inputs on any device)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch is imported lazily: the renderer's worker processes need numpy only
    import torch


def farthest_point_indices(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices ``(n,)`` int64 of a farthest-point sample of ``points (M, 3)`` (fpsample's QuickFPS).

    Deterministic for equal inputs; the start point is drawn with ``rng``.

    Raises:
        ValueError: fewer than ``n`` points.
    """
    import fpsample

    m = len(points)
    if m < n:
        raise ValueError(f"farthest-point sampling needs at least {n} points, got {m}")
    if m == n:
        return np.arange(n)
    h = 3 if m < 4096 else (5 if m < 32768 else 7)
    idx = fpsample.bucket_fps_kdline_sampling(points, n, h=h, start_idx=int(rng.integers(m)))
    return np.sort(np.asarray(idx, dtype=np.int64))


def farthest_point_sample(points: torch.Tensor, n: int, start: torch.Tensor | None = None) -> torch.Tensor:
    """Indices ``(B, n)`` int64 of a farthest-point sample of each cloud of ``points (B, M, 3)``.

    Exact greedy FPS (n passes over the cloud), on the points' device; the first index is ``start
    (B,)`` (default 0).

    Raises:
        ValueError: ``n`` larger than M, or points not (B, M, 3).
    """
    import torch

    if points.dim() != 3 or points.shape[-1] != 3:
        raise ValueError(f"farthest_point_sample needs (B, M, 3) points, got {tuple(points.shape)}")
    B, M, _ = points.shape
    if n > M:
        raise ValueError(f"farthest-point sampling needs at least {n} points, got {M}")
    idx = torch.empty(B, n, dtype=torch.long, device=points.device)
    cur = torch.zeros(B, dtype=torch.long, device=points.device) if start is None else start.to(points.device)
    dist = torch.full((B, M), float("inf"), dtype=points.dtype, device=points.device)
    ar = torch.arange(B, device=points.device)
    for i in range(n):
        idx[:, i] = cur
        d = ((points - points[ar, cur][:, None]) ** 2).sum(-1)
        dist = torch.minimum(dist, d)
        cur = dist.argmax(1)
    return idx
