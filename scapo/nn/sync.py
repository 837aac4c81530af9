"""Batch statistics over the global batch of a data-parallel run (used by :class:`scapo.nn.vn.VNBatchNorm`;
the process group itself is :mod:`scapo.engine.distributed`'s)."""

from __future__ import annotations

import torch
import torch.distributed as dist


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
        from torch.distributed.nn.functional import all_reduce

        n = all_reduce(torch.tensor([float(count)], device=x.device, dtype=x.dtype))
        s, sq, count = all_reduce(s), all_reduce(sq), n
    mean = s / count
    var = (sq / count - mean * mean).clamp_min(0.0)
    return mean, var
