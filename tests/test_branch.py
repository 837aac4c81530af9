"""Stage-2 branch correction of the stage-1 frames (scapo.models.branch)."""

import math

import pytest
import torch

from scapo.models.branch import apply_branch, axis_rotation, branch_of, fit_branch, rotation_between


def _frames_and_clouds(n_views: int = 60, minority: int = 24, seed: int = 0):
    """Views of one asymmetric shape ``S0`` turned about the canonical z axis, which every camera sees
    as its up (``-y``, as in the capture setup); the last ``minority`` frames took the half-turned
    branch ``R H^T`` (H: half turn about x), so their canonical clouds are ``H S0``."""
    g = torch.Generator().manual_seed(seed)
    S0 = torch.cat([torch.rand(80, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 0.2, 0.2], dtype=torch.float64),
                    torch.rand(40, 3, generator=g, dtype=torch.float64) * torch.tensor([0.2, 0.6, 0.2], dtype=torch.float64),
                    torch.rand(20, 3, generator=g, dtype=torch.float64) * torch.tensor([0.2, 0.2, 0.5], dtype=torch.float64)])
    S0 = S0 - S0.mean(0)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    A = rotation_between(z, torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)) @ axis_rotation(z, 0.7)
    phi = torch.linspace(0, 2 * math.pi, n_views + 1, dtype=torch.float64)[:-1]
    true = torch.stack([A @ axis_rotation(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), float(p)) for p in phi])
    H = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    R = true.clone()
    R[n_views - minority:] = true[n_views - minority:] @ H.T
    clouds = torch.stack([S0 @ (H.T if i >= n_views - minority else torch.eye(3, dtype=torch.float64))
                          for i in range(n_views)])
    return true, R, clouds, H


def test_rotation_between_and_axis_rotation():
    g = torch.Generator().manual_seed(1)
    for _ in range(5):
        a, b = torch.randn(3, generator=g, dtype=torch.float64), torch.randn(3, generator=g, dtype=torch.float64)
        M = rotation_between(a, b)
        assert torch.allclose(M @ (a / a.norm()), b / b.norm(), atol=1e-9)
        assert torch.allclose(M @ M.T, torch.eye(3, dtype=torch.float64), atol=1e-9)
        assert abs(float(torch.linalg.det(M)) - 1.0) < 1e-9
    a = torch.tensor([0.3, -0.2, 0.9], dtype=torch.float64)
    M = rotation_between(a, -a)  # antiparallel: a half turn
    assert torch.allclose(M @ (a / a.norm()), -a / a.norm(), atol=1e-9)
    assert abs(float(torch.linalg.det(M)) - 1.0) < 1e-9
    Rz = axis_rotation(torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64), math.pi / 2)
    assert torch.allclose(Rz @ torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
                          torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), atol=1e-12)


def test_fit_branch_undoes_a_half_turned_minority_branch():
    true, R, clouds, H = _frames_and_clouds()
    branch, F, info = fit_branch(R, clouds)
    assert info["active"] and abs(info["minority_fraction"] - 24 / 60) < 1e-9
    assert info["angle_deg"] > 170.0 and info["score"] < 1e-12 < info["score_identity"]
    wrong = branch_of(R, branch)
    assert wrong.tolist() == [False] * 36 + [True] * 24
    corrected = apply_branch(R, branch, F)
    assert torch.allclose(corrected, true, atol=1e-9)  # every frame back on the majority branch
    # differentiable in R, and a no-op when off
    Rg = R.clone().requires_grad_(True)
    apply_branch(Rg, branch, F).sum().backward()
    assert Rg.grad is not None and torch.isfinite(Rg.grad).all()
    off = torch.zeros(3, 3, dtype=R.dtype)
    assert torch.equal(apply_branch(R, off, F), R) and not branch_of(R, off).any()


def test_fit_branch_stays_off_without_a_minority_branch():
    true, _, _, _ = _frames_and_clouds()
    S = _frames_and_clouds()[2][:1].expand(len(true), -1, -1)
    branch, F, info = fit_branch(true, S)
    assert not info["active"] and torch.equal(branch, torch.zeros(3, 3, dtype=true.dtype))
    assert torch.equal(F, torch.eye(3, dtype=true.dtype))
    with pytest.raises(ValueError):
        fit_branch(true[:1], S[:1])
    with pytest.raises(ValueError):
        fit_branch(true, S[:3])


def test_model_branch_buffers_default_off_and_old_checkpoints_load():
    from scapo.models.presets import get_preset
    from scapo.models.scapo_model import ModelConfig, SCAPOModel
    from scapo.models.train import _identity_hash

    pc = get_preset("test")
    cfg = ModelConfig(num_parts=2, joint_types=(0,), joint_parts=((0, 1),), encoder=pc.encoder,
                      template_points=pc.template_points)
    model = SCAPOModel(cfg)
    assert not model.branch.abs().any() and torch.equal(model.branch_flip, torch.eye(3))
    old = {k: v for k, v in model.state_dict().items() if not k.startswith("branch")}
    fresh = SCAPOModel(cfg)
    fresh.load_checkpoint_state(old)  # a checkpoint from before the correction existed
    X = torch.randn(2, 64, 3)
    out = fresh(X)
    assert torch.equal(out["R"], out["enc"].R)  # off: the stage-1 frame
    # the identity of a run from before the field existed is unchanged by the field's default
    import dataclasses
    ident = {"preset": dataclasses.asdict(pc), "dataset_hash": "x"}
    before = {"preset": {k: v for k, v in ident["preset"].items() if k != "branch_flip"}, "dataset_hash": "x"}
    assert _identity_hash(ident) == _identity_hash(before)
    on = {"preset": {**ident["preset"], "branch_flip": True}, "dataset_hash": "x"}
    assert _identity_hash(on) != _identity_hash(before)
