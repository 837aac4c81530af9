"""Torch rotation and transform helpers (scapo.ops.so3) against scipy."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from scapo.ops import so3


@pytest.fixture
def rots():
    r = Rotation.random(64, random_state=0)
    # add the identity, tiny angles and (near) half turns: where log and rotvec need care
    extra = Rotation.from_rotvec(np.array([[0, 0, 0], [1e-7, 0, 0], [0, 1e-5, 1e-5], [np.pi, 0, 0],
                                           [0, np.pi - 1e-6, 0], [1, 1, 1] / np.sqrt(3) * np.pi]))
    return Rotation.concatenate([r, extra])


def test_hat_is_the_cross_product():
    v, u = torch.randn(10, 3, dtype=torch.float64), torch.randn(10, 3, dtype=torch.float64)
    torch.testing.assert_close((so3.skew(v) @ u[..., None])[..., 0], torch.cross(v, u, dim=-1))


def test_exp_and_rotvec_match_scipy(rots):
    w = torch.from_numpy(rots.as_rotvec())
    torch.testing.assert_close(so3.rotation_from_rotvec(w), torch.from_numpy(rots.as_matrix()), atol=1e-9, rtol=0)
    angle = w.norm(dim=-1)
    axis = w / angle.clamp_min(1e-12)[:, None]
    keep = angle > 1e-3
    torch.testing.assert_close(so3.exp_so3(axis[keep], angle[keep]), torch.from_numpy(rots.as_matrix()[keep.numpy()]))


def test_log_inverts_exp_like_scipy_including_half_turns(rots):
    R = torch.from_numpy(rots.as_matrix())
    w = so3.log_so3(R)
    assert torch.allclose(w.norm(dim=-1), torch.from_numpy(rots.magnitude()), atol=1e-6)
    # the rotation vector may flip sign only at exactly pi; the rotation it gives is the same
    torch.testing.assert_close(so3.rotation_from_rotvec(w), R, atol=1e-6, rtol=0)
    generic = rots.magnitude() < 3.0
    torch.testing.assert_close(w[generic], torch.from_numpy(rots.as_rotvec()[generic]), atol=1e-7, rtol=0)


def test_6d_gives_rotations_and_is_equivariant():
    v1, v2 = torch.randn(20, 3, dtype=torch.float64), torch.randn(20, 3, dtype=torch.float64)
    R = so3.rotation_from_6d(v1, v2)
    torch.testing.assert_close(R.transpose(1, 2) @ R, torch.eye(3, dtype=R.dtype).expand(20, 3, 3))
    assert torch.allclose(torch.linalg.det(R), torch.ones(20, dtype=R.dtype))
    Q = torch.from_numpy(Rotation.random(20, random_state=1).as_matrix())
    torch.testing.assert_close(so3.rotation_from_6d((Q @ v1[..., None])[..., 0], (Q @ v2[..., None])[..., 0]), Q @ R)


def test_rotation_between_takes_a_to_b_also_when_opposite():
    a = torch.nn.functional.normalize(torch.randn(30, 3, dtype=torch.float64), dim=-1)
    b = torch.nn.functional.normalize(torch.randn(30, 3, dtype=torch.float64), dim=-1)
    b[0] = -a[0]
    b[1] = a[1]
    R = so3.rotation_between(a, b)
    torch.testing.assert_close((R @ a[..., None])[..., 0], b, atol=1e-6, rtol=0)  # EPS in the axis normalisation


def test_transforms_build_invert_and_apply_like_scipy():
    r = Rotation.random(8, random_state=2)
    t = torch.randn(8, 3, dtype=torch.float64)
    T = so3.make_transform(torch.from_numpy(r.as_matrix()), t)
    torch.testing.assert_close(so3.invert_transform(T) @ T, torch.eye(4, dtype=T.dtype).expand(8, 4, 4))
    p = torch.randn(8, 5, 3, dtype=torch.float64)
    want = np.stack([r[i].apply(p[i].numpy()) + t[i].numpy() for i in range(8)])
    torch.testing.assert_close(so3.transform_points(T, p), torch.from_numpy(want))
