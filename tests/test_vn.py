"""Equivariance of every VN / VNT layer and of the whole encoder, in float32 and float64."""

import pytest
import torch

from scapo.nn.encoder import EncoderConfig, SE3Encoder
from scapo.nn.vn import (
    VNBatchNorm,
    VNInvariant,
    VNLeakyReLU,
    VNLinear,
    VNLinearLeakyReLU,
    VNMaxPool,
    VNTBatchNorm,
    VNTLinear,
    VNTLinearLeakyReLU,
    VNTMaxPool,
    equivariance_error,
    random_rotation,
    vn_mean_pool,
)
from scapo.ops.so3 import rotation_from_6d as gram_schmidt

TOL = {torch.float32: 1e-4, torch.float64: 1e-8}
DTYPES = [torch.float32, torch.float64]


def _prepare(layer, dtype):
    layer = layer.to(dtype)
    # give batch-norm layers non-trivial running statistics, then evaluate in eval mode
    layer.train()
    with torch.no_grad():
        for _ in range(2):
            layer(torch.randn(4, layer_in(layer), 3, 10, dtype=dtype))
    return layer.eval()


def layer_in(layer):
    for m in layer.modules():
        if isinstance(m, VNLinear):
            return m.weight.shape[1]
        if isinstance(m, VNTLinear):
            return m.weight_raw.shape[1]
    raise AssertionError


VN_LAYERS = [
    lambda: VNLinear(5, 7), lambda: VNLeakyReLU(5), lambda: VNLeakyReLU(5, share=True),
    lambda: VNBatchNorm(5), lambda: VNLinearLeakyReLU(5, 6), lambda: VNMaxPool(5),
]
VNT_LAYERS = [lambda: VNTLinear(5, 7), lambda: VNTLinearLeakyReLU(5, 6), lambda: VNTBatchNorm(5),
              lambda: VNTMaxPool(5)]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("make", VN_LAYERS)
def test_vn_layers_are_rotation_equivariant(make, dtype):
    torch.manual_seed(0)
    layer = make()
    if isinstance(layer, VNBatchNorm):
        layer = layer.to(dtype)
        layer.train()
        with torch.no_grad():
            layer(torch.randn(4, 5, 3, 10, dtype=dtype))
        layer.eval()
    else:
        layer = _prepare(layer, dtype)
    x = torch.randn(3, 5, 3, 10, dtype=dtype)
    assert equivariance_error(layer, x, rotate=True) < TOL[dtype]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("make", VNT_LAYERS)
def test_vnt_layers_are_se3_equivariant(make, dtype):
    torch.manual_seed(1)
    layer = make()
    if isinstance(layer, VNTBatchNorm):
        layer = layer.to(dtype).eval()
    else:
        layer = _prepare(layer, dtype)
    x = torch.randn(3, 5, 3, 10, dtype=dtype)
    assert equivariance_error(layer, x, rotate=True, translate=True) < TOL[dtype]


def test_vnt_linear_rows_sum_to_one_and_vn_linear_is_not_translation_equivariant():
    layer = VNTLinear(4, 3)
    torch.testing.assert_close(layer.weight.sum(1), torch.ones(3))
    x = torch.randn(2, 4, 3, 6, dtype=torch.float64)
    assert equivariance_error(VNLinear(4, 3).double(), x, translate=True) > 1e-3


@pytest.mark.parametrize("dtype", DTYPES)
def test_invariant_layer_and_pooling(dtype):
    torch.manual_seed(2)
    inv = VNInvariant(6).to(dtype)
    inv.train()
    with torch.no_grad():
        inv(torch.randn(4, 6, 3, 10, dtype=dtype))
    inv.eval()
    x = torch.randn(2, 6, 3, 10, dtype=dtype)
    Q = random_rotation(2, dtype)
    a, Fa = inv(torch.einsum("bij,bcjn->bcin", Q, x))
    b, Fb = inv(x)
    assert (a - b).abs().max() < TOL[dtype] * 10
    assert (Fa - Q @ Fb).abs().max() < TOL[dtype] * 10
    assert equivariance_error(lambda v: vn_mean_pool(v), x, translate=True) < TOL[dtype]
    R = gram_schmidt(torch.randn(5, 3, dtype=dtype), torch.randn(5, 3, dtype=dtype))
    assert (R.transpose(1, 2) @ R - torch.eye(3, dtype=dtype)).abs().max() < TOL[dtype]
    assert (torch.det(R) - 1).abs().max() < TOL[dtype]


@pytest.mark.parametrize("dtype", DTYPES)
def test_encoder_is_se3_equivariant(dtype):
    torch.manual_seed(3)
    enc = SE3Encoder(EncoderConfig(k=6, rot_channels=(8, 16), trans_channels=(4, 8), code_dim=32)).to(dtype)
    enc.train()
    with torch.no_grad():
        enc(torch.randn(4, 64, 3, dtype=dtype))
    enc.eval()
    X = torch.randn(3, 64, 3, dtype=dtype) * 0.4 + torch.tensor([0.0, 0.0, 2.0], dtype=dtype)
    Q = random_rotation(3, dtype)
    u = torch.randn(3, 3, dtype=dtype)
    with torch.no_grad():
        a = enc(X)
        b = enc(X @ Q.transpose(1, 2) + u[:, None])
    tol = TOL[dtype]
    scale = float(a.t.abs().max())
    assert (b.t - ((Q @ a.t.unsqueeze(-1)).squeeze(-1) + u)).abs().max() / scale < tol
    assert (b.R_raw - Q @ a.R_raw).abs().max() / float(a.R_raw.abs().max()) < tol
    assert (b.R - Q @ a.R).abs().max() < tol * 10
    assert (b.code - a.code).abs().max() / float(a.code.abs().max()) < tol


@pytest.mark.parametrize("cls,C,batchnorm", [(VNLinearLeakyReLU, 3, True), (VNLinearLeakyReLU, 2, False),
                                              (VNTLinearLeakyReLU, 2, True), (VNTLinearLeakyReLU, 3, False)])
def test_edge_pool_is_the_layer_then_the_mean_with_the_same_gradients(monkeypatch, cls, C, batchnorm):
    """The scalar form of an edge layer (``edge_pool``: Gram-matrix quadratic forms, one batched product over the
    neighbours) computes ``vn_mean_pool(layer(edges))`` exactly: outputs, input and weight gradients, batch
    statistics in training and running statistics in eval, in float64."""
    import scapo.nn.vn as vn

    monkeypatch.setattr(vn, "FUSED_EDGE_MIN", 0)  # the scalar form even for this small layer
    torch.manual_seed(0)
    layer = cls(C, 6, batchnorm=batchnorm).double()
    ref = cls(C, 6, batchnorm=batchnorm).double()
    ref.load_state_dict(layer.state_dict())
    edges = torch.randn(3, C, 3, 11, 5, dtype=torch.float64)
    edges[:, 0] = edges[:, 0, :, :, :1]  # as in DGCNN: one input is the centre point, the same for every neighbour
    for train in (True, False):
        layer.train(train), ref.train(train)
        e1, e2 = edges.clone().requires_grad_(), edges.clone().requires_grad_()
        a, b = layer.edge_pool(e1), vn_mean_pool(ref(e2))
        assert a.shape == (3, 6, 3, 11)
        assert torch.allclose(a, b, atol=1e-12)
        ga = torch.autograd.grad((a * torch.cos(a)).sum(), [e1, *layer.parameters()])
        gb = torch.autograd.grad((b * torch.cos(b)).sum(), [e2, *ref.parameters()])
        assert all(torch.allclose(x, y, atol=1e-10) for x, y in zip(ga, gb))
    for name, buf in layer.named_buffers():  # the same running statistics after the training pass
        assert torch.allclose(buf.double(), dict(ref.named_buffers())[name].double())


def test_edge_pool_is_equivariant_and_checks_its_input(monkeypatch):
    import scapo.nn.vn as vn

    monkeypatch.setattr(vn, "FUSED_EDGE_MIN", 0)
    torch.manual_seed(1)
    rot, trans = _prepare(VNLinearLeakyReLU(3, 4), torch.float64), _prepare(VNTLinearLeakyReLU(2, 4), torch.float64)
    edges = torch.randn(2, 3, 3, 9, 4, dtype=torch.float64)
    assert equivariance_error(rot.edge_pool, edges) < TOL[torch.float64]
    assert equivariance_error(trans.edge_pool, edges[:, :2], translate=True) < TOL[torch.float64]
    with pytest.raises(ValueError, match=r"edges \(B, 3, 3, N, k\)"):
        rot.edge_pool(edges[:, :2])
