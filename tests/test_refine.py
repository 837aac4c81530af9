"""Test-time articulated refinement: a known articulated motion is recovered from a wrong start."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from scapo.models.refine import (
    RefineConfig,
    TemplatePoser,
    posed_template,
    refine_articulation,
)
from scapo.models.scapo_model import ModelConfig
from scapo.ops.so3 import rotation_from_rotvec

CFG = ModelConfig(num_parts=2, joint_types=(0,), joint_parts=((0, 1),))


def two_slabs(n: int = 300) -> tuple[torch.Tensor, torch.Tensor]:
    """A laptop-like rest shape: a base slab (part 0) and an upright screen slab (part 1) hinged along y
    at x = 0.3, z = 0; one-hot skinning weights. Returns (points (1, 2n, 3), weights (1, 2n, 2))."""
    g = torch.Generator().manual_seed(0)
    base = torch.rand(n, 3, generator=g) * torch.tensor([0.6, 0.8, 0.05]) + torch.tensor([-0.3, -0.4, -0.05])
    screen = torch.rand(n, 3, generator=g) * torch.tensor([0.03, 0.8, 0.5]) + torch.tensor([0.27, -0.4, 0.0])
    w = torch.zeros(2 * n, 2)
    w[:n, 0], w[n:, 1] = 1.0, 1.0
    return torch.cat([base, screen])[None], w[None]


class FakeOutput(dict):
    """A slice of :class:`scapo.nn.outputs.SCAPOOutput`: its fields as attributes (and by name)."""

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None


def fake_forward(rest, w, state0, R0, t0, root0=None):
    """The slice of ``SCAPOModel.forward`` outputs that the refinement reads."""
    return FakeOutput({"enc": SimpleNamespace(R=R0, t=t0), "pivot_y": torch.tensor([[[0.3, 0.0, 0.0]]]),
            "axis_y": torch.tensor([[[0.0, 1.0, 0.0]]]), "Y_star": rest, "w_ystar": w,
            "state_x": state0, "root_x": root0})


def test_posed_template_moves_only_the_child_by_the_joint_state():
    rest, w = two_slabs()
    out = fake_forward(rest, w, None, None, None)
    eye, zero = torch.eye(3)[None], torch.zeros(1, 3)
    pts, T = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"],
                            torch.tensor([[0.0]]), None, eye, zero)
    torch.testing.assert_close(pts, rest)
    pts, T = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"],
                            torch.tensor([[np.pi / 2]]), None, eye, zero)
    n = rest.shape[1] // 2
    torch.testing.assert_close(pts[:, :n], rest[:, :n])
    # a quarter turn about +y through (0.3, 0, 0): (x, z) -> (0.3 + z, -(x - 0.3))
    ref = torch.stack([0.3 + rest[0, n:, 2], rest[0, n:, 1], -(rest[0, n:, 0] - 0.3)], -1)
    torch.testing.assert_close(pts[0, n:], ref, atol=1e-5, rtol=0)


@pytest.mark.parametrize("root", [False, True])
def test_refinement_recovers_a_known_pose_and_joint_state(root):
    rest, w = two_slabs()
    R_true = rotation_from_rotvec(torch.tensor([[0.10, -0.15, 0.05]]))
    t_true = torch.tensor([[0.05, -0.03, 0.02]])
    a_true = torch.tensor([[0.6]])
    out = fake_forward(rest, w, None, None, None)
    obs, _ = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"], a_true,
                            None, R_true, t_true)
    # the network's (wrong) answer: identity frame, half the joint state
    out = fake_forward(rest, w, torch.tensor([[0.3]]), torch.eye(3)[None], torch.zeros(1, 3),
                       torch.zeros(1) if root else None)
    r = refine_articulation(CFG, obs, out, RefineConfig(steps=200, lr=0.02, points=600))
    assert r["residual"].item() < 0.02 * r["residual_start"].item()
    # the fitted articulated pose: base frame and child frame agree with the truth
    R_base = r["R"] @ r["T"][:, 0, :3, :3]
    R_child = r["R"] @ r["T"][:, 1, :3, :3]
    child_true = R_true @ rotation_from_rotvec(torch.tensor([[0.0, 0.6, 0.0]]))
    for R, ref in ((R_base, R_true), (R_child, child_true)):
        cos = ((R.transpose(1, 2) @ ref).diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2
        angle = torch.arccos(cos.clamp(-1.0, 1.0))
        assert np.degrees(angle.item()) < 1.5
    assert r["state"].item() == pytest.approx(0.6, abs=0.03)  # the child's turn relative to the base
    torch.testing.assert_close(r["pivot"], out["pivot_y"])


def test_refinement_settings_are_checked():
    with pytest.raises(ValueError, match="steps"):
        RefineConfig(steps=-1)
    rest, w = two_slabs()
    out = fake_forward(rest, w, torch.zeros(1, 1), torch.eye(3)[None], torch.zeros(1, 3))
    with pytest.raises(ValueError, match="steps > 0"):
        refine_articulation(CFG, rest, out, RefineConfig(steps=0))


def test_refined_segmentation_follows_the_fitted_template():
    rest, w = two_slabs()
    out = fake_forward(rest, w, None, None, None)
    a_true = torch.tensor([[0.6]])
    obs, _ = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"], a_true,
                            None, torch.eye(3)[None], torch.zeros(1, 3))
    out = fake_forward(rest, w, torch.tensor([[0.3]]), torch.eye(3)[None], torch.zeros(1, 3))
    r = refine_articulation(CFG, obs, out, RefineConfig(steps=150, points=600))
    assert r["weights"].shape == (1, rest.shape[1], 2)
    truth = w.argmax(-1)  # the observation is the template itself, in the same point order
    assert (r["weights"].argmax(-1) == truth).float().mean() > 0.98


@pytest.mark.parametrize("root", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_template_poser_equals_the_reference_posed_template(root, dtype):
    """The refinement's fast poser against posed_template (bone_transforms + blend) on a 4-part tree with
    revolute and prismatic joints, a chain (part 3 hangs from part 2) and soft weights, batch 3."""
    g = torch.Generator().manual_seed(1)
    B, M, P = 3, 50, 4
    jt, jp = (0, 1, 0), ((0, 1), (0, 2), (2, 3))
    rest = torch.randn(B, M, 3, generator=g, dtype=dtype)
    w = torch.softmax(torch.randn(B, M, P, generator=g, dtype=dtype) * 3, -1)
    axis = torch.nn.functional.normalize(torch.randn(B, 3, 3, generator=g, dtype=dtype), dim=-1)
    pivot = torch.randn(B, 3, 3, generator=g, dtype=dtype) * 0.3
    R0 = rotation_from_rotvec(torch.randn(B, 3, generator=g, dtype=dtype))
    t0 = torch.randn(B, 3, generator=g, dtype=dtype)
    theta = torch.randn(B, 6 + 3 + int(root), generator=g, dtype=dtype) * 0.5
    theta[0, :3] = 0.0  # the smooth limit at a zero rotation vector
    poser = TemplatePoser(jt, jp, P, rest, w, pivot, axis, R0, t0, root)
    pts, T, R, t = poser(theta)
    R_ref = R0 @ rotation_from_rotvec(theta[:, :3])
    ref, T_ref = posed_template(jt, jp, P, rest, w, pivot, axis, theta[:, 6:9], theta[:, 9] if root else None,
                                R_ref, t0 + theta[:, 3:6])
    tol = {"atol": 1e-5, "rtol": 1e-5} if dtype == torch.float32 else {"atol": 1e-12, "rtol": 1e-12}
    torch.testing.assert_close(pts, ref, **tol)
    torch.testing.assert_close(T, T_ref, **tol)
    torch.testing.assert_close(R, R_ref, **tol)
    torch.testing.assert_close(t, t0 + theta[:, 3:6], **tol)
    # its gradient with respect to theta matches the reference's (the refinement descends on it)
    th = theta.clone().requires_grad_(True)
    poser(th)[0].square().sum().backward()
    th_ref = theta.clone().requires_grad_(True)
    posed_template(jt, jp, P, rest, w, pivot, axis, th_ref[:, 6:9], th_ref[:, 9] if root else None,
                   R0 @ rotation_from_rotvec(th_ref[:, :3]), t0 + th_ref[:, 3:6])[0].square().sum().backward()
    torch.testing.assert_close(th.grad, th_ref.grad, **({"atol": 1e-3, "rtol": 1e-4} if dtype == torch.float32
                                                         else {"atol": 1e-9, "rtol": 1e-9}))


def test_octahedral_rotations_are_the_24_proper_cube_rotations():
    from scapo.models.refine import octahedral_rotations
    C = octahedral_rotations(torch.float64)
    assert C.shape == (24, 3, 3)
    torch.testing.assert_close(C[0], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(C @ C.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(24, 3, 3))
    torch.testing.assert_close(torch.linalg.det(C), torch.ones(24, dtype=torch.float64))
    assert len({tuple(m.flatten().tolist()) for m in C}) == 24
    # closed under composition: a group
    keys = {tuple(m.flatten().tolist()) for m in C}
    assert all(tuple((a @ b).flatten().tolist()) in keys for a in C for b in C)


def _quarter_turned_start(rest, w):
    """Observation: the slabs at joint state 0.6, seen in the identity frame; the network's start is off
    by a quarter turn about x (one of the cube rotations) - a frame error a local fit does not undo."""
    out = fake_forward(rest, w, None, None, None)
    obs, _ = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"],
                            torch.tensor([[0.6]]), None, torch.eye(3)[None], torch.zeros(1, 3))
    R_bad = rotation_from_rotvec(torch.tensor([[np.pi / 2, 0.0, 0.0]]))
    return obs, fake_forward(rest, w, torch.tensor([[0.5]]), R_bad, torch.zeros(1, 3))


def test_octahedral_starts_recover_a_frame_that_is_a_quarter_turn_off():
    rest, w = two_slabs()
    obs, out = _quarter_turned_start(rest, w)
    one = refine_articulation(CFG, obs, out, RefineConfig(steps=40, lr=0.05, points=300))
    multi = refine_articulation(CFG, obs, out, RefineConfig(steps=40, lr=0.05, points=300, starts="octahedral"))
    assert multi["start"].item() != 0  # an alternative start won
    assert multi["residual"].item() < 0.3 * one["residual"].item()
    R_base = multi["R"] @ multi["T"][:, 0, :3, :3]
    angle = torch.arccos((((R_base.diagonal(dim1=1, dim2=2).sum(-1)) - 1) / 2).clamp(-1, 1))
    assert np.degrees(angle.item()) < 3.0
    assert multi["weights"].shape == (1, obs.shape[1], 2)


def test_octahedral_starts_keep_the_network_start_unless_the_margin_is_beaten():
    rest, w = two_slabs()
    out = fake_forward(rest, w, None, None, None)
    obs, _ = posed_template(CFG.joint_types, CFG.joint_parts, 2, rest, w, out["pivot_y"], out["axis_y"],
                            torch.tensor([[0.6]]), None, torch.eye(3)[None], torch.zeros(1, 3))
    # a good network start (small error): its fit is kept, identical to the single-start refinement
    out = fake_forward(rest, w, torch.tensor([[0.5]]), rotation_from_rotvec(torch.tensor([[0.05, 0.0, 0.0]])),
                       torch.zeros(1, 3))
    rc = dict(steps=30, lr=0.05, points=300)
    one = refine_articulation(CFG, obs, out, RefineConfig(**rc))
    multi = refine_articulation(CFG, obs, out, RefineConfig(**rc, starts="octahedral"))
    assert multi["start"].item() == 0
    torch.testing.assert_close(multi["R"], one["R"])
    torch.testing.assert_close(multi["state"], one["state"])
    # batch of two views: each picks on its own
    obs2, bad = _quarter_turned_start(rest, w)
    both = {k: (torch.cat([out[k], bad[k]]) if torch.is_tensor(out[k]) and k not in ("pivot_y", "axis_y", "Y_star",
                                                                                       "w_ystar") else out[k])
            for k in out}
    both.update({k: out[k].expand(2, *out[k].shape[1:]) for k in ("pivot_y", "axis_y", "Y_star", "w_ystar")})
    both["enc"] = SimpleNamespace(R=torch.cat([out["enc"].R, bad["enc"].R]), t=torch.zeros(2, 3))
    r = refine_articulation(CFG, torch.cat([obs, obs2]), FakeOutput(both), RefineConfig(**rc, starts="octahedral"))
    assert r["start"][0].item() == 0 and r["start"][1].item() != 0


def test_unknown_refinement_starts_are_refused():
    with pytest.raises(ValueError, match="unknown refinement starts 'cube'"):
        RefineConfig(steps=5, starts="cube")
    with pytest.raises(ValueError, match="margin"):
        RefineConfig(steps=5, starts="octahedral", margin=1.5)


def test_upright_direction_finds_the_majority_branch_of_a_two_fold_ambiguity():
    """Frames of views taken around a vertical axis keep one camera direction fixed in the canonical
    frame; 40 % of the frames took the half-turned branch (a symmetric shape), the mode is the other."""
    from scapo.models.refine import camera_direction_in_frame, upright_direction
    from scapo.ops.groups import random_rotation

    g = torch.Generator().manual_seed(0)
    A = random_rotation(1, generator=g)[0].double()  # canonical -> camera of the first view
    phi = torch.linspace(0, 2 * torch.pi, 50, dtype=torch.float64)
    c, s = torch.cos(phi), torch.sin(phi)
    Rz = torch.zeros(50, 3, 3, dtype=torch.float64)
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    R = A @ Rz  # turning about the canonical z axis: camera direction A e_z stays e_z in every frame
    F = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))  # half turn about x
    R[30:] = R[30:] @ F
    up, support = upright_direction(R)
    d, v = up[0], up[1]
    sign = torch.sign(d[2])
    assert torch.allclose(sign * d, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-4)
    assert torch.allclose(sign * v, A[:, 2], atol=1e-4)
    assert abs(support - 0.6) < 1e-9
    u = camera_direction_in_frame(R, v)
    assert ((u @ d) > 0.99).sum() == 30 and ((u @ d) < -0.99).sum() == 20
    with pytest.raises(ValueError):
        upright_direction(torch.zeros(0, 3, 3))


def test_stage2_starts_setting_option_and_preset(tmp_path):
    """``RefineConfig.stage2_starts`` (the hypothesis set of stage 2's first frame): the known sets, the half turns'
    group, the method option ("off") as predictions record it, and ``cpu-laptop`` choosing the cube group."""
    import dataclasses
    import json

    from scapo.errors import ConfigError
    from scapo.methods.scapo import SCAPOOptions, inference_settings
    from scapo.models.presets import get_preset
    from scapo.ops.groups import half_turns

    assert RefineConfig().stage2_starts == "off" and RefineConfig(stage2_starts="D2").stage2_starts == "D2"
    for bad in ("octahedral", "", "none"):  # one spelling of off
        with pytest.raises(ValueError, match="stage2_starts"):
            RefineConfig(stage2_starts=bad)
    H = half_turns()
    assert H.shape == (4, 3, 3) and np.array_equal(H[0], np.eye(3)) and not H.flags.writeable
    assert np.allclose(np.linalg.det(H), 1.0) and np.allclose(H @ H, np.eye(3))  # proper half turns
    assert get_preset("cpu-laptop").refine.stage2_starts == "O"
    assert get_preset("cpu-laptop/epochs-5-4").refine.stage2_starts == "O"  # a budget's schedule keeps it
    assert get_preset("cpu-eyeglasses").refine.stage2_starts == "D2" and get_preset("cpu").refine.stage2_starts == "off"
    assert get_preset("cpu-eyeglasses/epochs-6-5").refine.stage2_starts == "D2"
    with pytest.raises(ConfigError, match="stage2_starts"):
        SCAPOOptions(run=str(tmp_path), stage2_starts="X")
    run = tmp_path / "run"
    run.mkdir()
    stored = dataclasses.asdict(get_preset("cpu-laptop/epochs-5-4"))
    (run / "run.json").write_text(json.dumps({"preset": stored}))
    assert inference_settings(run, {"refine_steps": 0})["stage2_starts"] == "O"
    assert inference_settings(run, {"refine_steps": 0, "stage2_starts": "off"})["stage2_starts"] == "off"
    # the setting is read back from the run, never from the preset's current definition; an old run's "" is "off"
    (run / "run.json").write_text(json.dumps({"preset": {**stored, "refine": {**stored["refine"], "stage2_starts": ""}}}))
    assert inference_settings(run, {})["stage2_starts"] == "off" and get_preset("cpu-laptop").refine.stage2_starts == "O"
    (run / "run.json").write_text(json.dumps({"preset": {**stored, "refine": {**stored["refine"], "stage2_starts": "T"}}}))
    assert inference_settings(run, {})["stage2_starts"] == "T"
    from scapo.methods.registry import validate_options

    assert validate_options("scapo", {"stage2_starts": "off"})["stage2_starts"] == "off"  # "none" reads as no value
    assert inference_settings(run, {"stage2_starts": "D2"})["stage2_starts"] == "D2"
