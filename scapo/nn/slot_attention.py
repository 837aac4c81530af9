"""Slot attention with slot-specific parameters, as EAP groups points into parts.

Locatello et al., "Object-Centric Learning with Slot Attention", NeurIPS 2020, in the variant of
Meowuu7/equi-articulated-pose (``SPConvNets/utils/slot_attention_spec_v2.py``, the ``SlotAttention`` its
model imports; facts taken from it, code our own): every slot has its own query, key and value projections,
GRU cell, residual MLP and layer norms, and its own learned initial mean and log-sigma. Each iteration

1. ``dots[b, s, n] = q_s(slot_s) . k_s(x_n) / sqrt(D)``;
2. ``attn = softmax over slots (dim s) + eps``: points are shared out among the slots (competition);
3. ``update_s = sum_n v_s(x_n) attn[s, n] / sum_n attn[s, n]``: the slot's weighted mean of its values;
4. ``slot_s = GRU_s(update_s, slot_s)``, then ``slot_s += MLP_s(LN_s(slot_s))``.

The returned grouping is the last iteration's ``attn`` (over slots, summing to 1 + P eps per point).

Ours differs in one way: the initial slots are ``mu + sigma * noise`` in training (as the original) but
``mu`` in eval mode, so that a trained model's predictions are deterministic. The per-slot parameters are
stacked tensors applied by batched products (no Python loop over slots).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class SlotAttention(nn.Module):
    """Slot attention over per-point features (module docstring).

    ``forward(x (B, N, D)) -> (slots (B, S, D), attn (B, S, N))``; ``attn`` sums over slots to about 1 per point.

    Args:
        num_slots: S, the number of groups (EAP: the category's part count).
        dim: D, the feature width. iters: attention iterations (EAP's scripts: ``--slot-iters 7``).
        hidden: width of the residual MLP (at least ``dim``). eps: added to the attention before the weighted mean.
    """

    def __init__(self, num_slots: int, dim: int, iters: int = 3, hidden: int = 128, eps: float = 1e-8):
        super().__init__()
        if num_slots < 1 or dim < 1 or iters < 1:
            raise ValueError(f"SlotAttention needs num_slots, dim, iters >= 1, got {num_slots}, {dim}, {iters}")
        S, D, H = num_slots, dim, max(dim, hidden)
        self.S, self.D, self.iters, self.eps = S, D, iters, eps
        self.mu = nn.Parameter(torch.randn(1, S, D))
        self.log_sigma = nn.Parameter(nn.init.xavier_uniform_(torch.zeros(1, S, D)))

        def stack(*shape, fan_in):
            bound = 1.0 / math.sqrt(fan_in)
            return nn.Parameter(torch.empty(S, *shape).uniform_(-bound, bound))

        # per-slot linear maps (weights (S, in, out), biases (S, out)), as nn.Linear initialises them
        self.Wq, self.bq = stack(D, D, fan_in=D), stack(D, fan_in=D)
        self.Wk, self.bk = stack(D, D, fan_in=D), stack(D, fan_in=D)
        self.Wv, self.bv = stack(D, D, fan_in=D), stack(D, fan_in=D)
        # per-slot GRU cells: gates r, z, n stacked as nn.GRUCell does
        self.Wi, self.bi = stack(D, 3 * D, fan_in=D), stack(3 * D, fan_in=D)
        self.Wh, self.bh = stack(D, 3 * D, fan_in=D), stack(3 * D, fan_in=D)
        self.W1, self.b1 = stack(D, H, fan_in=D), stack(H, fan_in=D)
        self.W2, self.b2 = stack(H, D, fan_in=H), stack(D, fan_in=H)
        # per-slot layer norms (affine) of the inputs, the slots and before the MLP
        for name in ("in", "slot", "ff"):
            self.register_parameter(f"g_{name}", nn.Parameter(torch.ones(S, D)))
            self.register_parameter(f"b_{name}", nn.Parameter(torch.zeros(S, D)))

    def _norm(self, x: torch.Tensor, name: str) -> torch.Tensor:
        """Layer norm over the last dim with slot ``s``'s affine parameters; ``x (B, S, ..., D)``."""
        g, b = getattr(self, f"g_{name}"), getattr(self, f"b_{name}")
        shape = (1, self.S) + (1,) * (x.dim() - 3) + (self.D,)
        return nn.functional.layer_norm(x, (self.D,)) * g.view(shape) + b.view(shape)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if x.dim() != 3 or x.shape[-1] != self.D:
            raise ValueError(f"SlotAttention expects (B, N, {self.D}) features, got {tuple(x.shape)}")
        B = x.shape[0]
        mu = self.mu.expand(B, -1, -1)
        slots = mu + self.log_sigma.exp() * torch.randn_like(mu) if self.training else mu
        xs = self._norm(x.unsqueeze(1).expand(-1, self.S, -1, -1), "in")  # (B, S, N, D)
        k = torch.einsum("bsnd,sde->bsne", xs, self.Wk) + self.bk[None, :, None]
        v = torch.einsum("bsnd,sde->bsne", xs, self.Wv) + self.bv[None, :, None]
        attn = None
        for _ in range(self.iters):
            prev = slots
            q = torch.einsum("bsd,sde->bse", self._norm(slots, "slot"), self.Wq) + self.bq
            dots = torch.einsum("bsd,bsnd->bsn", q, k) / math.sqrt(self.D)
            attn = dots.softmax(dim=1) + self.eps  # competition among the slots for each point
            w = attn / attn.sum(dim=-1, keepdim=True)
            updates = torch.einsum("bsnd,bsn->bsd", v, w)
            slots = self._gru(updates, prev)
            h = torch.relu(torch.einsum("bsd,sdh->bsh", self._norm(slots, "ff"), self.W1) + self.b1)
            slots = slots + torch.einsum("bsh,shd->bsd", h, self.W2) + self.b2
        return slots, attn

    def _gru(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """Slot-specific GRU cells (``nn.GRUCell``'s equations); ``x, h (B, S, D)``."""
        gi = torch.einsum("bsd,sde->bse", x, self.Wi) + self.bi
        gh = torch.einsum("bsd,sde->bse", h, self.Wh) + self.bh
        i_r, i_z, i_n = gi.chunk(3, -1)
        h_r, h_z, h_n = gh.chunk(3, -1)
        r, z = torch.sigmoid(i_r + h_r), torch.sigmoid(i_z + h_z)
        n = torch.tanh(i_n + r * h_n)
        return (1 - z) * n + z * h
