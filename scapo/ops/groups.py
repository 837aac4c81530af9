"""Finite rotation groups and random rotations (candidate orientations for registration and search).

``rotation_group("O")`` is the cube (octahedral) group of 24 rotations, ``"I"`` the icosahedral group
of 60 and ``"T"`` the tetrahedral group of 12; each is returned with the identity first. They are the
discrete rotation sets of the ICP hypotheses, SCAPO's consensus search and refinement, and the
OP-Align-style object-level alignment (whose backbone selects one element of a finite group).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

#: The finite subgroups of SO(3) used in scapo, by scipy's name -> order.
GROUP_ORDERS = {"T": 12, "O": 24, "I": 60}


def half_turns() -> np.ndarray:
    """The identity and the half turns about the three coordinate axes (the Klein four-group D2) as float64
    ``(4, 3, 3)``, identity first: the orientations that exchange the ends of a frame's axes in pairs, i.e. the
    flips of a frame read from a near-symmetric shape (read-only array)."""
    out = np.stack([np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=4)
def _group(name: str) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    mats = Rotation.create_group(name).as_matrix()
    order = sorted(range(len(mats)), key=lambda i: -float(np.trace(mats[i])))  # identity first (stable)
    out = np.ascontiguousarray(mats[order])
    out.setflags(write=False)
    return out


def rotation_group(name: str = "O") -> np.ndarray:
    """The rotations of a finite group as float64 ``(G, 3, 3)``, identity first (read-only array).

    Raises:
        ValueError: ``name`` is not one of :data:`GROUP_ORDERS` ("T", "O", "I").
    """
    if name not in GROUP_ORDERS:
        raise ValueError(f"unknown rotation group {name!r}; use one of {', '.join(GROUP_ORDERS)}")
    return _group(name)


def octahedral_rotations(dtype=torch.float32, device=None) -> torch.Tensor:
    """The 24 rotations of the cube group (signed permutation matrices of determinant +1) as a new
    ``(24, 3, 3)`` tensor, the identity first."""
    return torch.from_numpy(np.array(_group("O"))).round().to(dtype=dtype, device=device)


def random_rotation(batch: int, dtype=torch.float64, generator: torch.Generator | None = None) -> torch.Tensor:
    """Uniform random rotations ``(batch, 3, 3)`` (QR of Gaussian matrices, sign-fixed, det +1), on CPU."""
    A = torch.randn(batch, 3, 3, dtype=dtype, generator=generator)
    Q, R = torch.linalg.qr(A)
    Q = Q * torch.sign(torch.diagonal(R, dim1=-2, dim2=-1)).unsqueeze(-2)
    det = torch.det(Q)
    Q[:, :, 2] *= det.unsqueeze(-1)
    return Q


