"""Batch statistics over the global batch of a data-parallel run (used by :class:`scapo.nn.vn.VNBatchNorm`;
the process group itself is :mod:`scapo.engine.distributed`'s)."""

from __future__ import annotations

import torch
import torch.distributed as dist


class _AllReduceSum(torch.autograd.Function):
    """Sum over the ranks, differentiable: the gradient of each rank's input is the sum of the ranks' output
    gradients (what the deprecated ``torch.distributed.nn.functional.all_reduce`` computes for SUM)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = x.clone()
        dist.all_reduce(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        g = grad.clone()
        dist.all_reduce(g)
        return g


def all_reduce_sum(x: torch.Tensor) -> torch.Tensor:
    """``x`` summed over the ranks of the process group, differentiable (every rank must call it)."""
    return _AllReduceSum.apply(x)


def sync_batch_stats(x: torch.Tensor, dims: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and (biased) variance of ``x`` over ``dims``, over the global batch of a data-parallel run
    (differentiable all-reduce of the sums; every rank must call it), or over ``x`` alone otherwise.

    Returns tensors shaped like ``x`` reduced over ``dims`` (keepdim)."""
    count = 1
    for d in dims:
        count *= x.shape[d]
    s = x.sum(dim=dims, keepdim=True)
    sq = (x * x).sum(dim=dims, keepdim=True)
    if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
        n = all_reduce_sum(torch.tensor([float(count)], device=x.device, dtype=x.dtype))
        s, sq, count = all_reduce_sum(s), all_reduce_sum(sq), n
    mean = s / count
    var = (sq / count - mean * mean).clamp_min(0.0)
    return mean, var
