"""SCAPO losses and blend skinning against naive references and hand cases."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from scapo.losses.scapo_losses import (
    boundary_direction,
    cross_space_loss,
    cycle_loss,
    dir_align_loss,
    entropy,
    joint_boundary_loss,
    joint_prox_loss,
    kp_seg_loss,
    orthonormality_loss,
    seg_loss,
    shape_var_loss,
)
from scapo.nn.skinning import (
    apply,
    blend,
    bone_transforms,
    cross_space_transforms,
    joint_transform,
    skinning_weights,
)
from scapo.ops.chamfer import chamfer_distance
from scapo.ops.rigid import joint_motion
from scapo.ops.so3 import exp_so3, rotation_between
from scapo.ops.so3 import invert_transform as invert

D = torch.float64


def naive_chamfer(a, b):
    out = []
    for x, y in zip(a, b):
        d1 = np.mean([min(float(((p - q) ** 2).sum()) for q in y) for p in x])
        d2 = np.mean([min(float(((p - q) ** 2).sum()) for p in x) for q in y])
        out.append(d1 + d2)
    return torch.tensor(out, dtype=D)


def test_chamfer_matches_loop_reference_and_has_finite_gradients():
    torch.manual_seed(0)
    a, b = torch.randn(2, 30, 3, dtype=D), torch.randn(2, 20, 3, dtype=D)
    torch.testing.assert_close(chamfer_distance(a, b), naive_chamfer(a, b))
    x = torch.randn(1, 10, 3, dtype=D, requires_grad=True)
    chamfer_distance(x, x.detach().clone()).sum().backward()  # coincident points: finite gradient
    assert torch.isfinite(x.grad).all()
    assert float(chamfer_distance(a, a).max()) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError):
        chamfer_distance(a[0], b)


def test_exp_so3_matches_scipy_and_rotation_between():
    # seeded: rotation_between normalises its axis as v / (|v| + 1e-8), so a random pair that happens to be nearly
    # parallel is off by up to ~1e-7 (CI drew one once, 5.3e-7); the exactly (anti)parallel pairs are tested below
    g = torch.Generator().manual_seed(0)
    axis = torch.nn.functional.normalize(torch.randn(5, 3, dtype=D, generator=g), dim=-1)
    angle = torch.rand(5, dtype=D, generator=g) * 3
    ref = Rotation.from_rotvec((axis * angle[:, None]).numpy()).as_matrix()
    np.testing.assert_allclose(exp_so3(axis, angle).numpy(), ref, atol=1e-12)
    a = torch.nn.functional.normalize(torch.randn(6, 3, dtype=D, generator=g), dim=-1)
    b = torch.cat([torch.nn.functional.normalize(torch.randn(4, 3, dtype=D, generator=g), dim=-1), a[4:5], -a[5:6]])
    R = rotation_between(a, b)
    torch.testing.assert_close((R @ a.unsqueeze(-1)).squeeze(-1), b)
    torch.testing.assert_close(R.transpose(1, 2) @ R, torch.eye(3, dtype=D).expand(6, 3, 3))


def test_identity_joint_state_gives_identity_bone_transforms():
    axis = torch.nn.functional.normalize(torch.randn(3, 2, 3, dtype=D), dim=-1)
    pivot = torch.randn(3, 2, 3, dtype=D)
    T = bone_transforms((0, 1), ((0, 1), (0, 2)), axis, pivot, torch.zeros(3, 2, dtype=D), 3)
    torch.testing.assert_close(T, torch.eye(4, dtype=D).expand(3, 3, 4, 4))


@pytest.mark.parametrize("jt", [0, 1])
def test_joint_transform_matches_numpy_reference(jt):
    axis = torch.nn.functional.normalize(torch.tensor([[0.3, 1.0, -0.2]], dtype=D), dim=-1)
    pivot = torch.tensor([[0.1, -0.4, 0.7]], dtype=D)
    state = torch.tensor([0.8], dtype=D)
    ref = joint_motion(jt, axis[0].numpy(), pivot[0].numpy(), 0.8)
    np.testing.assert_allclose(joint_transform(jt, axis, pivot, state)[0].numpy(), ref, atol=1e-12)


def test_blended_transform_reproduces_a_known_revolute_motion_for_rigid_weights():
    torch.manual_seed(1)
    pts = torch.randn(1, 50, 3, dtype=D)
    part = (pts[..., 0] > 0).long()  # child: x > 0
    w = torch.nn.functional.one_hot(part, 2).to(D)
    axis = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=D)
    pivot = torch.tensor([[[0.0, 0.5, 0.0]]], dtype=D)
    T = bone_transforms((0,), ((0, 1),), axis, pivot, torch.tensor([[math.radians(40)]], dtype=D), 2)
    moved = blend(pts, w, T)
    M = torch.from_numpy(joint_motion(0, np.array([0, 0, 1.0]), np.array([0, 0.5, 0]), math.radians(40)))
    expect = torch.where(part.unsqueeze(-1) == 1, apply(M[None], pts), pts)
    torch.testing.assert_close(moved, expect)
    back = blend(moved, w, invert(T))  # backward deformation inverts it for rigid weights
    torch.testing.assert_close(back, pts)


def test_skinning_weights_naive_reference():
    torch.manual_seed(2)
    pts, K = torch.randn(1, 7, 3, dtype=D), torch.randn(1, 2, 3, dtype=D)
    V = torch.from_numpy(Rotation.random(2, random_state=0).as_matrix())[None]
    ls = torch.randn(1, 2, 3, dtype=D) * 0.2
    w, W = skinning_weights(pts, K, V, ls, gamma=0.5)
    for i in range(7):
        for p in range(2):
            d = pts[0, i] - K[0, p]
            Q = V[0, p].T @ torch.diag(torch.exp(-2 * ls[0, p])) @ V[0, p]
            assert float(W[0, i, p]) == pytest.approx(float(d @ Q @ d))
        e = torch.exp(-W[0, i] / 0.5)
        torch.testing.assert_close(w[0, i], e / e.sum())


def test_cross_space_transform_hand_cases():
    d = torch.tensor([[[0.0, 1.0, 0.0]]], dtype=D)
    c = torch.tensor([[[0.2, 0.0, 0.1]]], dtype=D)
    a = torch.tensor([[0.3]], dtype=D)
    T = cross_space_transforms((0,), ((0, 1),), 2, c, d, a, c, d, a)  # identical joints: identity
    torch.testing.assert_close(T, torch.eye(4, dtype=D).expand(1, 2, 4, 4))
    T = cross_space_transforms((0,), ((0, 1),), 2, c, d, a, c, d, a + 0.5)  # state difference: a rotation
    ref = joint_motion(0, d[0, 0].numpy(), c[0, 0].numpy(), 0.5)
    np.testing.assert_allclose(T[0, 1].numpy(), ref, atol=1e-12)
    c2 = c + torch.tensor([0.0, 0.3, 0.4], dtype=D)
    T = cross_space_transforms((0,), ((0, 1),), 2, c, d, a, c2, -d, a)  # frames aligned: pivot maps to pivot
    p = apply(T[:, 1], c[:, 0:1])
    dist = torch.linalg.norm(torch.cross(p[0, 0] - c2[0, 0], d[0, 0], dim=-1))
    assert float(dist) < 1e-12


def test_stage1_and_cycle_hand_cases():
    R = torch.from_numpy(Rotation.random(3, random_state=1).as_matrix())
    assert float(orthonormality_loss(R)) == pytest.approx(0.0, abs=1e-20)
    assert float(orthonormality_loss(2 * R)) == pytest.approx(3 * 9.0)  # ||4I - I||^2 = 27
    x = torch.randn(2, 10, 3, dtype=D)
    assert float(cycle_loss(x, x)) == 0.0
    assert float(cycle_loss(x, x + torch.tensor([0.1, -0.2, 0.0], dtype=D))) == pytest.approx(0.3)
    assert float(cross_space_loss(x, x, x, x)) == pytest.approx(0.0, abs=1e-12)


def test_regulariser_hand_cases():
    torch.manual_seed(3)
    pts = torch.rand(1, 200, 3, dtype=D)
    part = (pts[..., 0] > 0.5).long()
    w = torch.nn.functional.one_hot(part, 2).to(D)
    K = torch.stack([pts[0][part[0] == p].mean(0) for p in range(2)])[None]
    assert float(kp_seg_loss(pts, w, K, 0.02)) == pytest.approx(0.0, abs=1e-20)
    assert float(kp_seg_loss(pts, w, K + 0.1, 0.02)) == pytest.approx(0.03)
    # keypoints at the part centroids: the nearest keypoint mostly agrees with the one-hot weights
    assert float(seg_loss(pts, w, K)) < 0.3
    assert float(seg_loss(pts, torch.nn.functional.one_hot(((pts - K[:, 1:]) ** 2).sum(-1).lt(
        ((pts - K[:, :1]) ** 2).sum(-1)).long(), 2).to(D), K)) == 0.0
    assert float(shape_var_loss(torch.zeros(2, 5, 3))) == 0.0
    assert float(shape_var_loss(torch.full((1, 5, 3), 0.1))) == pytest.approx(1 - math.exp(-60 * 0.03))
    # a hinge along y at x = 0.5: boundary points spread along y
    soft = torch.stack([torch.sigmoid((0.5 - pts[..., 0]) * 40), torch.sigmoid((pts[..., 0] - 0.5) * 40)], -1)
    pts_line = pts.clone()
    pts_line[..., 2] *= 0.05
    direction = boundary_direction(pts_line, soft, 0, 1)
    assert abs(float(direction[0, 1])) > 0.95
    assert float(dir_align_loss(pts_line, soft, torch.tensor([[[0.0, 1.0, 0.0]]], dtype=D), (0,), ((0, 1),))) < 0.01
    assert float(dir_align_loss(pts_line, soft, torch.tensor([[[1.0, 0.0, 0.0]]], dtype=D), (0,), ((0, 1),))) > 0.9
    on = pts[:, :1]
    assert float(joint_prox_loss(pts, on, (0,))) == pytest.approx(0.0, abs=1e-12)
    assert float(joint_prox_loss(pts, on + 10.0, (0,))) == pytest.approx(1.0)
    assert float(joint_prox_loss(pts, on + 10.0, (1,))) == 0.0  # prismatic joints have no pivot
    near = torch.tensor([[[0.5, 0.5, 0.5]]], dtype=D)
    far = torch.tensor([[[0.0, 0.5, 0.5]]], dtype=D)
    assert float(joint_boundary_loss(pts, soft, near, (0,))) < float(joint_boundary_loss(pts, soft, far, (0,))) < 0
    H = entropy(torch.full((1, 1, 2), 0.5, dtype=D))
    assert float(H) == pytest.approx(math.log(2))


def test_cross_instance_alignment_is_zero_for_aligned_copies_and_grows_with_misalignment():
    from scapo.losses.scapo_losses import cross_instance_alignment_loss

    torch.manual_seed(4)
    shape = torch.rand(1, 96, 3, dtype=D)
    Q = torch.from_numpy(Rotation.random(4, random_state=2).as_matrix())
    u = torch.randn(4, 3, dtype=D)
    X = shape @ Q.transpose(1, 2) + u[:, None]  # four posed copies of one shape
    # frames that undo the poses: every canonical copy coincides -> zero
    assert float(cross_instance_alignment_loss(X, u, Q)) == pytest.approx(0.0, abs=1e-12)
    eye = torch.eye(3, dtype=D).expand(4, 3, 3)
    assert float(cross_instance_alignment_loss(X, u, eye)) > 0.01  # frames ignoring the rotation
    one = cross_instance_alignment_loss(X[:1], u[:1], Q[:1])
    assert float(one) == 0.0  # a single cloud has no partner


def test_consensus_rotation_relabels_a_frame_that_disagrees_with_the_batch():
    from scapo.losses.scapo_losses import candidate_rotations, consensus_rotation_loss

    torch.manual_seed(5)
    G = candidate_rotations(dtype=D)
    assert G.shape == (30, 3, 3)
    assert torch.allclose(G[0], torch.eye(3, dtype=D))
    assert torch.allclose(G @ G.transpose(1, 2), torch.eye(3, dtype=D).expand(30, 3, 3), atol=1e-12)
    shape = torch.rand(1, 64, 3, dtype=D) * torch.tensor([1.0, 0.5, 0.2], dtype=D)  # no symmetry
    Q = torch.from_numpy(Rotation.random(5, random_state=3).as_matrix())
    u = torch.randn(5, 3, dtype=D)
    X = shape @ Q.transpose(1, 2) + u[:, None]
    # consistent frames: nothing to relabel, and the loss is the distance of R_raw to R (zero here)
    loss, frac = consensus_rotation_loss(X, u, Q, Q, G)
    assert float(loss) == pytest.approx(0.0, abs=1e-12) and float(frac) == 0.0
    # cloud 0 canonicalised 90 degrees off (a candidate): its target is the batch's frame Q[0]
    wrong = Q.clone()
    wrong[0] = Q[0] @ G[5]
    loss, frac = consensus_rotation_loss(X, u, wrong, wrong, G)
    assert float(frac) == pytest.approx(1 / 5)
    expected = float(((wrong[0] - Q[0]) ** 2).sum()) / 5
    assert float(loss) == pytest.approx(expected, rel=1e-9)


def test_root_motion_turns_the_base_and_carries_the_chain():
    axis = torch.tensor([[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]], dtype=D)
    pivot = torch.tensor([[[0.0, 0.5, 0.0], [0.3, 0.0, 0.2]]], dtype=D)
    state = torch.tensor([[0.4, 0.3]], dtype=D)
    root = torch.tensor([-0.25], dtype=D)
    jp = ((0, 1), (1, 2))
    T = bone_transforms((0, 0), jp, axis, pivot, state, 3, root)
    T0 = bone_transforms((0, 0), jp, axis, pivot, state, 3)
    M = torch.from_numpy(joint_motion(0, np.array([0, 0, 1.0]), np.array([0, 0.5, 0]), -0.25))
    torch.testing.assert_close(T[0, 0], M)  # the base turns about the root joint
    torch.testing.assert_close(T[0, 1:], M @ T0[0, 1:])  # and the whole chain follows it
    # child of the root joint: one rotation by state + root about the same line
    ref = joint_motion(0, np.array([0, 0, 1.0]), np.array([0, 0.5, 0]), 0.4 - 0.25)
    np.testing.assert_allclose(T[0, 1].numpy(), ref, atol=1e-12)
    with pytest.raises(ValueError, match="base part"):
        bone_transforms((0,), ((1, 0),), axis[:, :1], pivot[:, :1], state[:, :1], 2, root)


def test_cross_space_transform_with_root_motion_maps_input_parts_onto_template_parts():
    torch.manual_seed(3)
    d = torch.nn.functional.normalize(torch.randn(2, 1, 3, dtype=D), dim=-1)
    c = torch.randn(2, 1, 3, dtype=D)
    a_x, a_y = torch.randn(2, 1, dtype=D), torch.randn(2, 1, dtype=D)
    b_x, b_y = torch.randn(2, dtype=D), torch.randn(2, dtype=D)
    T_x = bone_transforms((0,), ((0, 1),), d, c, a_x, 2, b_x)
    T_y = bone_transforms((0,), ((0, 1),), d, c, a_y, 2, b_y)
    T = cross_space_transforms((0,), ((0, 1),), 2, c, d, a_x, c, d, a_y, b_x, b_y)
    # same joint frame in both spaces: X -> Y is "undo the input's motion, apply the template's"
    torch.testing.assert_close(T, T_y @ invert(T_x))
    # without root states the base stays put
    T = cross_space_transforms((0,), ((0, 1),), 2, c, d, a_x, c, d, a_y)
    torch.testing.assert_close(T[:, 0], torch.eye(4, dtype=D).expand(2, 4, 4))


def test_nearest_sq_dist_gives_the_dense_mins_values_and_gradients():
    """``nearest_sq_dist`` (issue 30's speed rewrite: matches found without gradient, matched pairs recomputed)
    equals ``pairwise_sq_dist(a, b).min`` in value and in gradient, both directions, on clouds without ties."""
    from scapo.ops.chamfer import nearest_sq_dist, pairwise_sq_dist

    g = torch.Generator().manual_seed(3)
    a0, b0 = torch.rand(2, 40, 3, generator=g, dtype=D), torch.rand(2, 30, 3, generator=g, dtype=D)
    w1, w2 = torch.rand(2, 40, generator=g, dtype=D), torch.rand(2, 30, generator=g, dtype=D)
    got = []
    for fast in (False, True):
        a, b = a0.clone().requires_grad_(), b0.clone().requires_grad_()
        if fast:
            da, db = nearest_sq_dist(a, b, both=True)
            assert torch.equal(nearest_sq_dist(a, b).detach(), da.detach())
        else:
            d = pairwise_sq_dist(a, b)
            da, db = d.min(-1).values, d.min(1).values
        ((da * w1).sum() + (db * w2).sum()).backward()
        got.append((da.detach(), db.detach(), a.grad, b.grad))
    for x, y in zip(*got):
        torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12)


def test_vn_leaky_relu_is_the_papers_clipped_projection():
    """The VN leaky ReLU written as one correction along the learned direction (issue 30's speed rewrite) is
    Deng et al.'s: ``slope p + (1 - slope) (p if <p, d> >= 0 else p - <p, d> / |d|^2 d)``."""
    from scapo.nn.vn import EPS, _leaky

    g = torch.Generator().manual_seed(0)
    p, d = torch.randn(4, 5, 3, 7, generator=g, dtype=D), torch.randn(4, 5, 3, 7, generator=g, dtype=D)
    dot = (p * d).sum(2, keepdim=True)
    proj = p - dot / ((d * d).sum(2, keepdim=True) + EPS) * d
    ref = 0.2 * p + 0.8 * torch.where(dot >= 0, p, proj)
    torch.testing.assert_close(_leaky(p, d, 0.2), ref, rtol=1e-12, atol=1e-12)
    assert (dot < 0).any() and (dot >= 0).any()


def test_template_loss_compares_each_view_in_metres_and_trains_the_template():
    """``L_template``: decoded shapes that are the template in each view's own units (two views at different scales)
    give ~0; one decoded a quarter turn off gives much more; the gradient reaches the template, and the stage-1 terms
    carry the term only where ``LossConfig.template`` is on (the model then has the template parameter)."""
    from dataclasses import replace

    from scapo.losses import LossConfig, stage1_terms
    from scapo.losses.scapo_losses import template_loss
    from scapo.models.presets import PRESETS
    from scapo.models.scapo_model import SCAPOModel
    from scapo.models.train import model_config

    g = torch.Generator().manual_seed(0)
    tpl = torch.rand(200, 3, generator=g) * torch.tensor([0.4, 0.2, 0.05])  # metres
    scale = torch.tensor([0.5, 0.8])
    S = torch.stack([tpl / 0.5, tpl / 0.8])
    assert float(template_loss(S, scale, tpl)) < 1e-10
    quarter = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    S_off = torch.stack([tpl / 0.5, (tpl - tpl.mean(0)) @ quarter.T / 0.8 + tpl.mean(0) / 0.8])
    assert float(template_loss(S_off, scale, tpl)) > 1e-3
    param = torch.nn.Parameter(tpl.clone() + 0.01)
    template_loss(S, scale, param).backward()
    assert param.grad is not None and float(param.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="template_loss"):
        template_loss(S, scale[:1], tpl)
    card = {"part_names": ["a", "b"], "joint_type": [0], "joint_parts": [[0, 1]]}
    pc = PRESETS.get("test")
    on = replace(pc, losses=replace(pc.losses, template=1.0))
    model = SCAPOModel(model_config(card, on))
    assert model.template_s1.shape == (pc.template_points, 3)
    assert not hasattr(SCAPOModel(model_config(card, pc)), "template_s1")
    X = torch.randn(4, 128, 3)
    terms = stage1_terms(model, X, model.stage1(X), on.losses, scale=torch.ones(4))
    assert "template" in terms and torch.isfinite(terms["template"])
    assert "template" not in stage1_terms(model, X, model.stage1(X), LossConfig(), scale=torch.ones(4))


def test_each_loss_term_gets_the_papers_weight_in_each_stage():
    """Hand case of ``weighted_total``: every term a different value, so a weight given to the wrong term shows. The
    paper's weights (Sec. 4): stage 1 rec 1, ortho / aug_consist / can_consist 0.1 (lambda_1-3); stage 2 cycle 10,
    recon 10, kp_seg 1, seg 1, shape_var 10, dir_align 0.1, joint_prox 1, joint_boundary 3; our align term 10 (an
    addition). In stage 2 the stage-1 terms are scaled by ``stage1_in_stage2``; a switched-off term weighs 0."""
    import dataclasses

    import torch

    from scapo.losses import LossConfig, weighted_total

    paper = {"rec": 1.0, "ortho": 0.1, "aug_consist": 0.1, "can_consist": 0.1, "align": 10.0, "cycle": 10.0,
             "recon": 10.0, "kp_seg": 1.0, "seg": 1.0, "shape_var": 10.0, "dir_align": 0.1, "joint_prox": 1.0,
             "joint_boundary": 3.0}
    values = {k: float(i + 2) for i, k in enumerate(paper)}  # 2, 3, 4, ...
    terms = {k: torch.tensor(v) for k, v in values.items()}
    stage1 = ("rec", "ortho", "aug_consist", "can_consist", "align")
    cfg = LossConfig()
    s1 = {k: terms[k] for k in stage1}
    assert float(weighted_total(s1, cfg, 1)) == pytest.approx(sum(paper[k] * values[k] for k in stage1))
    assert float(weighted_total(terms, cfg, 2)) == pytest.approx(sum(paper[k] * values[k] for k in paper))
    half = dataclasses.replace(cfg, stage1_in_stage2=0.5, disabled=("seg",))
    want = sum(paper[k] * values[k] * (0.5 if k in stage1 else 1.0) for k in paper if k != "seg")
    assert float(weighted_total(terms, half, 2)) == pytest.approx(want)
    assert float(weighted_total(s1, half, 1)) == pytest.approx(sum(paper[k] * values[k] for k in stage1))
