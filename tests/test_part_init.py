"""Data-driven stage-2 initialisation (scapo.models.part_init) on synthetic hinged plates."""

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from scapo.losses import LossConfig, stage2_terms
from scapo.models import part_init as PI
from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.nn.encoder import EncoderConfig
from scapo.ops.so3 import exp_so3

HINGE = torch.tensor([0.0, 0.0, 1.0])


def hinged_plates(B: int = 16, n: int = 160, seed: int = 0):
    """Laptop-like clouds in a bisector frame: a base plate (x in [0, .4], y = 0) and a screen plate
    hinged on the z axis (width 1.2 along z, wider than deep, so k-means cuts across the hinge),
    opened by 40..160 deg; each cloud rotated by minus half its opening about z (the frame of a
    whole-object canonicaliser). Returns clouds (B, n, 3), labels (B, n) (0 base, 1 screen)."""
    g = torch.Generator().manual_seed(seed)
    clouds, labels = [], []
    for _ in range(B):
        theta = math.radians(40 + 120 * float(torch.rand(1, generator=g)))
        lab = (torch.rand(n, generator=g) < 0.5).long()
        r = 0.4 * torch.rand(n, generator=g)
        z = 1.2 * torch.rand(n, generator=g) - 0.6
        ang = torch.where(lab == 1, torch.tensor(theta), torch.tensor(0.0))
        pts = torch.stack([r * torch.cos(ang), r * torch.sin(ang), z], -1)
        pts = pts + 0.005 * torch.randn(n, 3, generator=g)
        pts = pts @ exp_so3(HINGE, torch.tensor(-theta / 2)).T
        clouds.append(pts)
        labels.append(lab)
    return torch.stack(clouds), torch.stack(labels)


def best_iou(pred: torch.Tensor, gt: torch.Tensor) -> float:
    ious = []
    for perm in ((0, 1), (1, 0)):
        v = [((pred == perm[p]) & (gt == p)).sum() / ((pred == perm[p]) | (gt == p)).sum() for p in (0, 1)]
        ious.append(float(torch.stack(v).mean()))
    return max(ious)


def test_kabsch_recovers_a_rigid_transform():
    g = torch.Generator().manual_seed(1)
    src = torch.randn(3, 50, 3, generator=g, dtype=torch.float64)
    R = torch.from_numpy(Rotation.random(3, random_state=2).as_matrix())
    t = torch.randn(3, 3, generator=g, dtype=torch.float64)
    dst = src @ R.transpose(1, 2) + t[:, None]
    R_est, t_est = PI.kabsch(src, dst, torch.ones(3, 50, dtype=torch.float64))
    assert torch.allclose(R_est, R, atol=1e-9) and torch.allclose(t_est, t, atol=1e-9)


def test_true_parts_register_rigidly_and_a_cut_across_the_hinge_does_not():
    X, lab = hinged_plates(B=8, n=512)
    A, B, la, lb = X[:4], X[4:], lab[:4], lab[4:]
    good = PI.part_rigidity_residual(A, B, la, lb, 2)
    cross_a, cross_b = (A[..., 2] > 0).long(), (B[..., 2] > 0).long()  # left/right halves
    bad = PI.part_rigidity_residual(A, B, cross_a, cross_b, 2)
    # the true parts leave only the sampling floor (nearest-neighbour spacing)
    assert (good <= bad).all() and good.mean() < 0.5 * bad.mean(), (good, bad)


def test_initial_split_finds_the_moving_parts_where_kmeans_cuts_across_the_hinge():
    X, lab = hinged_plates()
    union = X.reshape(-1, 3)[::8]
    km = PI.kmeans(union, 2, starts=8, generator=torch.Generator().manual_seed(0))[0]
    km_lab = PI.pairwise_sq_dist(X, km.expand(len(X), 2, 3)).argmin(-1)
    assert best_iou(km_lab, lab) < 0.6  # the k-means attractor the initialisation avoids
    K, scores = PI.initial_split(X, union, 2, seed=0, directions=24, starts=8)
    assert K.shape == (2, 3) and torch.isfinite(scores).all()
    pred = PI.pairwise_sq_dist(X, K.expand(len(X), 2, 3)).argmin(-1)
    assert best_iou(pred, lab) > 0.8


def test_axis_from_motions_recovers_revolute_and_prismatic_axes():
    axis = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    axis = axis / axis.norm()
    angles = torch.linspace(-1.2, 1.2, 9, dtype=torch.float64)
    R = exp_so3(axis.expand(9, 3), angles)
    est = PI.axis_from_motions(R, torch.zeros(9, 3, dtype=torch.float64), 0)
    assert abs(float(est @ axis)) == pytest.approx(1.0, abs=1e-9)
    est = PI.axis_from_motions(torch.eye(3, dtype=torch.float64).expand(9, 3, 3), angles[:, None] * axis, 1)
    assert abs(float(est @ axis)) == pytest.approx(1.0, abs=1e-9)
    assert PI.axis_from_motions(R[4:5], torch.zeros(1, 3, dtype=torch.float64), 0) is None  # too few


def test_estimate_axes_finds_the_hinge_of_hinged_plates():
    X, lab = hinged_plates()
    K = torch.stack([X[lab == 0].mean(0), X[lab == 1].mean(0)])
    (axis,) = PI.estimate_axes(X, K, (0,), ((0, 1),), generator=torch.Generator().manual_seed(0))
    assert math.degrees(math.acos(min(1.0, abs(float(axis @ HINGE))))) < 5.0


def test_medoid_and_part_centroids():
    g = torch.arange(5, dtype=torch.float32) * 0.5
    grid = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    shifts = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [-0.1, 0, 0], [0, 0.1, 0], [0, -0.1, 0]])
    clouds = torch.stack([grid + s for s in shifts[[1, 3, 0, 2, 4]]])
    assert PI.medoid(clouds) == 2
    K = torch.tensor([[-1.0, 0, 0], [1.0, 0, 0], [50.0, 0, 0]])
    pts = torch.tensor([[-2.0, 0, 0], [-1.0, 1, 0], [2.0, 0, 0]])
    C = PI.part_centroids(pts, K)
    assert torch.allclose(C[0], torch.tensor([-1.5, 0.5, 0])) and torch.allclose(C[1], pts[2])
    assert torch.equal(C[2], K[2])  # no points: unchanged


def test_initial_split_rejects_bad_input():
    with pytest.raises(ValueError, match="two parts"):
        PI.initial_split(torch.zeros(4, 16, 3), torch.zeros(16, 3), 1)
    with pytest.raises(ValueError, match="two clouds"):
        PI.score_keypoints(torch.zeros(1, 16, 3), torch.zeros(2, 2, 3))


def test_seg_loss_shapes_bones_without_moving_their_centres():
    cfg = ModelConfig(num_parts=2, joint_types=(0,), joint_parts=((0, 1),),
                      encoder=EncoderConfig(k=4, rot_channels=(8,), trans_channels=(4,), code_dim=8,
                                            decoder_hidden=(16, 16), decoder_points=32), template_points=32)
    torch.manual_seed(0)
    model = SCAPOModel(cfg)
    X = torch.from_numpy(np.random.default_rng(0).normal(size=(2, 48, 3))).float()
    out = model(X, 2)
    for fixed, centre_grad in ((True, False), (False, True)):
        terms = stage2_terms(model, X, out, LossConfig(seg_fixed_centres=fixed))
        gK, gs = torch.autograd.grad(terms["seg"], [out["K"], out["log_scale"]], retain_graph=True, allow_unused=True)
        moved = gK is not None and float(gK.abs().max()) > 0
        assert moved == centre_grad
        assert gs is not None and float(gs.abs().max()) > 0


def _bench_script(name: str = "split_init_diagnosis"):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def folding_glasses(B: int = 24, n: int = 300, seed: int = 0):
    """Eyeglasses-like clouds in the object frame: a front bar along y (|y| <= 0.5) and two temple bars hinged at its
    ends about z, each opened by its own angle in 0..90 deg (0: folded behind the front, along -+y). Returns clouds
    (B, n, 3) and labels (B, n): 0 front (half the points), 1 and 2 the temples."""
    g = torch.Generator().manual_seed(seed)
    clouds, labels = [], []
    for _ in range(B):
        lab = torch.cat([torch.zeros(n // 2), torch.ones(n // 4), torch.full((n - n // 2 - n // 4,), 2.0)]).long()
        s = torch.rand(n, generator=g)
        pts = torch.stack([0.01 * torch.randn(n, generator=g), s - 0.5, 0.02 * torch.randn(n, generator=g)], 1)
        for part, side in ((1, 1.0), (2, -1.0)):
            m = lab == part
            ang = math.radians(90 * float(torch.rand(1, generator=g)))
            u = 0.9 * s[m]  # along the temple from its hinge
            d = torch.tensor([math.sin(ang), -side * math.cos(ang), 0.0])  # folded: towards the centre; open: +x
            pts[m] = torch.tensor([0.03, side * 0.5, 0.0]) + u[:, None] * d + 0.01 * torch.randn(int(m.sum()), 3,
                                                                                                 generator=g)
        clouds.append(pts)
        labels.append(lab)
    return torch.stack(clouds), torch.stack(labels)


def test_the_split_diagnosis_scores_a_split_against_the_parts_under_one_slot_assignment():
    mod = _bench_script()
    X, lab = folding_glasses()
    assert mod.split_miou(lab, lab, 3) == pytest.approx(1.0)
    assert mod.split_miou(lab, (lab + 1) % 3, 3) == pytest.approx(1.0)  # slots renamed: the same split
    assert mod.split_miou(lab, torch.zeros_like(lab), 3) < 0.4
    # per-cloud bones follow each cloud's temples; one static bone per part cannot (the temples fold)
    per = [mod.gaussian_bones(X[b], lab[b], 3) for b in range(len(X))]
    Kp, Vp, Lp = (torch.stack(t) for t in zip(*per))
    Ks, Vs, Ls = mod.gaussian_bones(X.reshape(-1, 3), lab.reshape(-1), 3)
    per_cloud = mod.split_miou(lab, mod.bone_labels(X, Kp, Vp, Lp), 3)
    static = mod.split_miou(lab, mod.bone_labels(X, Ks[None], Vs[None], Ls[None]), 3)
    assert per_cloud > 0.95 and static < per_cloud - 0.1


def test_the_split_diagnosis_refuses_a_missing_dataset(tmp_path, capsys):
    mod = _bench_script()
    assert mod.main(["--data", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def folding_bars(B: int = 24, n: int = 240, seed: int = 0):
    """Eyeglasses-like clouds in the front's frame: a front bar along y (part 0) and a thin temple (part 1, a bar of
    near-square section) hinged at its end about z, folded by 0..90 deg. Returns clouds (B, n, 3), labels (B, n)."""
    g = torch.Generator().manual_seed(seed)
    clouds, labels = [], []
    for _ in range(B):
        theta = math.radians(90 * float(torch.rand(1, generator=g)))
        lab = (torch.rand(n, generator=g) < 0.4).long()
        s = torch.rand(n, generator=g)
        sec = 0.02 * (torch.rand(n, 2, generator=g) - 0.5)
        front = torch.stack([sec[:, 0], 1.0 * s - 0.5, sec[:, 1]], -1)
        along = 0.8 * s  # the temple runs back along -x from the hinge at y = 0.5, turned by theta about z
        temple = torch.stack([-along * math.cos(theta), 0.5 - along * math.sin(theta), sec[:, 1]], -1)
        temple = temple + torch.stack([sec[:, 0], torch.zeros(n), torch.zeros(n)], -1)
        clouds.append(torch.where(lab[:, None] == 1, temple, front))
        labels.append(lab)
    return torch.stack(clouds), torch.stack(labels)


def test_axis_from_turns_finds_the_hinge_of_folding_bars_and_of_hinged_plates():
    for X, lab in (folding_bars(), hinged_plates()):
        axis = PI.axis_from_turns(X, lab, child=1)
        assert math.degrees(math.acos(min(1.0, abs(float(axis @ HINGE))))) < 5.0
    X, lab = folding_bars()
    K = torch.stack([X[lab == 0].mean(0), X[lab == 1].mean(0)])
    (moved,) = PI.estimate_axes(X, K, (0,), ((0, 1),), generator=torch.Generator().manual_seed(0))
    assert abs(float(moved @ HINGE)) < math.cos(math.radians(45.0))  # registration reads the bar's roll as motion
    assert PI.axis_from_turns(X[:2], lab[:2], child=1) is None  # fewer than three clouds show the child
    assert PI.axis_from_turns(X, torch.zeros_like(lab), child=1) is None  # no cloud shows it


def test_estimate_axes_turn_keeps_the_fallback_for_prismatic_joints_and_unseen_children():
    X, lab = folding_bars()
    fallback = [torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0])]
    axes = PI.estimate_axes_turn(X, lab, (1, 0), ((0, 1), (0, 2)), fallback)
    assert torch.equal(axes[0], fallback[0]) and torch.equal(axes[1], fallback[1])  # prismatic; child 2 unseen
    (axis,) = PI.estimate_axes_turn(X, lab, (0,), ((0, 1),), [None])
    assert abs(float(axis @ HINGE)) > math.cos(math.radians(5.0))


def test_the_axis_diagnosis_measures_sign_free_angles_and_refuses_bad_input(tmp_path, capsys):
    mod = _bench_script("axis_init_diagnosis")
    assert mod.angle_deg(-HINGE, HINGE) == pytest.approx(0.0, abs=1e-6)
    assert mod.angle_deg(torch.tensor([1.0, 0.0, 1.0]), HINGE) == pytest.approx(45.0)
    assert math.isnan(mod.angle_deg(None, HINGE))
    # on folding bars the L_dir-align target under the true split is not the hinge (the boundary is a small blob)
    X, lab = folding_bars()
    target, elongation = mod.dir_align_targets(X, lab, 2, 0, 1)
    assert target.shape == (len(X), 3) and elongation.shape == (len(X),)
    assert mod.main(["--data", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert mod.main(["--data", str(tmp_path), "--out", str(tmp_path / "o"), "--clouds", "2"]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def _miou(pred: torch.Tensor, gt: torch.Tensor, parts: int) -> float:
    import itertools

    return max(float(np.mean([float(((pred == perm[p]) & (gt == p)).sum()) / max(1, int(((pred == perm[p]) |
                                                                                           (gt == p)).sum()))
                              for p in range(parts)])) for perm in itertools.permutations(range(parts)))


def test_fit_template_parts_draws_temples_that_no_keypoint_cells_draw():
    """``split_init="fit"``: the template fitted part by part to the clouds finds the parts that move as one body; the
    Voronoi cells of the true parts' own centroids cut the front's ends off to the temples."""
    X, lab = folding_glasses(B=16, n=120)
    X = X - X.mean(1, keepdim=True)
    T, Tl = X[0], lab[0]
    K = torch.stack([T[Tl == p].mean(0) for p in range(3)])
    cells = PI.nearest_keypoint(T, K)
    labels, cloud_labels = PI.fit_template_parts(T, X, cells, 3)
    assert _miou(cells, Tl, 3) < 0.75 and _miou(labels, Tl, 3) > _miou(cells, Tl, 3) + 0.08
    assert labels.shape == Tl.shape and cloud_labels.shape == lab.shape and int(cloud_labels.max()) < 3
    # the choice keeps the keypoint split where it is already the parts (hinged plates) and takes a fit where the
    # fit moves more rigidly (the glasses); the base comes first after renumbering
    found = PI.choose_split(X, T, K, starts=2)
    assert found["source"] == "fit" and found["scores"][found["chosen"]] < found["scores"][0]
    assert _miou(found["template_labels"], Tl, 3) > 0.8
    perm, C = PI.base_first_labels(T, found["template_labels"], 3)
    front = int(torch.mode(perm[found["template_labels"]][Tl == 0]).values)
    assert front == 0 and torch.allclose(C[0], T[perm[found["template_labels"]] == 0].mean(0))
    # a template with both temples shut and stacked behind the front: the temples' centroids lie nearer each other
    # than the front's, so the hub of the centroids would be a temple; the largest part (the front) comes first
    n = 200
    s = torch.linspace(-0.5, 0.5, n)
    front = torch.stack([torch.zeros(n), s, torch.zeros(n)], 1)
    shut = [torch.stack([torch.full((n // 4,), x), torch.linspace(-0.45, 0.45, n // 4), torch.full((n // 4,), 0.05)],
                        1) for x in (0.04, 0.05)]
    folded, flab = torch.cat([shut[0], front, shut[1]]), torch.cat([torch.zeros(n // 4), torch.ones(n),
                                                                   torch.full((n // 4,), 2.0)]).long()
    Cf = torch.stack([folded[flab == p].mean(0) for p in range(3)])
    assert PI.base_first_order(Cf)[0] != 1  # the centroids' hub is a shut temple
    perm, C = PI.base_first_labels(folded, flab, 3)
    assert perm.tolist() == [1, 0, 2] and torch.allclose(C[0], front.mean(0))
    two, _ = PI.base_first_labels(folded[flab > 0], flab[flab > 0] - 1, 2)
    assert two.tolist() == [0, 1]  # two parts keep their order
    Xp, lp = hinged_plates(B=12, n=100)
    Kp = torch.stack([Xp[0][lp[0] == p].mean(0) for p in range(2)])
    plates = PI.choose_split(Xp, Xp[0], Kp, starts=2, pairs=48)
    assert _miou(plates["template_labels"], lp[0], 2) > 0.85
    with pytest.raises(ValueError, match="two clouds"):
        PI.choose_split(X[:1], T, K)


def test_split_init_fitted_takes_the_most_rigid_fit_even_where_the_keypoint_split_scores_as_well():
    """``TrainConfig.split_init = "fitted"`` (``choose_split(keypoint_split=False)``): clouds that never move make
    every split perfectly rigid (all scores 0); "fit" keeps the keypoint split (scored first), "fitted" takes a fit."""
    from scapo.models.presets import get_preset

    Xp, lp = hinged_plates(B=12, n=100)
    still = Xp[:1].expand(6, -1, -1).contiguous()
    Kp = torch.stack([still[0][lp[0] == p].mean(0) for p in range(2)])
    fit = PI.choose_split(still, still[0], Kp, starts=2, pairs=16)
    fitted = PI.choose_split(still, still[0], Kp, starts=2, pairs=16, keypoint_split=False)
    assert max(fit["scores"]) < 1e-8 and fit["source"] == "keypoints" and fit["chosen"] == 0
    assert fitted["source"] == "fit" and fitted["chosen"] >= 1 and fitted["scores"] == fit["scores"]
    assert fitted["scores"][fitted["chosen"]] <= min(fitted["scores"][1:]) + PI.SPLIT_TIE  # ties: the earliest
    assert fitted["chosen"] == 1  # every fit ties here
    assert get_preset("cpu/split-fit/split-fitted").split_init == "fitted"
    assert get_preset("cpu-eyeglasses/split-fitted").split_labels


def test_set_partitions_count_and_cover_every_grouping_once():
    """The groupings of ``items`` clusters into ``blocks`` parts are the Stirling numbers of the second kind, each a
    restricted growth string (groups numbered by first appearance), none repeated, every group used."""
    assert [len(PI.set_partitions(n, k)) for n, k in ((6, 3), (6, 2), (7, 3), (4, 4), (3, 1))] == [90, 31, 301, 1, 1]
    assert PI.set_partitions(3, 2) == [(0, 0, 1), (0, 1, 0), (0, 1, 1)]
    groups = PI.set_partitions(5, 3)
    assert len(set(groups)) == len(groups) == 25
    assert all(set(g) == {0, 1, 2} and g[0] == 0 and all(g[i] <= max(g[:i]) + 1 for i in range(1, 5)) for g in groups)
    assert PI.set_partitions(2, 3) == [] and PI.set_partitions(3, 0) == []


def test_overseg_starts_let_the_split_fit_find_temples_that_its_keypoint_start_misses():
    """``TrainConfig.split_overseg``: with only the fit from a bad keypoint start (three keypoints on the front, no
    random starts), the folding glasses' split stays wrong (mean IoU 0.48); the groupings of four template clusters
    add starts whose fits come near the front and the two temples (0.80), and one of them wins the rigidity score.
    Bad cluster counts are refused."""
    from scapo.errors import ConfigError
    from scapo.models.presets import get_preset

    X, lab = folding_glasses(B=8, n=120)
    X = X - X.mean(1, keepdim=True)
    T, Tl = X[0], lab[0]
    front = T[Tl == 0]
    K = front[torch.argsort(front[:, 1])[torch.tensor([5, 30, 55])]]  # three points along the front
    starts = PI.overseg_starts(T, 3, 6, seed=0)
    assert len(starts) == 90 and all(s.shape == Tl.shape and set(s.tolist()) == {0, 1, 2} for s in starts)
    without = PI.choose_split(X, T, K, starts=0, pairs=32, keypoint_split=False)
    found = PI.choose_split(X, T, K, starts=0, pairs=32, keypoint_split=False, overseg=4)
    assert len(without["scores"]) == 2 and len(found["scores"]) > 2 and found["scores"][:2] == without["scores"]
    assert _miou(without["template_labels"], Tl, 3) < 0.6 and _miou(without["cloud_labels"], lab, 3) < 0.5
    assert found["chosen"] >= 2 and found["scores"][found["chosen"]] < min(without["scores"][1:])
    assert _miou(found["template_labels"], Tl, 3) > 0.75 and _miou(found["cloud_labels"], lab, 3) > 0.6
    with pytest.raises(ValueError, match="clusters"):
        PI.overseg_starts(T, 3, 2)
    with pytest.raises(ValueError, match="clusters"):
        PI.choose_split(X, T, K, overseg=PI.MAX_OVERSEG_CLUSTERS + 1)
    assert get_preset("cpu-eyeglasses/split-overseg").split_overseg == 6
    with pytest.raises(ConfigError, match="split_overseg"):
        dataclasses.replace(get_preset("cpu-eyeglasses"), split_overseg=9)
    with pytest.raises(ConfigError, match="split_init 'fit' or 'fitted' too"):
        get_preset("cpu/split-overseg")
    from scapo.models.train import _check

    with pytest.raises(ConfigError, match="cannot be grouped into the 3 parts of eyeglasses"):
        _check(dataclasses.replace(get_preset("cpu-eyeglasses"), split_overseg=2),
               {"part_names": ["frame", "left_temple", "right_temple"], "category": "eyeglasses"}, 100)
