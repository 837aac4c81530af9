"""Point-network building blocks of the learned baselines (plain PyTorch, CPU and CUDA)."""

from __future__ import annotations

import torch
from torch import nn


class ResBlock(nn.Module):
    """Fully connected residual block ``x + fc2(relu(fc1(relu(x))))`` with a linear shortcut when the
    width changes (the ResNet-PointNet block of Occupancy Networks, also OP-Align's part-level head)."""

    def __init__(self, d_in: int, d_out: int):
        super().__init__()
        self.fc1 = nn.Linear(d_in, d_out)
        self.fc2 = nn.Linear(d_out, d_out)
        self.short = nn.Linear(d_in, d_out, bias=False) if d_in != d_out else nn.Identity()
        nn.init.zeros_(self.fc2.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.short(x) + self.fc2(torch.relu(self.fc1(torch.relu(x))))


class PointResNet(nn.Module):
    """ResNet-PointNet: per-point residual blocks, each fed the point feature concatenated with the
    max-pooled feature of the cloud.

    ``forward(points (B, N, d_in)) -> (per-point features (B, N, width), global feature (B, width))``.
    """

    def __init__(self, d_in: int = 3, width: int = 128, blocks: int = 3):
        super().__init__()
        self.fc_in = nn.Linear(d_in, 2 * width)
        self.blocks = nn.ModuleList([ResBlock(2 * width, width) for _ in range(blocks)])
        self.norms = nn.ModuleList([nn.LayerNorm(width) for _ in range(blocks)])

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.fc_in(x)
        for i, (blk, norm) in enumerate(zip(self.blocks, self.norms)):
            h = norm(blk(h))
            if i < len(self.blocks) - 1:
                h = torch.cat([h, h.max(1, keepdim=True).values.expand_as(h)], -1)
        return h, h.max(1).values


def mlp(sizes: list[int], last_act: bool = False) -> nn.Sequential:
    """Linear layers of ``sizes`` with ReLU between them (and after the last with ``last_act``)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2 or last_act:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class VNPointEncoder(nn.Module):
    """SO(3)-equivariant point features by vector neurons (Deng et al., ICCV 2021; :mod:`scapo.nn.vn`): an edge
    layer over the ``k`` nearest neighbours of the centred cloud (VN-DGCNN's edge features ``[x_j - x_i, x_i]``,
    averaged over neighbours), a point layer on each point's features beside the cloud's mean, and their
    invariant coordinates in a learned equivariant frame.

    ``forward(X (B, N, 3)) -> (equivariant (B, C, 3, N), invariant (B, N, 3C))``: rotating ``X`` about its
    centroid rotates the first and leaves the second unchanged (translation changes neither). Used by EAP-style
    (its part-level features) and NPCS-style (the rotation-robust backbone of the paper's NPCS-EPN row).
    """

    def __init__(self, channels: int, k: int):
        super().__init__()
        from scapo.nn.vn import VNInvariant, VNLinearLeakyReLU

        self.k = int(k)
        self.edge = VNLinearLeakyReLU(2, channels)
        self.point = VNLinearLeakyReLU(2 * channels, channels)
        self.inv = VNInvariant(channels)

    def forward(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        from scapo.nn.vn import gather_neighbours, knn_indices

        c = X.mean(1, keepdim=True)
        x = (X - c).transpose(1, 2).unsqueeze(1)  # (B, 1, 3, N)
        nb = gather_neighbours(x, knn_indices(X, self.k))  # (B, 1, 3, N, k)
        e = torch.cat([nb - x.unsqueeze(-1), x.unsqueeze(-1).expand_as(nb)], 1)  # (B, 2, 3, N, k)
        f = self.edge.edge_pool(e)  # (B, C, 3, N): vn_mean_pool(self.edge(e)), computed without (B, C, 3, N, k)
        f = self.point(torch.cat([f, f.mean(-1, keepdim=True).expand_as(f)], 1))
        inv, _ = self.inv(f)  # (B, C, 3, N)
        return f, inv.flatten(1, 2).transpose(1, 2)
