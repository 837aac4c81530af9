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

#: ``edge_pool`` computes on per-edge scalars (its faster form) when ``out_channels * k`` is at least this; below, the
#: layer's own forward and a mean are faster (the per-point batched matrix products are too small to pay for
#: themselves). Measured on one CPU thread (``scapo bench perf --what train``, ``results/perf/train_edge_pool/``):
#: SCAPO's ``cpu`` preset (16 x 8 and 8 x 8) is 1.2x slower in the scalar form, NPCS-style's and EAP-style's ``cpu``
#: presets (32 x 10) 1.06x and 1.33x faster, the ``paper`` presets 1.3-1.75x.
FUSED_EDGE_MIN = 256


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
        return x * self.scale(norm).unsqueeze(2)  # one full-size multiply by BN(|v|) / |v|

    def scale(self, norm: torch.Tensor, channel_dim: int = 1) -> torch.Tensor:
        """The factor ``BN(|v|) / |v|`` that multiplies each vector, from the vectors' norms ``norm``
        (``sqrt(|v|^2 + EPS^2)``), of shape ``(B, C, *S)`` or, with ``channel_dim=-1``, ``(B, *S, C)`` (the same
        shape out); batch statistics per channel over the batch and ``*S`` (over the global batch in a
        data-parallel run)."""
        if channel_dim == -1 and not (self.training and _distributed()):
            return self.bn(norm.reshape(-1, norm.shape[-1])).reshape(norm.shape) / norm  # rows: same statistics
        if channel_dim == -1:
            return self.scale(norm.movedim(-1, 1)).movedim(1, -1)
        B, C = norm.shape[:2]
        flat = norm.reshape(B, C, -1)
        if self.training and _distributed():
            normed = self._synced(flat)
        else:
            normed = self.bn(flat)
        return normed.reshape(norm.shape) / norm

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

    def edge_pool(self, edges: torch.Tensor) -> torch.Tensor:
        """``vn_mean_pool(self(edges))`` for edge features ``edges (B, C, 3, N, k)`` (the first layer of a
        VN-DGCNN, averaged over the ``k`` neighbours) -> ``(B, C_out, 3, N)``: the same function (same batch
        statistics, same gradients up to rounding) computed without the ``(B, C_out, 3, N, k)`` tensors.

        Every output vector of an edge is a combination of that edge's ``C`` input vectors ``e_c``:
        ``p_o = sum_c W_oc e_c`` (linear), ``d_o = sum_c U_oc e_c`` (direction), and after the batch norm and the
        leaky ReLU ``y_o = s_o p_o + b_o d_o``, with the per-edge scalars ``s_o = BN(|p_o|) / |p_o|`` and
        ``b_o = (slope - 1) min(<s_o p_o, d_o>, 0) / (|d_o|^2 + EPS)``. The norms and inner products are quadratic
        forms of the edge's Gram matrix ``<e_c, e_c'>`` (:func:`_edge_forms`) and the mean over neighbours is
        ``sum_c W_oc mean_k(s_o e_c) + U_oc mean_k(b_o e_c)`` (:func:`_neighbour_sum`), so the large tensors are
        ``(B, N, k, C_out)`` scalars instead of ``(B, C_out, 3, N, k)`` vectors: 2.7x faster forward at the
        ``paper`` preset's SCAPO edge layer (32 clouds of 1024 points, k 16); smaller layers (``C_out * k`` under
        :data:`FUSED_EDGE_MIN`) take the plain path, which is faster there. Norms from the Gram matrix round
        differently (relative ~1e-7 of ``(sum |W| |e|)^2`` in float32); they are clamped at zero before ``EPS^2``.

        Raises:
            ValueError: ``edges`` not of shape ``(B, C, 3, N, k)`` with this layer's ``C``."""
        W, U = self.linear.weight, self.direction.weight  # (O, C)
        vec = _edge_basis(edges, W.shape[1])  # (B, N, k, C, 3)
        if W.shape[0] * edges.shape[-1] < FUSED_EDGE_MIN:
            return vn_mean_pool(self(edges))
        pp, pd, dd = _edge_forms(vec, [(W, W), (W, U), (U, U)])  # (B, N, k, O) each
        s = self.bn.scale(_norm(pp), channel_dim=-1) if isinstance(self.bn, VNBatchNorm) else torch.ones_like(pp)
        b = (self.slope - 1) * (s * pd).clamp(max=0.0) / (dd + EPS)
        return (_neighbour_sum(s, vec, W) + _neighbour_sum(b, vec, U)) * (1.0 / edges.shape[-1])


def _edge_basis(edges: torch.Tensor, channels: int) -> torch.Tensor:
    """Edge features ``(B, C, 3, N, k)`` as per-edge rows of vectors ``(B, N, k, C, 3)`` (a view).

    Raises:
        ValueError: ``edges`` not of shape ``(B, channels, 3, N, k)``."""
    if edges.dim() != 5 or edges.shape[1] != channels or edges.shape[2] != 3:
        raise ValueError(f"edge_pool needs edges (B, {channels}, 3, N, k), got {tuple(edges.shape)}")
    return edges.permute(0, 3, 4, 1, 2)


def _edge_forms(vec: torch.Tensor, pairs: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, ...]:
    """Per edge and output channel, the inner products ``<sum_d A_od f_d, sum_d B_od f_d>`` of combinations of
    the edge's vectors ``vec (B, N, k, D, 3)`` (``f_d``), one ``(B, N, k, O)`` tensor per pair ``(A, B)`` of
    ``(O, D)`` weights: quadratic forms of the edge's Gram matrix, all pairs in one matrix product."""
    B, N, k, D, _ = vec.shape
    O = pairs[0][0].shape[0]
    gram = (vec[..., :, None, :] * vec[..., None, :, :]).sum(-1).reshape(B, N, k, D * D)  # (a bmm is slower)
    forms = torch.cat([a[:, :, None] * b[:, None, :] for a, b in pairs]).reshape(len(pairs) * O, D * D)
    return (gram @ forms.T).split(O, dim=-1)


def _neighbour_sum(coef: torch.Tensor, vec: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``sum_k sum_d weight_od coef_o f_d`` ``(B, O, 3, N)`` for per-edge scalars ``coef (B, N, k, O)``, the edges'
    vectors ``vec (B, N, k, D, 3)`` and weights ``weight (O, D)``: one batched matrix product over the neighbours
    (``coef^T f``, ``(O, k) x (k, 3 D)`` per point), then the channel mixing on the ``k``-times smaller result."""
    B, N, k, D, _ = vec.shape
    summed = (coef.transpose(-1, -2) @ vec.reshape(B, N, k, D * 3)).reshape(B, N, -1, D, 3)
    return torch.einsum("bnodj,od->bojn", summed, weight)


def _norm(sq: torch.Tensor) -> torch.Tensor:
    """``sqrt(max(sq, 0) + EPS^2)``: the vector norm of :class:`VNBatchNorm` from a squared norm that may round
    below zero."""
    return sq.clamp_min(0.0).add(EPS * EPS).sqrt()


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

    def edge_pool(self, edges: torch.Tensor) -> torch.Tensor:
        """``vn_mean_pool(self(edges))`` for edge features ``edges (B, C, 3, N, k)`` (SCAPO's translation branch's
        first layer, averaged over the ``k`` neighbours) -> ``(B, C_out, 3, N)``: the same function computed on
        ``(B, N, k, C_out)`` scalars, as :meth:`VNLinearLeakyReLU.edge_pool` does.

        With ``e_c`` an edge's inputs, ``ebar_c`` their mean over the point's neighbours and ``et_c = e_c - ebar_c``:
        the batch norm (about the neighbours' mean) gives ``p'_o = s_o q_o + m_o`` with ``q_o = sum_c W_oc et_c``,
        ``m_o = sum_c W_oc ebar_c`` and ``s_o = BN(|q_o|) / |q_o|`` (1 without batch norm); with the origin
        ``o = sum_c V_c e_c`` and the direction ``b_o = sum_c (U_oc - V_c) e_c``, the output is
        ``p'_o + c_o b_o``, ``c_o = (slope - 1) min(<p'_o - o, b_o>, 0) / (|b_o|^2 + EPS)``. All inner products
        are quadratic forms in the ``2 C`` vectors ``(et, ebar)`` of each edge, and the mean over neighbours is
        ``sum_c W_oc mean_k(s_o et_c) + m_o + sum_c (U_oc - V_c) mean_k(c_o e_c)``.

        Raises:
            ValueError: ``edges`` not of shape ``(B, C, 3, N, k)`` with this layer's ``C``."""
        W, U, V = self.linear.weight, self.direction.weight, self.origin.weight  # (O, C), (O, C), (1, C)
        C = W.shape[1]
        vec = _edge_basis(edges, C)  # (B, N, k, C, 3)
        if W.shape[0] * edges.shape[-1] < FUSED_EDGE_MIN:
            return vn_mean_pool(self(edges))
        mean = vec.mean(2, keepdim=True)  # (B, N, 1, C, 3)
        basis = torch.cat([vec - mean, mean.expand_as(vec)], dim=3)  # (B, N, k, 2 C, 3): (et, ebar)
        zero, Vo = torch.zeros_like(W), V.expand_as(W)
        q, mo, b = torch.cat([W, zero], 1), torch.cat([-Vo, W - Vo], 1), torch.cat([U - Vo, U - Vo], 1)
        qq, qb, mob, bb = _edge_forms(basis, [(q, q), (q, b), (mo, b), (b, b)])
        s = self.bn.bn.scale(_norm(qq), channel_dim=-1) if isinstance(self.bn, VNTBatchNorm) else torch.ones_like(qq)
        c = (self.slope - 1) * (s * qb + mob).clamp(max=0.0) / (bb + EPS)
        k = edges.shape[-1]
        m = torch.einsum("bncj,oc->bojn", mean[:, :, 0], W)  # (B, O, 3, N)
        return (_neighbour_sum(s, basis[:, :, :, :C], W) + _neighbour_sum(c, vec, U - Vo)) * (1.0 / k) + m


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
