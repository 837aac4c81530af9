"""Vector-neuron layers (SO(3)-equivariant) and their translation-equivariant VNT counterparts.

Features are lists of 3D vectors: tensors of shape ``(B, C, 3, *S)`` (batch, channels, xyz,
any spatial dims such as points and neighbours). A rotation ``Q`` acts on dimension 2.

- VN layers (Deng et al., "Vector Neurons: A General Framework for SO(3)-Equivariant Networks",
  ICCV 2021): linear maps mix channels only, non-linearities act on each vector through a learned
  direction, batch norm rescales vector norms, pooling picks whole vectors. They are rotation
  equivariant ``f(Q V) = Q f(V)``.
- VNT layers (Katzir et al., "Shape-Pose Disentanglement using SE(3)-equivariant Vector
  Neurons", ECCV 2022): linear maps are *affine* combinations of channels (each row of the weight
  sums to 1), so a common translation of all input vectors passes through: ``f(V + u) = f(V) + u``;
  the non-linearity works relative to a learned origin (also an affine combination).

:func:`equivariance_error` is the numerical check used by the tests on every layer.
"""

from __future__ import annotations

import torch
import torch.distributed
from torch import nn

from scapo.ops.groups import random_rotation
from scapo.ops.so3 import rotation_from_6d

EPS = 1e-6


def _mix(weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Channel mixing ``(O, C) x (B, C, 3, *S) -> (B, O, 3, *S)``."""
    return torch.einsum("oc,bc...->bo...", weight, x)


class VNLinear(nn.Module):
    """``V' = W V`` with ``W (C_out, C_in)``; rotation equivariant."""

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(out_channels, in_channels))
        nn.init.kaiming_uniform_(self.weight, a=5 ** 0.5)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _mix(self.weight, x)


class VNTLinear(nn.Module):
    """Affine channel mixing: ``V' = W V`` with every row of ``W`` summing to 1 (translation equivariant).

    The free parameter is projected each call: ``W = W_raw - mean_row(W_raw) + 1 / C_in``.
    """

    def __init__(self, in_channels: int, out_channels: int, init_std: float = 0.1):
        super().__init__()
        # near-uniform affine weights at start: outputs begin close to the mean of the inputs (e.g. the
        # centroid of the points) instead of an arbitrary extrapolation far from them
        self.weight_raw = nn.Parameter(torch.randn(out_channels, in_channels) * init_std / max(in_channels, 1) ** 0.5)

    @property
    def weight(self) -> torch.Tensor:
        w = self.weight_raw
        return w - w.mean(dim=1, keepdim=True) + 1.0 / w.shape[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _mix(self.weight, x)


def _leaky(p: torch.Tensor, d: torch.Tensor, slope: float) -> torch.Tensor:
    """VN leaky ReLU of vectors ``p`` against directions ``d`` (both (B, C, 3, *S))."""
    dot = (p * d).sum(2, keepdim=True)
    d_sq = (d * d).sum(2, keepdim=True)
    # slope p + (1 - slope) (p if <p, d> >= 0 else p - <p, d> / |d|^2 d), written as one correction along d: the
    # coefficient is computed on the (B, C, 1, *S) scalars, so the full-size tensors see one multiply and one
    # subtraction instead of a projection, a where and a blend (the same function; the training step's largest cost)
    return p + ((slope - 1) * dot.clamp(max=0.0) / (d_sq + EPS)) * d  # an add: its backward passes the gradient as is


class VNLeakyReLU(nn.Module):
    """VN leaky ReLU: the component of each vector against a learned direction ``U V`` is clipped."""

    def __init__(self, channels: int, share: bool = False, negative_slope: float = 0.2):
        super().__init__()
        self.direction = VNLinear(channels, 1 if share else channels)
        self.slope = negative_slope

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _leaky(x, self.direction(x), self.slope)


class VNBatchNorm(nn.Module):
    """Batch norm of vector norms (directions kept): ``v' = v / |v| * BN(|v|)``."""

    def __init__(self, channels: int):
        super().__init__()
        self.bn = nn.BatchNorm1d(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        norm = (x * x).sum(2).add(EPS * EPS).sqrt()  # (B, C, *S); faster than .norm on the middle dim
        B, C = norm.shape[:2]
        flat = norm.reshape(B, C, -1)
        if self.training and _distributed():
            normed = self._synced(flat)
        else:
            normed = self.bn(flat)
        return x * (normed.reshape(norm.shape) / norm).unsqueeze(2)  # one full-size multiply by BN(|v|) / |v|

    def _synced(self, flat: torch.Tensor) -> torch.Tensor:
        """Batch norm with statistics over the global batch of a data-parallel run (scapo.nn.sync); the
        running statistics are updated as ``nn.BatchNorm1d`` does (unbiased variance, momentum)."""
        from scapo.nn.sync import sync_batch_stats

        bn = self.bn
        mean, var = sync_batch_stats(flat, (0, 2))
        out = (flat - mean) / (var + bn.eps).sqrt() * bn.weight[None, :, None] + bn.bias[None, :, None]
        with torch.no_grad():
            n = flat.shape[0] * flat.shape[2] * torch.distributed.get_world_size()
            bn.num_batches_tracked.add_(1)
            m = bn.momentum if bn.momentum is not None else 1.0 / float(bn.num_batches_tracked)
            bn.running_mean.mul_(1 - m).add_(m * mean.reshape(-1))
            bn.running_var.mul_(1 - m).add_(m * var.reshape(-1) * n / max(n - 1, 1))
        return out


def _distributed() -> bool:
    """A data-parallel run with more than one process (torch.distributed initialised)."""
    return torch.distributed.is_available() and torch.distributed.is_initialized() and \
        torch.distributed.get_world_size() > 1


class VNLinearLeakyReLU(nn.Module):
    """VNLinear -> VNBatchNorm (optional) -> VNLeakyReLU (direction computed from the input)."""

    def __init__(self, in_channels: int, out_channels: int, batchnorm: bool = True, negative_slope: float = 0.2):
        super().__init__()
        self.linear = VNLinear(in_channels, out_channels)
        self.direction = VNLinear(in_channels, out_channels)
        self.bn = VNBatchNorm(out_channels) if batchnorm else nn.Identity()
        self.slope = negative_slope

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _leaky(self.bn(self.linear(x)), self.direction(x), self.slope)


class VNMaxPool(nn.Module):
    """Per channel, keep the vector with the largest projection on a learned direction (over dim -1)."""

    def __init__(self, channels: int):
        super().__init__()
        self.direction = VNLinear(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        dot = (x * self.direction(x)).sum(2, keepdim=True)  # (B, C, 1, *S)
        idx = dot.argmax(dim=-1, keepdim=True).expand(*x.shape[:-1], 1)
        return x.gather(-1, idx).squeeze(-1)


def vn_mean_pool(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Mean over a spatial dimension (equivariant for VN and VNT features alike). Written as a sum scaled after the
    reduction: the backward pass of ``mean`` writes a full-size divided copy of the gradient, that of ``sum`` only
    expands it (the edge features of a k-NN layer are the largest tensors of a training step)."""
    return x.sum(dim=dim) * (1.0 / x.shape[dim])


class VNTBatchNorm(nn.Module):
    """VN batch norm applied to vectors relative to their mean over the last dim (translation equivariant)."""

    def __init__(self, channels: int):
        super().__init__()
        self.bn = VNBatchNorm(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.mean(dim=-1, keepdim=True)
        return self.bn(x - mean) + mean


class VNTLinearLeakyReLU(nn.Module):
    """VNT block: affine mixing, batch norm about the mean, and a leaky ReLU relative to a learned origin.

    ``p = W_p V`` (features), ``o = W_o V`` (origin), ``d = W_d V - o`` (directions); the
    component of ``p - o`` against ``d`` is clipped. All of ``W_p, W_o, W_d`` are affine, so the
    block commutes with translations.
    """

    def __init__(self, in_channels: int, out_channels: int, batchnorm: bool = True, negative_slope: float = 0.2):
        super().__init__()
        self.linear = VNTLinear(in_channels, out_channels)
        self.direction = VNTLinear(in_channels, out_channels)
        self.origin = VNTLinear(in_channels, 1)
        self.bn = VNTBatchNorm(out_channels) if batchnorm else nn.Identity()
        self.slope = negative_slope

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        p = self.bn(self.linear(x))
        o = self.origin(x)
        return _leaky(p - o, self.direction(x) - o, self.slope) + o


class VNTMaxPool(nn.Module):
    """VN max pooling with projections measured from a learned origin (translation equivariant)."""

    def __init__(self, channels: int):
        super().__init__()
        self.direction = VNTLinear(channels, channels)
        self.origin = VNTLinear(channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        o = self.origin(x)
        dot = ((x - o) * (self.direction(x) - o)).sum(2, keepdim=True)
        idx = dot.argmax(dim=-1, keepdim=True).expand(*x.shape[:-1], 1)
        return x.gather(-1, idx).squeeze(-1)


class VNInvariant(nn.Module):
    """VN invariant layer: a learned equivariant frame ``F (B, 3, 3)`` (columns) from the features,
    then invariant coordinates ``F^T v`` of every feature vector: ``(B, C, 3, *S) -> (B, C, 3, *S)``."""

    def __init__(self, channels: int):
        super().__init__()
        self.vn1 = VNLinearLeakyReLU(channels, max(channels // 2, 2))
        self.frame = VNLinear(max(channels // 2, 2), 2)

    def forward(self, x: torch.Tensor, pooled: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        src = pooled if pooled is not None else x.mean(dim=tuple(range(3, x.dim())))
        z = self.frame(self.vn1(src.unsqueeze(-1)).squeeze(-1))  # (B, 2, 3)
        F = rotation_from_6d(z[:, 0], z[:, 1])
        inv = torch.einsum("bci...,bij->bcj...", x, F)
        return inv, F


def knn_indices(points: torch.Tensor, k: int) -> torch.Tensor:
    """Indices (B, N, k) of the k nearest neighbours of each point (itself included), ``points (B, N, 3)``."""
    d = torch.cdist(points, points)
    return d.topk(min(k, points.shape[1]), dim=-1, largest=False).indices


def gather_neighbours(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``x (B, C, 3, N)`` at neighbour indices ``idx (B, N, k)`` -> ``(B, C, 3, N, k)``."""
    B, C, _, N = x.shape
    k = idx.shape[-1]
    flat = idx.reshape(B, 1, 1, N * k).expand(B, C, 3, N * k)
    return x.gather(3, flat).reshape(B, C, 3, N, k)


# ------------------------------------------------------------------------------------------ checks
def equivariance_error(fn, x: torch.Tensor, rotate: bool = True, translate: bool = False, generator=None) -> float:
    """Largest deviation from SO(3)/SE(3) equivariance of ``fn`` on vector features ``x (B, C, 3, *S)``.

    Compares ``fn(Q x + u)`` with ``Q fn(x) + u`` (``u`` only for VNT layers, whose outputs are
    points) for a random rotation ``Q`` and translation ``u`` per batch element. ``fn`` must be
    in eval mode for batch norm. Returns the max absolute difference relative to the output scale.
    """
    B = x.shape[0]
    Q = random_rotation(B, x.dtype, generator) if rotate else torch.eye(3, dtype=x.dtype).expand(B, 3, 3)
    u = torch.randn(B, 3, dtype=x.dtype, generator=generator) if translate else torch.zeros(B, 3, dtype=x.dtype)
    def act(v):
        return torch.einsum("bij,bcj...->bci...", Q, v) + u.reshape((B, 1, 3) + (1,) * (v.dim() - 3))

    with torch.no_grad():
        a = fn(act(x))
        b = act(fn(x))
    return float((a - b).abs().max() / (b.abs().max() + EPS))
