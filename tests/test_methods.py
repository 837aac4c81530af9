"""Every registered method end to end, the registry, the learned-baseline harness, and the geometry
each method rests on."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from scapo.cli.main import main
from scapo.errors import ConfigError, PredictionError, TrainingError
from scapo.eval import evaluate
from scapo.methods import METHODS, describe, method_of_run, run_method, train_method, validate_options
from scapo.ops.align import ransac_umeyama
from scapo.ops.chamfer import trimmed_one_sided_chamfer
from scapo.ops.groups import GROUP_ORDERS, octahedral_rotations, rotation_group
from scapo.ops.rigid import as_transform, joint_motion
from scapo.ops.sampling import farthest_point_sample

ALL = METHODS.names()  # every registered method: a new one is covered without an edit here
#: the learned baselines (registered through scapo.methods.learned.register_learned)
LEARNED = [n for n in ALL if getattr(METHODS.get(n).factory, "spec", None) is not None]
PAPER = ["icp", "npcs", "eap", "op-align", "scapo"]


def test_registry_has_the_five_methods_with_their_marks(capsys):
    assert set(PAPER) <= set(METHODS.names()) and set(LEARNED) >= {"npcs", "eap", "op-align"}
    marks = {n: METHODS.get(n).marks() for n in PAPER}
    assert marks == {"icp": "-S-", "npcs": "PSJ", "eap": "---", "op-align": "---", "scapo": "---"}
    assert {n for n in PAPER if METHODS.get(n).needs_alignment} == {"eap", "op-align", "scapo"}
    assert all("test" in METHODS.get(n).presets for n in ALL if METHODS.get(n).trained)  # the quick run
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for n in ALL:
        line = next(ln for ln in out.splitlines() if ln.split()[:1] == [n])
        assert METHODS.get(n).marks() in line and METHODS.get(n).display in line
    assert describe("scapo-no-refine") == ("SCAPO (ours, no refinement)", dict(METHODS.get("scapo").supervision))
    assert describe("op-align")[0] == "OP-Align-style" and describe("someone-else") is None


def test_options_are_validated_against_each_methods_dataclass():
    with pytest.raises(ConfigError, match="unknown option 'iters' for method 'npcs'; valid options: run, device"):
        validate_options("npcs", {"iters": "3"})
    assert validate_options("eap", {"batch_size": "8", "cross_category": "yes"}) == {"batch_size": 8,
                                                                                    "cross_category": True}
    with pytest.raises(ConfigError, match="batch_size must be >= 1"):
        METHODS.get("op-align").factory(run="x", batch_size=0)
    with pytest.raises(ConfigError, match="needs a trained run"):
        METHODS.get("eap").factory()
    with pytest.raises(ConfigError, match="not trained"):
        train_method("icp", "d", "r")


@pytest.fixture(scope="module")
def trained_runs(trained_test_runs):
    """One run of every trained method (its ``test`` preset) on the small laptop dataset (conftest.py)."""
    return trained_test_runs


def test_the_parts_axes_option_needs_a_run_trained_in_the_parts_frame(trained_runs):
    """``scapo predict --option parts_axes=plane`` changes how a ``stage2_frame="parts"`` run's passes find the
    base's directions; a run trained otherwise has no such passes and is refused with what to do."""
    from scapo.errors import ConfigError
    from scapo.methods.scapo import SCAPOMethod, SCAPOOptions

    with pytest.raises(ConfigError, match="stage2_frame='parts'.*drop the option"):
        SCAPOMethod(SCAPOOptions(run=trained_runs["scapo"], parts_axes="plane")).load()


@pytest.mark.parametrize("name", ["scapo", "op-align"])
def test_the_axis_sweep_step_runs_on_a_trained_method_and_sets_only_the_revolute_axes(name, laptop_data,
                                                                                     trained_runs, tmp_path):
    """``axis_sweep=true``: fitted on the training split's one-pass predictions, it changes the joint axes (unit,
    turned by each view's base rotation) and nothing else, and records what it found."""
    plain = run_method(name, laptop_data, tmp_path / "a.npz", run=trained_runs[name])
    swept = run_method(name, laptop_data, tmp_path / "b.npz", run=trained_runs[name], axis_sweep=True)
    assert swept.method.endswith("+axis-sweep") and len(swept.info["axis_sweep"]) == 1
    assert np.array_equal(plain.part_label, swept.part_label) and np.allclose(plain.T_cam_obj, swept.T_cam_obj)
    assert np.allclose(np.linalg.norm(swept.joint_axis, axis=-1), 1.0, atol=1e-5)
    found = swept.info["axis_sweep"][0]
    if found["mode"] != "kept":  # the canonical axis, the same in every view's base frame
        canon = np.einsum("bji,bkj->bki", swept.T_cam_obj[:, :3, :3], swept.joint_axis)[:, 0]
        assert np.allclose(np.abs(canon @ np.array(found["axis"])), 1.0, atol=1e-3)


@pytest.mark.parametrize("name", ALL)
def test_every_method_trains_predicts_and_is_scored(name, laptop_data, trained_runs, tmp_path):
    opts = {"run": trained_runs[name]} if name in trained_runs else dict(METHODS.get(name).quick_options)
    preds = run_method(name, laptop_data, tmp_path / "p.npz", **opts)
    assert preds.needs_alignment == METHODS.get(name).needs_alignment
    assert preds.supervision == dict(METHODS.get(name).supervision)
    splits = set(preds.split.tolist())
    assert splits == ({"test", "train"} if preds.needs_alignment else {"test"})
    res = evaluate(laptop_data, tmp_path / "p.npz")
    for k in ("S", "R", "t", "D", "C", "R_median"):
        assert math.isfinite(res.summary[k]), (name, k, res.summary[k])
    assert 0 <= res.summary["S"] <= 100 and 0 <= res.summary["R"] <= 180 and 0 <= res.summary["D"] <= 90
    if name in trained_runs:
        assert method_of_run(trained_runs[name]) == name


@pytest.mark.parametrize("name", [n for n in ALL if METHODS.get(n).refinable])
def test_every_refinable_method_predicts_with_the_test_time_refinement(name, laptop_data, trained_runs, tmp_path):
    preds = run_method(name, laptop_data, tmp_path / "p.npz", run=trained_runs[name], refine=True)
    assert preds.method == f"{name}+refine" and preds.info["refine"]["steps"] > 0
    assert preds.info["refine"]["upright_deg"] == 0  # no gravity cue
    assert 0 <= preds.info["refine_start_rate"] <= 1
    res = evaluate(laptop_data, tmp_path / "p.npz")
    for k in ("S", "R", "D", "C", "R_sym"):
        assert math.isfinite(res.summary[k]), (name, k)


@pytest.mark.parametrize("name,axis", [("scapo", False), ("npcs", True)])
def test_a_trained_method_predicts_with_the_hinge_resplit(name, axis, laptop_data, trained_runs, tmp_path):
    plain = run_method(name, laptop_data, tmp_path / "a.npz", run=trained_runs[name])
    preds = run_method(name, laptop_data, tmp_path / "p.npz", run=trained_runs[name], hinge=True, hinge_axis=axis)
    suffix = "+hinge-axis" if axis else "+hinge"
    assert preds.method == name + suffix and 0 <= preds.info["hinge"]["changed_share_mean"] <= 1
    keep = plain.part_label != preds.part_label  # only the joint's two parts trade points
    jp = plain.joint_parts[0, 0]
    assert np.isin(plain.part_label[keep], jp).all() and np.isin(preds.part_label[keep], jp).all()
    if not axis:
        move = preds.joint_pivot - plain.joint_pivot  # the pivot moves normal to the joint axis only
        a = plain.joint_axis / np.linalg.norm(plain.joint_axis, axis=-1, keepdims=True)
        assert np.abs((move * a).sum(-1)).max() < 1e-5 and np.allclose(preds.joint_axis, plain.joint_axis)
    assert np.allclose(preds.part_pose, plain.part_pose)
    from scapo.steps.hinge import hinge_predictions  # the same step on the file already written

    post = hinge_predictions(laptop_data, tmp_path / "a.npz", axis_from_planes=axis)
    assert post.method == name + suffix and (post.part_label == preds.part_label).all()
    assert np.allclose(post.joint_pivot, preds.joint_pivot, atol=1e-5)
    assert np.allclose(post.joint_axis, preds.joint_axis, atol=1e-5)
    with pytest.raises(PredictionError, match="already"):
        hinge_predictions(laptop_data, post)
    # the bar axes, a rank chosen on the training split from the method's own split (a few steps of training: its
    # "lid" may look like a bar); a joint given a rank keeps the one-pass split, one without is the plain step
    bar = run_method(name, laptop_data, tmp_path / "b.npz", run=trained_runs[name], hinge=True, hinge_axis=axis,
                     hinge_bar_axis=True)
    (rank,) = bar.info["hinge"]["bar_axes"]
    assert bar.method == name + suffix + "-bar" and rank in (None, 0, 1, 2)
    if rank is None:
        assert (bar.part_label == preds.part_label).all() and np.allclose(bar.joint_axis, preds.joint_axis)
    else:
        assert (bar.part_label == plain.part_label).all()
        assert np.allclose(np.linalg.norm(bar.joint_axis, axis=-1), 1.0, atol=1e-4)
    if name == "npcs":  # a supervised method's file holds no training split to choose the ranks on
        with pytest.raises(PredictionError, match="training-split"):
            hinge_predictions(laptop_data, tmp_path / "a.npz", axis_from_bars=True)
    else:  # the diagnosis with the true split (bench/diagnostics/hinge_rows.py --true-labels): labels replaced, joints the method's
        import importlib.util
        from pathlib import Path

        from scapo.eval.predictions import Predictions
        from scapo.steps.hinge import prediction_arrays

        path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / "hinge_rows.py"
        spec = importlib.util.spec_from_file_location("hinge_rows", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        assert mod.main(["--data", str(laptop_data), "--pred", str(tmp_path / "a.npz"), "--out-dir",
                         str(tmp_path / "d"), "--true-labels", "--bar-axis"]) == 0
        diag = Predictions.load(tmp_path / "d" / "a+true-labels+hinge-bar.npz")
        assert diag.method == name + "-true-labels+hinge-bar" and "diagnosis" in diag.info
        assert diag.info["hinge"]["bar_axes"] == [None]  # the true lid is a plate
        true = mod.with_true_labels(laptop_data, plain)
        gt = prediction_arrays(laptop_data, plain, ("part_label",))["part_label"]
        assert (true.part_label == gt).all() and np.allclose(true.joint_axis, plain.joint_axis)


def test_scapo_snaps_its_frame_to_base_axes_signed_by_the_other_parts(laptop_data, trained_runs, tmp_path):
    """``base_frame=parts``: the ranks chosen and the offset fitted on the training split, every view's base rotation
    then its base axes signed by the other parts; translations kept."""
    plain = run_method("scapo", laptop_data, tmp_path / "a.npz", run=trained_runs["scapo"], refine_steps=0)
    preds = run_method("scapo", laptop_data, tmp_path / "p.npz", run=trained_runs["scapo"], refine_steps=0,
                       base_frame="parts", hinge=True, hinge_bar_axis=True)  # with the bar axes fitted before it
    info = preds.info["base_frame"]
    assert info["mode"] == "parts" and len(info["signed_ranks"]) == 2 and 0 <= info["train_support"] <= 1
    assert "bar_axes" in preds.info["hinge"]
    assert np.allclose(preds.part_pose[..., :3, 3], plain.part_pose[..., :3, 3], atol=1e-5)
    assert math.isfinite(evaluate(laptop_data, tmp_path / "p.npz").summary["R"])


def test_scapo_takes_its_object_frame_from_the_base_slot_chosen_on_the_training_split(laptop_data, trained_runs,
                                                                                      tmp_path):
    """``base_slot`` without ``base_frame``: the object frame ``T_cam_obj`` is the chosen slot's pose (``auto``: the
    slot whose training-view rotations spread least; ``1``: slot 1), and nothing else changes."""
    plain = run_method("scapo", laptop_data, tmp_path / "a.npz", run=trained_runs["scapo"], refine_steps=0)
    auto = run_method("scapo", laptop_data, tmp_path / "b.npz", run=trained_runs["scapo"], refine_steps=0,
                      base_slot="auto")
    one = run_method("scapo", laptop_data, tmp_path / "c.npz", run=trained_runs["scapo"], refine_steps=0,
                     base_slot="1")
    from scapo.methods.scapo import SCAPOMethod, SCAPOOptions

    info = auto.info["object_slot"]
    assert auto.method == "scapo+slot-auto" and one.method == "scapo+slot-1" and info["option"] == "auto"
    disp = info["dispersion"]  # the least spread (rounded in the record), or slot 0 kept by the bootstrap's guard
    assert len(disp) == 2 and (disp[info["slot"]] <= min(disp) + 1e-4 or info["slot"] == 0)
    assert np.allclose(auto.T_cam_obj, plain.part_pose[:, info["slot"]], atol=1e-6)
    assert np.allclose(one.T_cam_obj, plain.part_pose[:, 1], atol=1e-6)
    for p in (auto, one):
        assert np.allclose(p.part_pose, plain.part_pose, atol=1e-6) and (p.part_label == plain.part_label).all()
        assert np.allclose(p.joint_axis, plain.joint_axis, atol=1e-6)
    assert "object_slot" not in plain.info and "base_frame" not in auto.info
    m = SCAPOMethod(SCAPOOptions(run=trained_runs["scapo"], base_slot="auto")).load()
    with pytest.raises(ConfigError, match="fit"):  # the slot is chosen on a training split first
        m.steps.apply(np.zeros((1, 64, 3)), {})
    m = SCAPOMethod(SCAPOOptions(run=trained_runs["scapo"], base_slot="5")).load()
    with pytest.raises(ConfigError, match="part slots 0-1"):
        m.steps.fit(np.random.default_rng(0).normal(size=(2, 64, 3)) * 0.1, m._network)
    # one pipeline of prediction steps for every trained method: a baseline takes the same step, alike
    base = run_method("npcs", laptop_data, tmp_path / "d.npz", run=trained_runs["npcs"])
    slot = run_method("npcs", laptop_data, tmp_path / "e.npz", run=trained_runs["npcs"], base_slot="auto")
    assert slot.method == "npcs+slot-auto" and slot.info["object_slot"]["option"] == "auto"
    assert np.allclose(slot.T_cam_obj, base.part_pose[:, slot.info["object_slot"]["slot"]], atol=1e-6)


@pytest.mark.parametrize("name", ["scapo", "npcs"])
def test_a_trained_method_reads_its_part_rotations_from_its_hinges(name, laptop_data, trained_runs, tmp_path):
    """``hinge_frames=true``: offsets fitted on the training split, then the part rotations from the hinges; for a
    self-supervised method's file (it holds the training split), ``hinge_frame_predictions`` gives the same."""
    from scapo.steps.hinge import hinge_frame_predictions

    kw = {"run": trained_runs[name], "hinge": True, "hinge_axis": True}
    hinged = run_method(name, laptop_data, tmp_path / "h.npz", **kw)
    prior = name == "scapo"  # with the view prior for one of them
    preds = run_method(name, laptop_data, tmp_path / "f.npz", hinge_frames=True, hinge_view_prior=prior, **kw)
    assert preds.method == f"{name}+hinge-axis+hinge-frames" + ("+view-prior" if prior else "")
    assert len(preds.info["hinge_frames"]["support"]) == 2 and ("view_prior" in preds.info["hinge_frames"]) == prior
    if not prior:
        assert (preds.part_label == hinged.part_label).all()
    assert np.allclose(preds.joint_axis, hinged.joint_axis)
    assert np.allclose(preds.part_pose[..., :3, 3], hinged.part_pose[..., :3, 3])  # only rotations change
    assert math.isfinite(evaluate(laptop_data, tmp_path / "f.npz").summary["R"])
    if name == "npcs":  # a supervised method's file holds no training split to fit on
        with pytest.raises(PredictionError, match="training-split"):
            hinge_frame_predictions(laptop_data, hinged)
        return
    post = hinge_frame_predictions(laptop_data, hinged, view_prior=prior)
    assert post.method == preds.method and np.allclose(post.part_pose, preds.part_pose, atol=1e-4)
    assert (post.part_label == preds.part_label).all() and np.allclose(post.joint_state, preds.joint_state)
    with pytest.raises(PredictionError, match="already"):
        hinge_frame_predictions(laptop_data, post)


def test_eap_template_posed_by_its_part_poses_is_its_own_reconstruction():
    """The template parts EAP-style returns, posed by its part poses, are the network's reconstruction of the cloud
    mapped back to the camera (stage 1's canonical frame through stage 0's), with the slots in the card's order."""
    from scapo.methods import eap
    from scapo.methods.learned import normalize_clouds

    torch.manual_seed(0)
    net = eap.EAPNet(2, [0], [(0, 1)], eap.PRESETS.get("test")).eval()
    pts = torch.rand(3, 64, 3) * torch.tensor([0.4, 0.3, 0.2]) + torch.tensor([0.1, -0.2, 1.5])
    o = net.infer(pts)
    X, c, sc = normalize_clouds(pts)
    with torch.no_grad():
        Xc, Rw, shift = net.canonicalise(X)
        out = net(Xc)
        posed = net.posed(out) @ Rw[:, None].transpose(-1, -2) + shift[:, None, None]
        want = (sc[:, None, None, None] * posed + c[:, None, None]).double().numpy()
    perm = np.stack([net.card_order(int(k)) for k in out["w"].sum(1).argmax(-1)])
    want = want[np.arange(3)[:, None], perm].reshape(3, -1, 3)
    T = o["part_pose"][np.arange(3)[:, None], o["template_label"]]  # (B, M, 4, 4)
    got = np.einsum("bmij,bmj->bmi", T[..., :3, :3], o["template"]) + T[..., :3, 3]
    np.testing.assert_allclose(got, want, atol=1e-5)


@pytest.mark.parametrize("name", LEARNED)
def test_learned_runs_resume_refuse_other_configs_and_other_methods(name, laptop_data, trained_runs, tmp_path):
    run = trained_runs[name]
    ck = run / "checkpoint.pt"
    before = ck.read_bytes()
    assert train_method(name, laptop_data, run, None, progress=False) == ck  # a finished run is not retrained
    assert ck.read_bytes() == before
    with pytest.raises(TrainingError, match="preset fields that differ: seed"):
        train_method(name, laptop_data, run, "test", progress=False, seed=5)
    other = next(n for n in trained_runs if n != name)
    with pytest.raises(TrainingError, match=f"holds a '{name}' run"):
        train_method(other, laptop_data, run, "test", progress=False)
    with pytest.raises(ConfigError, match=f"is a run of method '{name}'"):
        run_method(other, laptop_data, None, run=run)
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="non-empty folder without a scapo run"):
        train_method(name, laptop_data, tmp_path / "foreign", "test", progress=False)


def test_an_interrupted_learned_run_resumes_to_the_same_weights(laptop_data, tmp_path, monkeypatch):
    from scapo.engine import loop as learned  # the engine's loop (scapo.engine.loop.run_epoch)
    from scapo.methods import learned as harness
    from scapo.methods import npcs

    preset = dataclasses.replace(npcs.PRESETS.get("test"), epochs=3)
    train_method_direct = harness.train_learned
    full = tmp_path / "full"
    train_method_direct(npcs.SPEC, laptop_data, full, preset, progress=False)

    calls = {"n": 0}
    real_epoch = learned.run_epoch

    def stop_after_two(*a, **k):
        if calls["n"] == 2:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real_epoch(*a, **k)

    part = tmp_path / "part"
    monkeypatch.setattr(learned, "run_epoch", stop_after_two)
    with pytest.raises(KeyboardInterrupt):
        train_method_direct(npcs.SPEC, laptop_data, part, preset, progress=False)
    monkeypatch.setattr(learned, "run_epoch", real_epoch)
    state = torch.load(part / "checkpoint.pt", weights_only=False)
    assert state["epoch"] == 2 and not state["done"]
    train_method_direct(npcs.SPEC, laptop_data, part, preset, progress=False)
    a = torch.load(full / "checkpoint.pt", weights_only=False)["model"]
    b = torch.load(part / "checkpoint.pt", weights_only=False)["model"]
    for k in a:
        torch.testing.assert_close(a[k], b[k])


def test_an_unfinished_learned_run_is_refused_by_predict(laptop_data, tmp_path, monkeypatch):
    from scapo.engine import loop as learned  # the engine's loop

    def stop(*a, **k):
        raise KeyboardInterrupt

    with pytest.raises(TrainingError, match="holds no checkpoint"):
        run_method("eap", laptop_data, None, run=tmp_path / "empty")
    real = learned.run_epoch
    calls = {"n": 0}

    def one(*a, **k):
        if calls["n"]:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real(*a, **k)

    monkeypatch.setattr(learned, "run_epoch", one)
    with pytest.raises(KeyboardInterrupt):
        train_method("eap", laptop_data, tmp_path / "r", "test", progress=False)
    with pytest.raises(TrainingError, match="unfinished run"):
        run_method("eap", laptop_data, None, run=tmp_path / "r")


def test_perf_reports_each_learned_methods_inference_time():
    from scapo.bench.perf import bench_method

    for name in LEARNED:
        (row,) = bench_method(name, "test", device="cpu", iters=1, num_points=256)
        assert row["method"] == name and row["infer_ms_per_cloud_b1"] > 0 and row["infer_clouds_per_s_b32"] > 0
    with pytest.raises(ConfigError, match="needs --data"):
        bench_method("icp")


# ------------------------------------------------------------------------------------------ geometry
def test_ransac_umeyama_survives_30_percent_outliers():
    rng = np.random.default_rng(0)
    src = rng.uniform(-0.5, 0.5, (400, 3))
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    dst = 0.8 * src @ R.T + [0.1, -0.2, 1.5]
    bad = rng.choice(400, 120, replace=False)
    dst[bad] += rng.uniform(-0.5, 0.5, (120, 3))
    T, s, inliers = ransac_umeyama(src, dst, threshold=0.02, rng=rng)
    assert s == pytest.approx(0.8, rel=1e-3)
    np.testing.assert_allclose(T[:3, :3] / s, R, atol=1e-3)
    np.testing.assert_allclose(T[:3, 3], [0.1, -0.2, 1.5], atol=1e-3)
    assert inliers.sum() >= 270 and inliers[bad].mean() < 0.05
    with pytest.raises(ValueError, match="threshold"):
        ransac_umeyama(src, dst, threshold=0.0)


@pytest.mark.parametrize("name", list(GROUP_ORDERS))
def test_candidate_rotations_form_a_group(name):
    G = rotation_group(name)
    assert G.shape == (GROUP_ORDERS[name], 3, 3)
    np.testing.assert_allclose(G[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.einsum("gij,gkj->gik", G, G), np.broadcast_to(np.eye(3), G.shape), atol=1e-9)
    flat = G.reshape(len(G), 9)
    for a in G:  # closed under composition and inverse
        prods = np.einsum("ij,gjk->gik", a, G).reshape(len(G), 9)
        assert np.abs(prods[:, None] - flat[None]).sum(-1).min(1).max() < 1e-9
        assert np.abs(flat - a.T.reshape(9)).sum(-1).min() < 1e-9
    with pytest.raises(ValueError, match="unknown rotation group"):
        rotation_group("X")


def test_octahedral_rotations_are_the_cube_group_as_integers():
    C = octahedral_rotations(torch.float64)
    assert C.shape == (24, 3, 3) and torch.equal(C[0], torch.eye(3, dtype=torch.float64))
    assert torch.equal(C, C.round()) and torch.allclose(torch.det(C), torch.ones(24, dtype=torch.float64))


def test_torch_farthest_point_sample_and_trimmed_chamfer():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(2, 300, 3, generator=g)
    pts[:, :100] = 10.0 + pts[:, :100] * 0.01  # a far cluster must be sampled
    idx = farthest_point_sample(pts, 8)
    assert idx.shape == (2, 8) and (idx < 100).any(1).all() and (idx >= 100).any(1).all()
    b = torch.rand(1, 100, 3, generator=g)
    a = torch.cat([b[:, :70], b[:, 70:] + 5.0], 1)  # 30 % of a lies far from every point of b
    assert float(trimmed_one_sided_chamfer(a, b, keep=0.7)) == pytest.approx(0.0, abs=1e-6)
    assert float(trimmed_one_sided_chamfer(a, b, keep=1.0)) > 1.0


def _moved_object(states, joint_type=0):
    """Part poses (K, 2, 4, 4) of a two-part object under random rigid motions and joint states;
    each part's canonical frame is offset from the object frame by a fixed pose."""
    rng = np.random.default_rng(1)
    axis = np.array([0.0, 0.6, 0.8])
    pivot = np.array([0.1, -0.2, 0.05])
    off = [as_transform(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3)) for _ in range(2)]
    T = []
    for s in states:
        obj = as_transform(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
        T.append([obj @ off[0], obj @ joint_motion(joint_type, axis, pivot, s) @ off[1]])
    return np.array(T), axis, pivot, off


def test_joint_from_part_poses_recovers_a_revolute_and_a_prismatic_joint():
    from scapo.methods.joints import joint_from_part_poses
    from scapo.ops.rigid import closest_point_on_line

    axis, pivot = np.array([0.0, 0.6, 0.8]), np.array([0.1, -0.2, 0.05])
    parent = as_transform(Rotation.from_rotvec([0.2, 0.4, -0.3]).as_matrix(), [0.3, 0.1, 1.2])
    child = parent @ joint_motion(0, axis, pivot, 0.7)
    ax, pv, st = joint_from_part_poses(parent, child, 0, axis, pivot)
    np.testing.assert_allclose(ax, parent[:3, :3] @ axis, atol=1e-9)
    np.testing.assert_allclose(closest_point_on_line(pv, ax), closest_point_on_line(parent[:3, :3] @ pivot
                                                                                    + parent[:3, 3], ax), atol=1e-9)
    assert st == pytest.approx(0.7)
    child = parent @ joint_motion(1, axis, pivot, -0.25)
    ax, pv, st = joint_from_part_poses(parent, child, 1, axis, pivot)
    np.testing.assert_allclose(ax, parent[:3, :3] @ axis, atol=1e-9)
    assert st == pytest.approx(-0.25)


def test_op_align_part_motion_moves_a_part_onto_its_canonical_state():
    from scapo.methods import op_align

    net = op_align.OPAlignNet(2, [0], [(0, 1)], op_align.PRESETS.get("test"))
    d_s = torch.tensor([[[0.0, 0.0, 1.0]]])
    d_y = torch.nn.functional.normalize(torch.tensor([[[0.0, 1.0, 1.0]]]), dim=-1)
    src = {"drct": d_s, "pivot": torch.tensor([[[0.1, 0.0, 0.0]]]), "state": torch.tensor([[[0.0, 0.3]]])}
    dst = {"drct": d_y, "pivot": torch.tensor([[[0.0, 0.2, 0.0]]]), "state": torch.tensor([[[0.0, -0.4]]])}
    R, t = net.side_motion(src, dst, 0, 1)
    torch.testing.assert_close(R[0] @ d_s[0, 0], d_y[0, 0])  # direction onto direction
    torch.testing.assert_close(R[0] @ src["pivot"][0, 0] + t[0], dst["pivot"][0, 0])  # pivot onto pivot
    e = torch.tensor([1.0, 0.0, 0.0])  # a direction normal to both axes turns by the state difference
    Rd = op_align.direction_rotation(d_s[0], d_y[0])[0]
    cos = float((R[0] @ e) @ (Rd @ e))
    assert cos == pytest.approx(math.cos(-0.7), abs=1e-5)


def test_eap_stage0_makes_stage1s_input_the_same_for_a_turned_cloud():
    """Stage 0 (the whole-object network) is rotation-equivariant, so the canonical cloud it hands stage 1 is the same
    for a cloud and the cloud turned and moved, and the predicted part poses turn with it."""
    from scapo.methods import eap

    torch.manual_seed(0)
    net = eap.EAPNet(2, [0], [(0, 1)], eap.PRESETS.get("test")).double().eval()
    X = torch.rand(2, 64, 3, dtype=torch.float64) - 0.5
    Q = torch.from_numpy(Rotation.from_rotvec([0.4, -1.0, 2.0]).as_matrix())
    with torch.no_grad():
        a, b = net.canonicalise(X), net.canonicalise(X @ Q.T + 0.3)
    torch.testing.assert_close(b[0], a[0], atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(b[1], Q @ a[1], atol=1e-6, rtol=1e-6)
    with torch.no_grad():
        pa, pb = net._predict(X + 1.0), net._predict((X + 1.0) @ Q.T)
    torch.testing.assert_close(pb["R"], Q @ pa["R"], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(pb["axis"], pa["axis"] @ Q.T, atol=1e-5, rtol=1e-5)


def test_eap_parts_turn_about_one_shared_axis_within_a_quarter_turn():
    """EAP's constrained part poses (``M38`` 1076-1121): every part's rotation relative to another is a turn about
    the one shared axis (through the orbit) by the difference of their angles, each angle within [0, 90] deg, and a
    part's pivot stays where it is; a prismatic category slides along the axis instead."""
    from scapo.methods import eap

    torch.manual_seed(1)
    net = eap.EAPNet(3, [0, 0], [(0, 1), (0, 2)], eap.PRESETS.get("test")).double().eval()
    with torch.no_grad():
        net.motion[-1].bias.normal_(0, 3.0)  # spread the angles
        o = net(torch.rand(4, 64, 3, dtype=torch.float64) - 0.5)
    assert float(o["amount"].min()) >= 0.0 and float(o["amount"].max()) <= np.pi / 2 + 1e-9
    G = net.anchors.double()[o["orbit"]]  # (B, 3, 3)
    u = (G @ o["axis"][..., None])[..., 0]
    for p, q in ((1, 0), (2, 0), (2, 1)):
        rel = o["R"][:, p] @ o["R"][:, q].transpose(1, 2)
        rv = torch.from_numpy(Rotation.from_matrix(rel.numpy()).as_rotvec())
        want = u * (o["amount"][:, p] - o["amount"][:, q])[:, None]
        torch.testing.assert_close(rv, want, atol=1e-6, rtol=1e-6)
    axis, amount = torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([[0.3, 1.2]])
    centre, pivot = torch.tensor([[[0.2, 0.0, 0.0], [0.0, 0.3, 0.0]]]), torch.tensor([[[0.1, 0.1, 0.0]] * 2])
    R, t = eap.part_motion(axis, amount, centre, pivot, prismatic=False)
    for p in range(2):  # the pivot, as a point of the part's centred shape, is fixed by the motion
        torch.testing.assert_close(R[0, p] @ (pivot[0, p] - centre[0, p]) + t[0, p], pivot[0, p])
    R, t = eap.part_motion(axis, amount, centre, pivot, prismatic=True)
    torch.testing.assert_close(R, torch.eye(3).expand(1, 2, 3, 3))
    torch.testing.assert_close(t, centre + amount[..., None] * axis[:, None])


def test_eap_stage1_leaves_stage0_as_trained():
    """Stage 1 trains the part network with stage 0 frozen: its optimiser holds none of stage 0's parameters, and
    steps of stage 1 change neither stage 0's parameters nor its statistics."""
    from scapo.methods import eap

    torch.manual_seed(0)
    net = eap.EAPNet(2, [0], [(0, 1)], eap.PRESETS.get("test")).train()
    s0, s1 = net.training_stages()
    assert (s0["index"], s1["index"]) == (1, 2) and s1["epochs"] == 2 and s0["epochs"] == 1
    frozen = {k: v.clone() for m in net.stage0_modules() for k, v in m.state_dict().items()}
    held = {id(p) for p in s1["params"]()}
    assert not any(id(p) in held for m in net.stage0_modules() for p in m.parameters())
    opt = torch.optim.Adam(s1["params"](), lr=1e-2)
    batch = {"points": torch.rand(4, 128, 3) + torch.tensor([0.0, 0.0, 1.0])}
    for _ in range(3):
        _, total = s1["losses"](batch, 0.5)
        opt.zero_grad()
        total.backward()
        opt.step()
    after = {k: v for m in net.stage0_modules() for k, v in m.state_dict().items()}
    assert all(torch.equal(frozen[k], after[k]) for k in frozen)
    assert all(p.grad is None for m in net.stage0_modules() for p in m.parameters())


def test_eap_base_is_the_largest_part_and_every_point_is_predicted_at_the_training_density(monkeypatch):
    """The base is the slot with the most points: its pose is ``T_cam_obj`` and it becomes the card's root part (the
    labels follow); a cloud of more points than the training density is predicted in interleaved subsets of at most
    that many, every point labelled by its subset, the poses the first subset's."""
    from scapo.methods import eap

    torch.manual_seed(0)
    net = eap.EAPNet(2, [0], [(0, 1)], eap.PRESETS.get("test")).eval()
    assert net.card_order(1).tolist() == [1, 0] and net.card_order(0).tolist() == [0, 1]
    seen = []
    real = net._predict

    def spy(points):
        seen.append(points.shape[1])
        out = real(points)
        out["label"] = torch.ones_like(out["label"])  # every point in slot 1: the largest
        out["base"] = torch.ones_like(out["base"])
        return out

    monkeypatch.setattr(net, "_predict", spy)
    pts = torch.rand(2, 300, 3) + torch.tensor([0.0, 0.0, 1.0])
    o = net.infer(pts)
    assert max(seen) <= net.pc.points and sum(seen) == 300 and len(seen) == 3
    assert (o["part_label"] == 0).all()  # slot 1 is the card's base part 0
    np.testing.assert_array_equal(o["T_cam_obj"], o["part_pose"][:, 0])

    # two interleaved subsets of one cloud (the cloud twice, its copies in different subsets), labelled by a network
    # whose segmentation is a function of the point: each point and its copy get the same label, the rule's
    def by_side(points):
        out = real(points)
        out["label"] = (points[..., 0] > 0.5).long()
        out["base"] = torch.zeros_like(out["base"])
        return out

    monkeypatch.setattr(net, "_predict", by_side)
    half = torch.rand(1, net.pc.points, 3) + torch.tensor([0.0, 0.0, 1.0])
    o = net.infer(torch.cat([half, half], 1))
    lab = o["part_label"][0]
    np.testing.assert_array_equal(lab[:net.pc.points], lab[net.pc.points:])
    np.testing.assert_array_equal(lab[:net.pc.points], (half[0, :, 0] > 0.5).long().numpy())


def test_op_align_density_aware_chamfer_matches_the_original_rule_and_bounds_outliers():
    """OP-Align's ``1 - exp(-alpha d)`` Chamfer (art_metric.py 169-178, 234-239) on hand-made clouds."""
    from scapo.methods.op_align import density_chamfer
    from scapo.ops.chamfer import chamfer_distance

    a = torch.tensor([[[0.0, 0, 0]]])
    b = torch.tensor([[[0.1, 0, 0]]])
    want = (1 - math.exp(-30 * 0.01)) + 30 / 120 * (1 - math.exp(-120 * 0.01))
    assert float(density_chamfer(a, b, 30, 120)) == pytest.approx(want, rel=1e-5)
    torch.manual_seed(0)
    x, y = torch.rand(2, 50, 3), torch.rand(2, 60, 3)
    torch.testing.assert_close(density_chamfer(x, y, 0.0, 0.0), chamfer_distance(x, y))  # alpha 0: plain
    far = torch.cat([x, torch.full((2, 1, 3), 100.0)], 1)  # one outlier: plain Chamfer explodes, density does not
    assert float((chamfer_distance(far, y) - chamfer_distance(x, y)).min()) > 100
    gap = density_chamfer(far, y, 30, 120) - density_chamfer(x, y, 30, 120)
    assert float(gap.max()) < 1.0 / 51 + 1e-3


def test_op_align_local_density_is_zero_for_even_spacing_and_grows_with_clumps():
    from scapo.methods.op_align import local_density

    u = torch.linspace(0, 2 * math.pi, 65)[:-1]
    ring = torch.stack([torch.cos(u), torch.sin(u), torch.zeros_like(u)], -1)[None]  # equal neighbour distances
    assert float(local_density(ring, 4)) < 1e-8
    clumped = ring.clone()
    clumped[0, :32] *= 0.1  # half of the points crowd near the centre
    assert float(local_density(clumped, 4)) > 1e-3


def test_op_align_template_prior_variance_penalty_and_bounded_residual():
    """The category template ``y_base`` is shared: with a zero offset every instance's shape is ``y_base`` and the
    variance penalty is 0, a large offset costs close to 1 (art_metric.py 302-307); the anchors' residual
    rotations stay within +-18 deg (art_so3net_pn.py 273-278); the expected-distance attention term moves the
    attention to the nearest anchor."""
    from scapo.methods import op_align

    torch.manual_seed(0)
    pc = op_align.PRESETS.get("test")
    net = op_align.OPAlignNet(2, [0], [(0, 1)], pc)
    with torch.no_grad():
        net.decoder[-1].weight.zero_()
        net.decoder[-1].bias.zero_()
    o = net.object_level(torch.rand(3, 64, 3) - 0.5)
    torch.testing.assert_close(o["Y"], net.y_base.expand(3, -1, -1))
    assert float(op_align.offset_variance(o["offset"].detach(), pc.var_alpha).max()) == 0.0
    assert float(op_align.offset_variance(torch.ones(1, 5, 3), 60.0)) == pytest.approx(1.0, abs=1e-6)
    for _ in range(3):
        with torch.no_grad():
            net.anchor_head[-1].weight.normal_(0, 10.0)
        r = net.object_level(torch.rand(2, 64, 3) - 0.5)
        rel = net.anchors.transpose(1, 2).unsqueeze(0) @ r["R"]  # G^T R: the residual
        cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)
        assert float(torch.rad2deg(torch.arccos(cos)).max()) <= pc.max_residual_deg + 1e-3
    logits = torch.zeros(1, 3, requires_grad=True)
    dist = torch.tensor([[1.0, 0.1, 0.5]])
    (torch.softmax(logits, -1) * dist).sum().backward()
    assert int(logits.grad.argmin()) == 1  # gradient descent raises the nearest anchor's attention


def test_op_align_object_frame_is_its_base_parts_pose_and_its_terms_follow_the_original():
    """``T_cam_obj`` is the base part's pose (the root of the kinematic tree; the dataset's convention), not the
    object-level rigid fit; the clouds are normalised to a mean centroid distance of 0.25 (``LightDataset.py`` 45-50);
    the pivot term is ``1 - exp(-30 d^2)`` of the mean distance to the 8 nearest points and sends no gradient into
    the shape (``art_metric.py`` 267-274); the canonical shape's states go to 0, its pivots are free
    (``art_metric.py`` 256-265)."""
    from scapo.methods import op_align

    torch.manual_seed(0)
    pc = op_align.PRESETS.get("test")
    pts = torch.rand(3, 96, 3) * torch.tensor([0.4, 0.3, 0.02]) + torch.tensor([0.0, 0.0, 0.8])
    X, c, sc = op_align.normalize_op_align(pts)
    assert float(X.norm(dim=-1).mean(-1).sub(0.25).abs().max()) < 1e-6
    torch.testing.assert_close(X * sc[:, None, None] + c[:, None], pts)
    for joint_parts, base in (([(0, 1)], 0), ([(1, 0)], 1), ([(2, 0), (2, 1)], 2)):
        parts = 1 + max(max(p) for p in joint_parts)
        net = op_align.OPAlignNet(parts, [0] * len(joint_parts), joint_parts, pc).eval()
        assert net.base == base
        out = net.infer(pts)
        np.testing.assert_array_equal(out["T_cam_obj"], out["part_pose"][:, base])
    shape = torch.rand(2, 50, 3, requires_grad=True)
    pivot = shape[:, :1].detach().clone().requires_grad_(True)
    term = op_align.pivot_near(pivot, shape)
    term.backward()
    assert shape.grad is None or float(shape.grad.abs().max()) == 0.0
    assert pivot.grad is not None and 0.0 < float(term) < 1.0
    net = op_align.OPAlignNet(2, [0], [(0, 1)], pc).train()
    terms, _ = net.losses({"points": pts}, 0.0)
    assert {"cano_joint", "pivot_near", "balance"} <= set(terms)


def test_eap_orbit_choice_picks_the_one_anchor_that_fits_every_part():
    """Two parts posed by one cube rotation of the group (one orbit shared by the parts); the orbit choice (EAP's
    selection by reconstruction distance over the sum of the parts) finds the anchor that poses both."""
    from scapo.methods import eap

    rng = np.random.default_rng(0)
    net = eap.EAPNet(2, [0], [(0, 1)], eap.PRESETS.get("cpu"))
    G = net.anchors
    shapes = []
    for size in ((0.4, 0.1, 0.05), (0.2, 0.3, 0.08)):  # boxes with an extra bump: no rotational symmetry
        pts = (rng.random((128, 3)) - 0.5) * size
        pts[:20] += np.array([size[0] / 2, size[1] / 2, 0.05])
        shapes.append(pts)
    Y = torch.tensor(np.stack(shapes), dtype=torch.float32)[None]  # (1, 2, 128, 3)
    R = torch.from_numpy(Rotation.from_rotvec([[0.0, 0.0, 0.3], [0.0, 0.0, 0.9]]).as_matrix()).float()[None]
    t = torch.tensor([[[0.2, 0.0, 0.1], [-0.3, 0.2, 0.0]]])
    want = 17
    X = torch.cat([(Y[0, p] @ R[0, p].T + t[0, p]) @ G[want].T for p in range(2)])[None]  # (1, 256, 3)
    w = torch.zeros(1, 256, 2)
    w[0, :128, 0], w[0, 128:, 1] = 1, 1
    assert net.select_orbit(X, w, R, t, Y).tolist() == [want]


def test_npcs_vn_backbone_gives_labels_and_npcs_that_no_rotation_changes():
    """NPCS-style's ``vn`` backbone (the cpu and paper presets; the paper's NPCS-EPN row): part logits and NPCS
    maps, both rotation-invariant targets, are the same for a cloud and the cloud turned about its centroid."""
    import dataclasses

    from scapo.methods import npcs

    torch.manual_seed(0)
    pc = dataclasses.replace(npcs.PRESETS.get("cpu"), vn_channels=8, width=32)
    assert npcs.PRESETS.get("cpu").backbone == "vn" and npcs.PRESETS.get("paper").backbone == "vn"
    net = npcs.NPCSNet(2, [0], [(0, 1)], pc).double().eval()
    X = torch.rand(2, 96, 3, dtype=torch.float64) - 0.5
    Q = torch.from_numpy(Rotation.from_rotvec([0.4, -1.0, 2.0]).as_matrix())
    a, b = net(X), net(X @ Q.T)
    torch.testing.assert_close(a[0], b[0], atol=1e-8, rtol=1e-6)
    torch.testing.assert_close(a[1], b[1], atol=1e-8, rtol=1e-6)
    torch.testing.assert_close(a[2], b[2], atol=1e-8, rtol=1e-6)  # the per-part NPCS (cpu preset: part_npcs)
    with pytest.raises(ConfigError, match="backbone"):
        dataclasses.replace(pc, backbone="pointnet++")


def test_perf_train_times_every_trained_methods_step_and_refuses_icp(tmp_path, capsys):
    """``scapo bench perf --what train`` (issue 30): clouds/s of one training step per stage for every trained
    method (two stages for SCAPO), written with provenance; ICP, which is not trained, is refused."""
    from scapo.bench.perf import bench_train

    rows = bench_train(["npcs", "scapo"], "test", iters=1)
    by = {r["method"]: r for r in rows}
    assert by["npcs"]["stage1_clouds_per_s"] > 0 and by["scapo"]["stage2_clouds_per_s"] > 0
    assert by["npcs"]["points"] == 128 and by["scapo"]["threads"] >= 1
    with pytest.raises(ConfigError, match="not trained"):
        bench_train(["icp"], "test")
    assert main(["bench", "perf", "--what", "train", "--method", "npcs", "--preset", "test",
                 "--out", str(tmp_path)]) == 0
    assert (tmp_path / "train_test_npcs.json").is_file()
    # --baseline: each stage's clouds/s before and the speed-up, the baseline's commit in the provenance
    assert main(["bench", "perf", "--what", "train", "--method", "npcs", "--preset", "test", "--out",
                 str(tmp_path / "after"), "--baseline", str(tmp_path / "train_test_npcs.json")]) == 0
    import json

    out = json.loads((tmp_path / "after" / "train_test_npcs_vs_baseline.json").read_text())
    row = out["rows"][0]
    assert row["stage1_clouds_per_s_speedup"] == pytest.approx(  # rounded to 0.01
        row["stage1_clouds_per_s"] / row["stage1_clouds_per_s_before"], abs=0.0051)
    assert out["provenance"]["baseline_commit"]
    from scapo.bench.perf import compare_train

    with pytest.raises(ConfigError, match="points=128, now 64"):
        compare_train([{**row, "points": 64}], tmp_path / "train_test_npcs.json")
    with pytest.raises(ConfigError, match="cannot read the baseline"):
        compare_train([row], tmp_path / "nothing.json")
    assert main(["bench", "perf", "--what", "model", "--baseline", str(tmp_path / "train_test_npcs.json")]) != 0
    assert "--baseline and --budget-minutes go with" in capsys.readouterr().err
    assert main(["bench", "perf", "--what", "model", "--iters", "3"]) == 2  # only --what train takes --iters
    assert "--iters goes with 'bench perf --what train' without --data" in capsys.readouterr().err
    assert main(["bench", "perf", "--what", "train", "--iters", "0"]) == 2
    err = capsys.readouterr().err
    assert "error: --iters must be >= 1, got 0" in err and "Traceback" not in err


def _two_part_object(rng):
    """Rest-frame points (metres) of a two-part object, its bbox diagonal and part labels."""
    base = rng.uniform([-0.2, -0.15, -0.02], [0.2, 0.15, 0.02], (300, 3))
    lid = rng.uniform([-0.2, 0.13, 0.0], [0.2, 0.15, 0.25], (200, 3))
    x = np.concatenate([base, lid])
    diag = float(np.linalg.norm(x.max(0) - x.min(0)))
    return x, diag, np.repeat([0, 1], [300, 200])


def test_npcs_part_pose_from_per_part_npcs_recovers_each_parts_pose_and_the_scale():
    """ANCSH's per-part NPCS route (``part_pose_from_coords``): from exact NAOCS and per-part NPCS, every part's
    pose (object rest frame -> camera, the lid moved about a hinge) and the bbox diagonal come back; with 20 %
    of the NPCS replaced by outliers RANSAC still finds them; without per-part NPCS the NAOCS route gives the
    same pose."""
    from scapo.methods.npcs import part_pose_from_coords

    rng = np.random.default_rng(0)
    x, diag, lab = _two_part_object(rng)
    naocs = x / diag
    R0 = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    hinge = as_transform(Rotation.from_rotvec([0.8, 0, 0]).as_matrix(), [0, 0.15 - 0.15 * np.cos(0.8), 0])
    poses = [as_transform(R0, [0.1, -0.2, 1.5]), as_transform(R0, [0.1, -0.2, 1.5]) @ hinge]
    for p in (0, 1):
        sel = lab == p
        cam = x[sel] @ poses[p][:3, :3].T + poses[p][:3, 3]
        lo, hi = naocs[sel].min(0), naocs[sel].max(0)
        npcs_p = (naocs[sel] - (lo + hi) / 2) / np.linalg.norm(hi - lo)
        for part, tol in ((npcs_p, 1e-6), (None, 1e-6)):
            T, d = part_pose_from_coords(cam, naocs[sel], part, 0.005, 64, np.random.default_rng(1))
            np.testing.assert_allclose(T, poses[p], atol=tol)
            assert abs(d - diag) < 1e-6
        noisy = npcs_p.copy()
        bad = rng.random(len(noisy)) < 0.2
        noisy[bad] += rng.normal(0, 0.3, (bad.sum(), 3))
        T, d = part_pose_from_coords(cam, naocs[sel], noisy, 0.005, 128, np.random.default_rng(1))
        assert np.degrees(Rotation.from_matrix(T[:3, :3] @ poses[p][:3, :3].T).magnitude()) < 0.5
        assert np.linalg.norm(T[:3, 3] - poses[p][:3, 3]) < 0.01 and abs(d - diag) / diag < 0.02


def test_npcs_part_boxes_are_each_parts_box_over_the_views_of_its_instance():
    """The per-part NPCS targets' boxes (``part_boxes``, NPCS-style's ``derive``): per instance and part, the box of
    that part's points over all its views (so each view of an instance gets the same box), the NAOCS box for a
    part no view shows; nothing when the preset has no per-part NPCS."""
    from scapo.methods import npcs

    pc = npcs.PRESETS.get("cpu")
    assert pc.part_npcs and npcs.PRESETS.get("paper").part_npcs and not npcs.PRESETS.get("test").part_npcs
    card = {"part_names": ["base", "lid", "knob"]}
    npc = np.zeros((3, 4, 3), np.float32)
    lab = np.full((3, 4), -1)
    npc[0, :2], lab[0, :2] = [[0, 0, 0], [0.2, 0.1, 0]], 0  # instance 7, view 0: two base points
    npc[1, :3], lab[1, :3] = [[-0.2, 0.3, 0.1], [0, 0, 0.4], [0.1, 0.1, 0.1]], 0  # instance 7, view 1
    npc[2, :4], lab[2, :4] = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], 1  # instance 9: four lid points
    a = {"npcs": npc, "part_label": lab, "instance_id": np.array([7, 7, 9])}
    box = npcs.part_boxes(a, card, pc)["part_box"]
    assert box.shape == (3, 3, 4) and box.dtype == np.float32
    lo, hi = np.array([-0.2, 0, 0]), np.array([0.2, 0.3, 0.4])
    for v in (0, 1):
        np.testing.assert_allclose(box[v, 0], [*(lo + hi) / 2, np.linalg.norm(hi - lo)], atol=1e-6)
        np.testing.assert_allclose(box[v, 1], [0, 0, 0, 1])  # lid never seen in instance 7
    np.testing.assert_allclose(box[2, 1], [0.5, 0.5, 0.5, 3 ** 0.5], atol=1e-6)
    np.testing.assert_allclose(box[2, 2], [0, 0, 0, 1])
    assert npcs.part_boxes(a, card, npcs.PRESETS.get("test")) == {}


def test_npcs_with_per_part_npcs_trains_and_predicts(laptop_data, tmp_path):
    """The ``part_npcs`` setting end to end: training logs the per-part NPCS term and predictions are scored."""
    import csv

    from scapo.methods import npcs
    from scapo.methods.learned import train_learned

    preset = dataclasses.replace(npcs.PRESETS.get("test"), part_npcs=True)
    train_learned(npcs.SPEC, laptop_data, tmp_path / "run", preset, progress=False)
    with open(tmp_path / "run" / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and all(math.isfinite(float(r["part_npcs"])) for r in rows)
    run_method("npcs", laptop_data, tmp_path / "p.npz", run=tmp_path / "run")
    res = evaluate(laptop_data, tmp_path / "p.npz")
    assert math.isfinite(res.summary["R"]) and math.isfinite(res.summary["D"])


def test_training_budget_turns_measured_speeds_into_epochs_that_fill_the_budget():
    """``perf --what train --budget-minutes``: the planned minutes of each preset's schedule on the tables'
    training clouds, and the epochs per stage (same factor for every stage) that fill the budget; a fixed
    iteration count is planned but not rescaled; bad budgets are refused."""
    from scapo.bench.perf import training_budget

    rows = [{"method": "a", "batch_size": 16, "stage1_clouds_per_s": 32.0, "stage1_epochs": 10,
             "max_steps_per_epoch": 0, "iterations": 0},
            {"method": "b", "batch_size": 16, "stage1_clouds_per_s": 32.0, "stage2_clouds_per_s": 16.0,
             "stage1_epochs": 2, "stage2_epochs": 2, "max_steps_per_epoch": 10, "iterations": 0},
            {"method": "c", "batch_size": 16, "stage1_clouds_per_s": 16.0, "stage1_epochs": 1,
             "max_steps_per_epoch": 0, "iterations": 100},
            {"method": "icp"}]
    a, b, c, d = training_budget(rows, 530 / 60, 840)
    assert a["planned_min"] == pytest.approx(52 * 10 * 0.5 / 60, abs=0.01) and a["stage1_epochs_for_budget"] == 20
    assert b["planned_min"] == 0.5 and (b["stage1_epochs_for_budget"], b["stage2_epochs_for_budget"]) == (35, 35)
    assert c["planned_min"] == pytest.approx(100 / 60, abs=0.01) and "stage1_epochs_for_budget" not in c
    assert d == {"method": "icp"}
    with pytest.raises(ConfigError, match="budget-minutes"):
        training_budget(rows, 0, 840)


def test_train_speed_on_a_dataset_separates_steps_from_fixed_costs(laptop_data, tmp_path):
    """``perf --what train --data``: a real two-epoch run per stage and the engine's record of where its time went
    give each stage's clouds/s, the seconds each epoch adds and the run's one-time seconds; ``--budget-minutes``
    turns them into epochs that fill the budget (the fixed cost left out of it)."""
    import json

    from scapo.bench.perf import bench_train_data, training_budget

    (row,) = bench_train_data(laptop_data, ["scapo"], "test", steps=2, work=tmp_path / "w")
    assert row["stage1_clouds_per_s"] > 0 and row["stage2_clouds_per_s"] > 0 and row["fixed_s"] >= 0
    assert row["stage1_epoch_s"] >= 0 and row["train_clouds"] > 0 and (row["stage1_epochs"], row["stage2_epochs"]) == (1, 1)
    timing = json.loads((tmp_path / "w" / "scapo_test" / "timing.json").read_text())
    assert timing["stages"]["1"]["steps"] == timing["stages"]["2"]["steps"] == 4 and timing["steps"] == 8
    parts = sum(p["step_s"] + p["epoch_s"] + p["start_s"] for p in timing["stages"].values()) + timing["final_s"]
    assert parts + timing["other_s"] == pytest.approx(timing["session_s"], abs=0.01) and timing["other_s"] >= 0
    assert parts > 0.5 * timing["session_s"]  # the steps and epochs take most of it
    r = {**row, "fixed_s": 30.0, "stage1_epoch_s": 1.0, "stage2_epoch_s": 1.0, "max_steps_per_epoch": 2,
         "stage1_clouds_per_s": 8.0, "stage2_clouds_per_s": 4.0, "batch_size": 4}
    (b,) = training_budget([r], 1.5, 16)  # 30 s fixed; an epoch of each stage: 1 + 1 and 2 + 1 seconds
    assert b["planned_min"] == pytest.approx((30 + 2 + 3) / 60, abs=0.01)
    assert (b["stage1_epochs_for_budget"], b["stage2_epochs_for_budget"]) == (12, 12)  # 60 s / 5 s
    with pytest.raises(ConfigError, match="--steps must be >= 2"):
        bench_train_data(laptop_data, ["scapo"], "test", steps=1)
    with pytest.raises(ConfigError, match="training clouds, fewer than"):
        bench_train_data(laptop_data, ["npcs"], "test", steps=10_000)
    assert main(["bench", "perf", "--what", "train", "--method", "npcs", "--preset", "test", "--data", str(laptop_data),
                 "--steps", "2", "--budget-minutes", "1", "--out", str(tmp_path)]) == 0
    out = json.loads((tmp_path / f"train_test_{laptop_data.name}_npcs.json").read_text())
    assert out["rows"][0]["stage1_epochs_for_budget"] >= 1 and out["provenance"]["budget_minutes"] == 1.0


@pytest.mark.parametrize("name", ["scapo", "npcs", "eap", "op-align"])
def test_cpu_presets_fill_the_equal_training_budget(name):
    """Issue 30's equal budget: every trained method's ``cpu`` preset trains on the same 256 points and, at the
    speed measured on the tables' data (``results/perf/train_cpu_laptop_i150_v8_s1_<method>.json``, written by
    ``scapo bench perf --what train --data ... --budget-minutes 15``), its epochs fill the stated 15 minutes per
    cell within 10 %."""
    import json
    from pathlib import Path

    from scapo.bench.perf import training_budget

    measured = json.loads((Path(__file__).parents[1] / "results" / "perf" /
                           f"train_cpu_laptop_i150_v8_s1_{name}.json").read_text())
    (row,) = measured["rows"]
    assert measured["provenance"]["budget_minutes"] == 15.0 and row["threads"] == 1
    pc = METHODS.get(name).preset("cpu")
    assert getattr(pc, "train_points", getattr(pc, "points", None)) == 256 and pc.batch_size == 16
    from scapo.registry import schedule_fields

    epochs = {f"stage{k}_epochs": getattr(pc, f) for k, f in enumerate(schedule_fields(pc), 1)}
    assert pc.max_steps_per_epoch == 100 and not getattr(pc, "iterations", 0)
    (plan,) = training_budget([{**row, **epochs, "max_steps_per_epoch": pc.max_steps_per_epoch}], 15.0,
                              row["train_clouds"])
    assert abs(plan["planned_min"] - 15.0) <= 1.5, plan


def test_npcs_infer_points_splits_the_cloud_into_training_density_subsets(trained_test_runs):
    """``--option infer_points=n``: every point gets the label and maps of the subset it was inferred in (the same
    network outputs as inferring that subset alone); the default (0) is the run's training point count; n >= N is
    every point at once, as the committed tables did; bad values are refused."""
    from scapo.methods import load_run
    from scapo.methods.learned import normalize_clouds
    from scapo.methods.npcs import NPCSOptions

    method = load_run(trained_test_runs["npcs"], infer_points=32)
    net = method.module
    X = torch.rand(2, 100, 3) - 0.5
    lo, co, _ = net.outputs(X)
    perm = torch.randperm(100, generator=torch.Generator().manual_seed(0))
    first = torch.tensor_split(perm, 4)[0]  # ceil(100 / 32) = 4 subsets of 25
    lo1, co1, _ = net(normalize_clouds(X[:, first])[0])
    torch.testing.assert_close(lo[:, first], lo1)
    torch.testing.assert_close(co[:, first], co1)
    net.infer_points = 0
    torch.testing.assert_close(net.outputs(X)[0], net(normalize_clouds(X)[0])[0])
    assert load_run(trained_test_runs["npcs"]).module.infer_points == method.preset.points == 128  # the default
    assert load_run(trained_test_runs["npcs"], infer_points=100000).module.infer_points == 100000  # all at once
    out = method.predict_points(X.numpy())
    assert out["part_label"].shape == (2, 100) and out["part_pose"].shape == (2, 2, 4, 4)
    for bad in (-1, 8, True):
        with pytest.raises(ConfigError, match="infer_points"):
            NPCSOptions(run="x", infer_points=bad)


def test_npcs_diagnosis_ladder_is_exact_from_ground_truth_maps(trained_test_runs, laptop_data, tmp_path):
    """``bench/diagnostics/npcs_diagnosis.py``: fed the ground-truth labels and maps, NPCS-style's pose fitting and the evaluator
    give zero error (so what the ladder's other rungs lose is the network's), and every rung and map is reported."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / "npcs_diagnosis.py"
    spec = importlib.util.spec_from_file_location("npcs_diagnosis", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "ladder.json"
    assert mod.main(["--data", str(laptop_data), "--run", str(trained_test_runs["npcs"]), "--split", "test",
                     "--infer-points", "64", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    lad = next(iter(doc["runs"].values()))
    oracle = lad["rungs"]["oracle"]
    assert oracle["S"] == 100.0 and oracle["R"] < 1e-3 and oracle["D"] < 1e-3
    assert set(lad["rungs"]) == {"oracle", "net labels + GT maps", "GT labels + net maps", "net (all points)",
                                 "net (infer_points=64)"}
    assert 0.0 <= lad["maps"]["infer_points=64"]["seg_accuracy"] <= 1.0 and lad["maps_train"]["clouds"] > 0
    assert doc["provenance"]["commit"] and doc["dataset_hash"]
    assert mod.main(["--data", str(tmp_path / "none"), "--run", str(trained_test_runs["npcs"])]) == 2
    assert mod.main(["--digest", str(out)]) == 0 and mod.main(["--digest", str(tmp_path / "none.json")]) == 2
    table = mod.digest([out])
    assert "| oracle | 100.0 | 0.0 |" in table and "maps on training clouds" in table
