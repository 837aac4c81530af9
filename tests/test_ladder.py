"""The canonical-frame ladder: complete clouds (``--complete``), rest states, one shape, frame consistency, variants
and a small end-to-end ladder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from scapo.bench.ladder import RUNGS, parse_variant, rung_config
from scapo.data import generate, load, make_config
from scapo.errors import ConfigError
from scapo.ops.groups import random_rotation as _random_rotation


def random_rotation(n: int, seed: int):
    import torch

    return _random_rotation(n, generator=torch.Generator().manual_seed(seed))


@pytest.fixture(scope="module")
def complete_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("complete") / "laptop"
    generate(make_config("laptop", 4, 3, seed=2, complete=True, viewpoints="sphere", test_fraction=0.25,
                         val_fraction=0.0, num_points=512), out, progress=False)
    return out


def _surface_distance(ds, i):
    """Distance of every point of sample ``i`` to its part's rest mesh, after undoing the part's pose."""
    from scapo.data.config import GenerateConfig
    from scapo.data.generate import instance_asset_path, load_instance
    from scapo.sim.assets.urdf import load_part_mesh

    cfg = GenerateConfig.from_dict(ds.card["config"])
    s = ds[i]
    spec = load_instance(cfg, instance_asset_path(cfg, ds.root, int(s["instance_id"])))
    d = np.zeros(len(s["points"]))
    for p in range(spec.num_parts):
        m = s["part_label"] == p
        inv = np.linalg.inv(s["part_pose"][p])
        rest = s["points"][m] @ inv[:3, :3].T + inv[:3, 3]
        d[m] = _distance_to_faces(load_part_mesh(spec, p), rest)
    return d, s


def _distance_to_faces(mesh: trimesh.Trimesh, pts: np.ndarray) -> np.ndarray:
    """Per point, the smallest distance to the plane of a face whose triangle holds the point's projection (inf when
    no face does): zero for points sampled on the mesh."""
    tri = mesh.triangles  # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rel = pts[:, None] - tri[None, :, 0]  # (P, F, 3)
    h = np.einsum("pfi,fi->pf", rel, n)
    proj = pts[:, None] - h[..., None] * n[None]
    bary = trimesh.triangles.points_to_barycentric(np.repeat(tri[None], len(pts), 0).reshape(-1, 3, 3),
                                                   proj.reshape(-1, 3)).reshape(len(pts), len(tri), 3)
    inside = (bary > -1e-6).all(-1)
    return np.where(inside, np.abs(h), np.inf).min(1)


def test_complete_clouds_lie_on_every_part_and_both_sides(complete_data):
    ds = load(complete_data, "train")
    assert ds.card["config"]["render"]["complete"] is True
    for i in (0, len(ds) - 1):
        d, s = _surface_distance(ds, i)
        assert (s["part_label"] >= 0).all()
        assert set(np.unique(s["part_label"])) == {0, 1}  # every part sampled
        assert d.max() < 1e-4 * float(s["bbox_diag"]) + 1e-6  # on the posed mesh
        # complete: both faces of the thin base slab carry points, not only the side facing the camera. In the base's
        # rest frame its thickness is along z: points above and below its mid-plane.
        base = s["part_label"] == 0
        inv = np.linalg.inv(s["part_pose"][0])
        z = (s["points"][base] @ inv[:3, :3].T + inv[:3, 3])[:, 2]
        mid = 0.5 * (z.min() + z.max())
        assert (z > mid).mean() > 0.2 and (z < mid).mean() > 0.2


def test_complete_clouds_follow_area(complete_data):
    """Area-weighted sampling: each part's share of the points is near its share of the posed surface."""
    from scapo.data.config import GenerateConfig
    from scapo.data.generate import instance_asset_path, load_instance
    from scapo.sim.assets.urdf import load_part_mesh

    ds = load(complete_data, "train")
    cfg = GenerateConfig.from_dict(ds.card["config"])
    s = ds[0]
    spec = load_instance(cfg, instance_asset_path(cfg, ds.root, int(s["instance_id"])))
    area = np.array([load_part_mesh(spec, p).area for p in range(spec.num_parts)])
    share = np.bincount(s["part_label"], minlength=spec.num_parts) / len(s["part_label"])
    assert np.allclose(share, area / area.sum(), atol=0.1)


def test_rest_state_and_one_shape(tmp_path):
    out = tmp_path / "one"
    generate(make_config("laptop", 4, 2, seed=2, complete=True, viewpoints="sphere", state="rest", one_shape=True,
                         test_fraction=0.25, val_fraction=0.0, num_points=256), out, progress=False)
    ds = load(out, "train")
    a = ds.arrays(["joint_state", "bbox_diag"])
    assert np.all(a["joint_state"] == 0.0)
    assert len(set(np.round(a["bbox_diag"], 9))) == 1  # one shape for every instance
    assert len(set(ds.card["assets"].values())) == 1  # every instance's asset digest is instance 0's


def test_new_settings_keep_older_config_hashes():
    """The defaults of --complete, --state and --one-shape leave a config's dict as before they existed."""
    d = make_config("laptop", 10, 2, seed=1).to_dict()
    assert "complete" not in d["render"] and "state" not in d["render"] and "one_shape" not in d
    d = make_config("laptop", 10, 2, seed=1, complete=True, state="rest", one_shape=True).to_dict()
    assert d["render"]["complete"] is True and d["render"]["state"] == "rest" and d["one_shape"] is True


def test_bad_settings_are_refused():
    with pytest.raises(ConfigError, match="state"):
        make_config("laptop", 10, 2, state="open")
    with pytest.raises(ConfigError, match="sensor"):
        make_config("laptop", 10, 2, complete=True, sensor="realistic")
    with pytest.raises(ConfigError, match="backend"):
        make_config("laptop", 10, 2, complete=True, backend="maniskill")


def test_rungs_differ_in_one_setting_each():
    cfgs = {r: rung_config("laptop", r, 20, 2, 4, 1).to_dict() for r in RUNGS}
    for a in cfgs.values():  # the same sizes and splits on every rung
        assert (a["instances"], a["views"], a["train_views"], a["test_fraction"], a["val_fraction"]) == (20, 2, 4, 0.2,
                                                                                                         0.1)
    assert cfgs["one"]["one_shape"] and cfgs["one"]["render"]["state"] == "rest"
    assert cfgs["complete"]["render"]["complete"] and "one_shape" not in cfgs["complete"]
    assert "complete" not in cfgs["paper"]["render"] and cfgs["paper"]["view"]["object_euler_deg"]
    assert cfgs["sphere"]["view"]["random_rotation"] and "complete" not in cfgs["sphere"]["render"]
    # aligned: the complete rung without the rotation (every Euler range is 0, so the frame is given)
    assert cfgs["aligned"]["render"]["complete"] and "one_shape" not in cfgs["aligned"]
    assert cfgs["aligned"]["view"]["object_euler_deg"] == [[0.0, 0.0]] * 3
    assert "random_rotation" not in cfgs["aligned"]["view"] or not cfgs["aligned"]["view"]["random_rotation"]


def test_a_cells_consistency_is_scored_again_when_it_predates_the_twin_object_frame(tmp_path, monkeypatch):
    """``_upgrade``: a record of a category that declares a symmetry, written before ``CONSISTENCY_VERSION`` 2, gets
    its two frame-consistency shares again from its own predictions (its resampling column kept); a current record,
    or one of a category without a symmetry, is returned as it is."""
    import scapo.bench.ladder as ladder
    from scapo.eval import Predictions

    calls = []
    monkeypatch.setattr(ladder, "split_consistency", lambda data, preds: calls.append(preds) or (0.25, 0.75))
    monkeypatch.setattr(Predictions, "load", staticmethod(lambda path: "predictions"))
    for name, card in (("sym", {"symmetry": {"parts": [1, 0]}}), ("plain", {})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "card.json").write_text(json.dumps(card))
    old = {"method": "npcs", "seed": 0, "dataset_hash": "h", "S": 50.0, "frame_consistency": 0.2,
           "frame_consistency_sym": 0.3, "resampling_deg": 4.0}
    for name in ("sym", "plain"):
        (tmp_path / f"{name}_s0.json").write_text(json.dumps(old))
    assert ladder._upgrade(tmp_path / "plain_s0.json", tmp_path / "plain", "npcs", None) == old and not calls
    rec = ladder._upgrade(tmp_path / "sym_s0.json", tmp_path / "sym", "npcs", None)
    assert calls == ["predictions"] and rec["frame_consistency"] == 0.25 and rec["frame_consistency_sym"] == 0.75
    assert rec["resampling_deg"] == 4.0 and rec["consistency_version"] == ladder.CONSISTENCY_VERSION == 2
    assert json.loads((tmp_path / "sym_s0.json").read_text()) == rec  # written back
    assert ladder._upgrade(tmp_path / "sym_s0.json", tmp_path / "sym", "npcs", None) == rec and len(calls) == 1


def test_a_variant_may_train_another_preset_with_its_own_speed_file():
    from scapo.bench.ladder import speed_file, variant_preset

    assert variant_preset({"preset": "cpu-laptop", "lr": "0.002"}, "cpu") == ("cpu-laptop", {"lr": "0.002"})
    assert variant_preset({"lr": "0.002"}, "cpu") == ("cpu", {"lr": "0.002"})
    work = Path("w")
    assert speed_file(work, "scapo") == work / "speed_scapo.json"
    a, b = speed_file(work, "scapo", sets={"lr": "0.002"}), speed_file(work, "scapo", sets={"lr": "0.003"})
    assert a != b and a.name.startswith("speed_scapo_v") and a == speed_file(work, "scapo", sets={"lr": "0.002"})


def test_parse_variant():
    assert parse_variant("scapo:cons:losses.consensus=1,losses.align=0") == (
        "scapo", "cons", {"losses.consensus": "1", "losses.align": "0"})
    for bad in ("scapo", "scapo:cons", "scapo::a=1", "scapo:a b:x=1", "scapo:x:novalue"):
        with pytest.raises(ConfigError):
            parse_variant(bad)


def test_ladder_end_to_end(tmp_path, capsys, monkeypatch):
    """A tiny ladder (one rung, NPCS-style and a variant of it at their test presets) writes its table and resumes
    without recomputing; a speed file measured on another kind of CPU is set aside and measured again. (In this
    process, as the compute curve's test: two interpreters' start took half its time.)"""
    from scapo.cli.main import main

    cmd = ["bench", "ladder", "--category", "laptop", "--rungs", "one",
           "--methods", "npcs", "--variant", "npcs:wide:lr=0.002", "--preset", "test", "--budget-minutes", "0.05",
           "--instances", "10", "--views", "2", "--train-views", "8", "--work", str(tmp_path / "w"), "--out",
           str(tmp_path / "o"), "--no-progress", "--workers", "1"]  # rendered in this process (no pool to start)
    assert main(cmd) == 0, capsys.readouterr().err
    table = json.loads((tmp_path / "o" / "ladder_laptop.json").read_text())
    rows = {(x["rung"], x["method"]) for x in table["records"]}
    assert rows == {("one", "npcs"), ("one", "npcs:wide")}
    for x in table["records"]:
        assert 0.0 <= x["frame_consistency"] <= 1.0 and x["split"] == "val" and x["provenance"]["commit"]
        # the compute ledger: every phase charged, within 110 % of the 0.05 core-minutes, and its inference time
        assert x["ledger"]["unit"] == "core-seconds" and {"setup", "stage1/steps"} <= set(x["ledger"]["phases"])
        assert 0 < x["charged_min"] <= 1.1 * 0.05 and x["plan"]["budget_s"] == 3.0 and x["infer_ms_per_cloud"] > 0
    # the variant's speed and one-time work are measured on their own (a variant can cost more than its base)
    assert len(list((tmp_path / "w" / "ladder").glob("speed_npcs_test_cpu_v*.json"))) == 1
    md = (tmp_path / "o" / "ladder_laptop.md").read_text()
    assert "frame cons." in md and "npcs:wide" in md and "first rung below" in md and "charged min" in md
    capsys.readouterr()
    assert main(cmd) == 0 and "measuring" not in capsys.readouterr().out
    assert json.loads((tmp_path / "o" / "ladder_laptop.json").read_text())["records"] == table["records"]
    # a speed file measured on another kind of CPU is kept aside and measured again on this one
    speed = next(p for p in (tmp_path / "w" / "ladder").glob("speed_npcs*.json") if "cpu_v" not in p.name)
    rows = json.loads(speed.read_text())
    speed.write_text(json.dumps([{**r, "cpu_kind": "Other CPU, family 1 model 2, avx2"} for r in rows]))
    import scapo.bench.perf as perf
    from scapo.bench.ladder import _training_presets

    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: rows)  # the measurement, as this machine made it
    data = next((tmp_path / "w" / "ladder" / "data").iterdir())
    _training_presets(["npcs"], data, 0.05, "test", tmp_path / "w" / "ladder")
    out = capsys.readouterr().out
    assert f"{speed.name} was measured on another kind of CPU (Other CPU, family 1 model 2, avx2; this is" in out
    assert len(list(speed.parent.glob(speed.stem + ".*.other-cpu.json"))) == 1
    from scapo.provenance import cpu_kind

    assert {r["cpu_kind"] for r in json.loads(speed.read_text())} == {cpu_kind()}


@pytest.mark.parametrize("args,match", [
    (["--rungs", "bogus"], "unknown rung"),
    (["--rungs", "one", "--variant", "scapo"], "METHOD:LABEL"),
    (["--rungs", "one", "--variant", "icp:x:a=1"], "not trained"),
    (["--rungs", "one", "--budget-minutes", "0"], "budget"),
    (["--rungs", "one", "--budget-minutes", "1e9"], "at most 10080"),
    (["--rungs", "one,one"], "given twice"),
    (["--rungs", "one", "--methods", "npcs,npcs"], "given twice"),
    (["--rungs", "one", "--variant", "scapo:x:no_such_field=1"], "no_such_field"),
])
def test_ladder_refuses_bad_arguments(tmp_path, capsys, args, match):
    from scapo.cli.main import main

    assert main(["bench", "ladder", "--work", str(tmp_path / "w"), "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not (tmp_path / "w" / "ladder" / "data").exists()  # refused before any work


def test_frame_spread_separates_view_dependence_from_shape_dependence():
    """``bench/diagnostics/frame_spread.py``: offsets that differ only between instances have no within-instance spread; offsets
    that differ only between the views of each instance have instance means near the common one."""
    import importlib.util

    from scipy.spatial.transform import Rotation

    spec = importlib.util.spec_from_file_location("frame_spread", Path(__file__).resolve().parents[1] / "bench" /
                                                  "diagnostics" / "frame_spread.py")
    fs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fs)
    inst = np.repeat(np.arange(4), 6)
    per_instance = Rotation.from_euler("z", np.array([[-30.0], [-10.0], [10.0], [30.0]]), degrees=True).as_matrix()[inst]
    shape = fs.spread_stats(per_instance, inst)
    assert shape["median_within_instance_deg"] < 1e-3 and shape["median_instance_means_to_common_deg"] > 9
    views = Rotation.from_euler("x", np.tile([-20.0, 20.0], 12)[:, None], degrees=True).as_matrix()
    view = fs.spread_stats(views, inst)
    assert view["median_within_instance_deg"] == 20.0 and view["median_instance_means_to_common_deg"] < 1e-3
    # the centre: a predicted centre that moves with half the visible mean's move, and frames that deviate where it does
    rng = np.random.default_rng(0)
    visible = rng.normal(size=(24, 3)) * 0.02
    cs = fs.centre_stats(np.broadcast_to(np.eye(3), (24, 3, 3)).copy(), 0.5 * visible + 0.1, visible, inst)
    assert abs(cs["centre_on_visible_slope"] - 0.5) < 1e-9
    still = fs.centre_stats(views, np.full((24, 3), 0.1), visible, inst)  # a fixed centre: no move, slope 0
    assert still["median_centre_move_mm"] == 0.0 and still["centre_on_visible_slope"] == 0.0
    # the state: frames that turn about the joint axis (object z) by 0.5 x the joint state, plus a turn about x that
    # the state does not explain
    state = np.radians(rng.uniform(-60, 60, 24))
    turn = Rotation.from_euler("zx", np.c_[0.5 * np.degrees(state), rng.normal(0, 5, 24)], degrees=True).as_matrix()
    st = fs.state_stats(turn, np.tile([0.0, 0.0, 2.0], (24, 1)), state)
    assert abs(st["about_joint_on_state_slope"] - 0.5) < 0.05 and st["about_joint_state_r2"] > 0.95
    assert abs(fs.state_stats(views, np.tile([0.0, 0.0, 1.0], (24, 1)), state)["about_joint_on_state_slope"]) < 1e-6


def _bench_script(name: str):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_frame_by_state_splits_the_symmetry_aware_inliers_by_joint_state_and_ground_truth():
    """``bench/diagnostics/frame_by_state.py``: one canonical frame through the own ground truth at low states and through the twin
    at middle ones, and frames of their own at high states: the bins show where the frame holds, own / twin which
    ground truth it holds through."""
    from scapo.eval.frames import frame_inliers

    mod = _bench_script("frame_by_state")
    M = 60
    gt = np.tile(np.eye(4), (M, 2, 1, 1))
    gt[:, 0, :3, :3] = random_rotation(M, seed=1).numpy()
    gt[:, 1, :3, :3] = random_rotation(M, seed=2).numpy()  # each sample's twin
    offset = random_rotation(1, seed=3).numpy()[0]
    state = np.linspace(-1.0, 1.0, M)
    pred = gt[:, 0].copy()
    pred[:, :3, :3] = gt[:, 0, :3, :3] @ offset.T
    pred[20:40, :3, :3] = gt[20:40, 1, :3, :3] @ offset.T
    pred[40:, :3, :3] = random_rotation(20, seed=4).numpy()
    edges = mod.state_bins(state, 3)
    assert len(edges) == 4 and edges[0] == -1.0 and edges[-1] == 1.0
    r = mod.by_state(*frame_inliers(pred, gt), state, edges)
    assert r["sym"] == pytest.approx(40 / 60, abs=1e-3) and r["own"] == pytest.approx(20 / 60, abs=1e-3)
    assert r["twin"] == pytest.approx(20 / 60, abs=1e-3)
    assert [b["sym"] for b in r["bins"]] == [1.0, 1.0, 0.0] and [b["samples"] for b in r["bins"]] == [20, 20, 20]
    assert r["outlier_deg_median"] > 15
    # the frames between base and child: 0 the base's, 1 the child's, 0.5 half the joint's turn from each
    from scipy.spatial.transform import Rotation

    poses = np.tile(np.eye(4), (M, 2, 1, 1))
    poses[:, 0, :3, :3] = gt[:, 0, :3, :3]
    turn = Rotation.from_rotvec(np.c_[np.zeros(M), state, np.zeros(M)]).as_matrix()  # the joint about y by the state
    poses[:, 1, :3, :3] = gt[:, 0, :3, :3] @ turn
    assert np.allclose(mod.joint_frames(poses, 0.0), poses[:, 0]) and np.allclose(mod.joint_frames(poses, 1.0),
                                                                                   poses[:, 1])
    half = mod.joint_frames(poses, 0.5)[:, :3, :3]
    assert np.allclose(half @ half.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.allclose(half @ (gt[:, 0, :3, :3].transpose(0, 2, 1) @ half), poses[:, 1, :3, :3], atol=1e-9)


def test_the_frame_branches_find_two_frames_a_half_turn_apart():
    from scipy.spatial.transform import Rotation

    mod = _bench_script("frame_branches")
    rng = np.random.default_rng(0)
    base = Rotation.from_rotvec([0.3, -0.2, 0.1])
    small = Rotation.from_rotvec(rng.normal(scale=np.radians(2), size=(30, 3)))
    half = Rotation.from_rotvec([np.pi, 0, 0])
    offsets = np.concatenate([(base * small[:18]).as_matrix(), (base * half * small[18:]).as_matrix()])
    b = mod.branches(offsets)
    assert [x["size"] for x in b] == [18, 12]
    assert b[0]["angle_deg"] == 0 and b[1]["angle_deg"] == pytest.approx(180, abs=8)
    assert abs(b[1]["axis"][0]) == pytest.approx(1, abs=0.1)  # about x: the half turn's axis
    assert [x["size"] for x in mod.branches(offsets[:18])] == [18]  # one frame: one branch


def test_the_frame_branches_refuse_missing_inputs(tmp_path, capsys):
    mod = _bench_script("frame_branches")
    assert mod.main(["--data", str(tmp_path / "none"), "--pred", f"x={tmp_path / 'p.npz'}", "--out",
                     str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_the_seed_bootstrap_gives_each_row_its_seeds_spread_and_the_supported_differences(tmp_path, capsys):
    """``bench/diagnostics/seed_bootstrap.py``: a row's mean over its seeds with their standard deviation (ddof 1); a
    clear difference held by every seed is supported, one that a single seed shows is not; bad input ends in a
    scapo: message and writes nothing."""
    import dataclasses

    import pandas as pd

    from scapo.eval.evaluator import EvalResult
    from scapo.eval.tables import pairwise_bootstrap

    mod = _bench_script("seed_bootstrap")
    rng = np.random.default_rng(0)

    def result(label, seed, S):
        n = 15 * 8
        ps = pd.DataFrame({"instance_id": np.repeat(np.arange(15), 8), "view_id": np.tile(np.arange(8), 15),
                           "S": S + rng.normal(0, 2, n), "D": np.full(n, 10.0), "R_p0": np.full(n, 5.0)})
        return EvalResult(label, "laptop", "val", ps, {"S": float(ps.S.mean()), "D_median": 10.0, "R_median": 5.0,
                                                       "frame_consistency": 0.5 + seed / 10}, info={"seed": seed})

    res = [result("good", s, 80.0 + s) for s in range(3)] + [result("weak", s, 50.0 + s) for s in range(3)]
    res += [result("lucky", s, 50.0 + (40.0 if s == 0 else 0.0)) for s in range(3)]  # one seed far ahead
    table = mod.rows(res)
    assert table["good"]["seeds"] == [0, 1, 2]
    assert table["good"]["S"]["mean"] == pytest.approx(np.mean([r.summary["S"] for r in res[:3]]))
    assert table["good"]["frame_consistency"]["std"] == pytest.approx(0.1)
    boot = pairwise_bootstrap([dataclasses.replace(r) for r in res], draws=400)
    pairs = {(p["a"], p["b"]): p for p in boot["metrics"]["S"]}
    assert pairs[("good", "weak")]["supported"] and pairs[("good", "weak")]["better"] == "good"
    assert not pairs[("weak", "lucky")]["supported"]  # the draws without the lucky seed have no difference
    lines = mod.render(table, boot, "val", "laptop_paper")
    assert any("| good | 0, 1, 2 |" in ln for ln in lines) and any("val instances" in ln for ln in lines)
    assert mod.main(["--data", str(tmp_path / "none"), "--pred", f"x={tmp_path / 'p.npz'}", "--out",
                     str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_template_registration_finds_the_start_that_fits_and_refuses_bad_input(tmp_path, capsys):
    """A lopsided cloud turned by a half turn is registered back to its template from the cube-rotation start that
    fits (the identity start alone cannot undo a half turn); bad arguments end in a scapo: message, nothing written."""
    import torch
    from scipy.spatial.transform import Rotation

    from scapo.ops.groups import rotation_group

    mod = _bench_script("template_registration")
    g = torch.Generator().manual_seed(0)
    U = torch.randn(200, 3, generator=g) * torch.tensor([0.5, 0.2, 0.1])
    U = torch.cat([U, torch.tensor([[0.8, 0.3, 0.05]]) + 0.05 * torch.randn(40, 3, generator=g)])  # a lump off-axis
    U = U - U.mean(0)
    Q = torch.tensor(Rotation.from_rotvec([0.0, 0.0, 3.0]).as_matrix(), dtype=torch.float32)  # 172 deg about z
    S = (U @ Q.T)[None]  # the template turned: the registration must turn it back by Q^T
    O = torch.tensor(rotation_group("O"), dtype=torch.float32)
    R, res, _ = mod.icp_starts(S, U, O)
    assert float(torch.linalg.matrix_norm(R[0] - Q.T)) < 0.05 and float(res[0]) < 1e-4
    R1, res1, _ = mod.icp_starts(S, U, torch.eye(3)[None])
    assert float(res1[0]) > 10 * float(res[0])
    (tmp_path / "x.npz").write_bytes(b"")
    pred = f"a={tmp_path / 'x.npz'}"
    assert mod.main(["--rounds", "0", "--data", str(tmp_path), "--pred", pred, "--out", str(tmp_path / "o")]) == 2
    assert "--rounds must be at least 1" in capsys.readouterr().err
    assert mod.main(["--data", str(tmp_path / "none"), "--pred", "a=x.npz", "--out", str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_part_confusion_reads_a_view_level_exchange_of_mirror_parts():
    """Predictions that are the truth with the two temples exchanged in half of the views: the best assignment keeps
    the order, the exchange fits better in half of the views, and the better of the two per view is exact."""
    mod = _bench_script("part_confusion")
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 3, size=(10, 60))
    pred = labels.copy()
    swap = pred[5:].copy()
    pred[5:][swap == 1], pred[5:][swap == 2] = 2, 1
    perm, miou = mod.best_assignment(pred, labels, 3)
    assert perm[0] == 0 and 0.6 < miou < 0.8
    C = mod.confusion(pred, labels, perm, 3)
    assert C[0, 0] == pytest.approx(1.0) and C.sum(1) == pytest.approx(np.ones(3))
    kept = 0.5 * (mod.iou(pred == perm[1], labels == 1) + mod.iou(pred == perm[2], labels == 2))
    exchanged = 0.5 * (mod.iou(pred == perm[2], labels == 1) + mod.iou(pred == perm[1], labels == 2))
    assert np.maximum(kept, exchanged) == pytest.approx(np.ones(10)) and float((exchanged > kept).mean()) == 0.5


def test_part_confusion_refuses_bad_bins_and_missing_inputs(tmp_path, capsys):
    mod = _bench_script("part_confusion")
    (tmp_path / "x.npz").write_bytes(b"")
    pred = f"a={tmp_path / 'x.npz'}"
    for bins in ("0", "0,50,20", "a,b"):
        assert mod.main(["--bins", bins, "--data", str(tmp_path), "--pred", pred, "--out", str(tmp_path / "o")]) == 2
        assert "--bins" in capsys.readouterr().err
    assert mod.main(["--data", str(tmp_path / "none"), "--pred", pred, "--out", str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_pseudo_label_confusion_scores_a_runs_split_labels(laptop_data, tmp_path, capsys):
    """A run's split_labels.npy that is the training split's truth with the two parts exchanged in every other view
    scores half right under the one best assignment and is written with its sha256; a run without the file, labels
    of the wrong shape and bad --bins end in a scapo: message with nothing written."""
    import json

    from scapo.data import load

    mod = _bench_script("pseudo_label_confusion")
    truth = load(laptop_data, "train").arrays(["part_label"])["part_label"]
    labels = truth.copy()
    labels[::2] = np.where(truth[::2] >= 0, 1 - truth[::2], -1)  # base <-> lid in every other view
    run = tmp_path / "run"
    run.mkdir()
    np.save(run / "split_labels.npy", labels)
    points = np.arange(0, truth.shape[1], 2)  # the template: every other point of sample 3, its split the truth
    np.savez(run / "template_split.npz", sample=np.int64(3), points=points, labels=truth[3][points],
             labels_refit=1 - truth[3][points])
    R = load(laptop_data, "train").arrays(["T_cam_obj"])["T_cam_obj"][:, :3, :3].copy()
    R[1] = 0.0  # a cloud without a target; the others the true rotations turned by one offset: one frame
    np.save(run / "frame_targets.npy", R @ np.diag([1.0, -1.0, -1.0]))
    out = tmp_path / "res" / "plc"
    assert mod.main(["--data", str(laptop_data), "--run", f"r={run}", "--out", str(out)]) == 0
    rec = json.loads(out.with_suffix(".json").read_text())
    row = rec["rows"]["r"]
    assert row["views"] == len(truth) and row["confusion"][0][1] == pytest.approx(0.5, abs=0.1)
    t = row["template"]
    assert t["sample"] == 3 and t["labels"]["mean_iou"] == 1.0 and t["labels_refit"]["mean_iou"] == 1.0
    assert t["labels_refit"]["assignment"] == [1, 0] and sum(t["true_part_points"]) == len(points)
    assert row["frame_targets"] == {"with_target": round(1 - 1 / len(truth), 4), "consistency": 1.0}
    assert rec["predictions"]["r"]["file"].endswith("split_labels.npy") and "Pseudo-label" in out.with_suffix(
        ".md").read_text()
    capsys.readouterr()
    bad = tmp_path / "bad"
    bad.mkdir()
    assert mod.main(["--data", str(laptop_data), "--run", f"b={bad}", "--out", str(tmp_path / "o")]) == 2
    assert "has no split_labels.npy" in capsys.readouterr().err
    np.save(bad / "split_labels.npy", labels[:, :5])
    assert mod.main(["--data", str(laptop_data), "--run", f"b={bad}", "--out", str(tmp_path / "o")]) == 2
    assert "the dataset the run was trained on" in capsys.readouterr().err
    np.save(bad / "split_labels.npy", labels)
    (bad / "template_split.npz").write_bytes(b"PK\x03\x04 not a zip")  # a corrupt archive
    assert mod.main(["--data", str(laptop_data), "--run", f"b={bad}", "--out", str(tmp_path / "o")]) == 2
    assert "template_split.npz cannot be read" in capsys.readouterr().err
    assert mod.main(["--bins", "3,1", "--data", str(laptop_data), "--run", f"r={run}", "--out", str(tmp_path / "o")]) == 2
    assert "--bins" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_a_cell_over_its_budget_is_refused_and_the_others_are_computed(tmp_path, monkeypatch):
    """A cell refused by the compute ledger (:class:`~scapo.errors.BudgetError`) does not stop the ladder: the other
    cells are computed and their table written, then the command ends with the refusal."""
    from scapo.bench import ladder
    from scapo.errors import BudgetError

    def cell(data, work, category, rung, method, seed, *a, **k):
        if seed == 0:
            raise BudgetError(f"cell {category}/{rung}/{method}_s0 charged 1000 core-seconds, more than 110 %")
        return {"rung": rung, "method": method, "seed": seed, "frame_consistency": 0.5, "frame_consistency_sym": 0.5,
                "alignment_inlier_ratio": None, "resampling_deg": None, "S": 50.0, "D": 1.0, "D_median": 1.0, "C": 0.1,
                "R": 1.0, "R_median": 1.0, "R_sym": 1.0, "R_sym_median": 1.0, "R_sym_over90": 0.0,
                "wall": {"train_steps": 10}, "provenance": {"commit": "c"}, "dataset_hash": "h"}

    monkeypatch.setattr(ladder, "_finished_dataset", lambda folder, cfg: True)
    monkeypatch.setattr(ladder, "_training_presets", lambda *a, **k: {})
    monkeypatch.setattr(ladder, "_cell", cell)
    with pytest.raises(BudgetError, match="(?s)1 cell\\(s\\) refused.*npcs_s0"):
        ladder.run_ladder("laptop", ["npcs"], ["paper"], [0, 1], work=tmp_path / "w", out=tmp_path / "o")
    table = json.loads((tmp_path / "o" / "ladder_laptop.json").read_text())
    assert [r["seed"] for r in table["records"]] == [1]


def test_a_finished_cell_is_not_reused_for_another_dataset_schedule_or_budget(tmp_path):
    """A ladder or compute cell is found by rung, method and seed; ``check_reuse`` refuses it for a run of another
    dataset, schedule or budget (a table at 0.2 core-minutes once came back with the 0.05-minute cell, silently), and
    a record that is damaged (truncated, ``[]``, a field missing, NaN) is a clear error naming the file."""
    from scapo.bench.ladder import check_reuse, read_record
    from scapo.errors import ConfigError

    rec = {"method": "npcs", "seed": 0, "dataset_hash": "a" * 64, "S": 50.0, "frame_consistency": 0.5,
           "budget_values": {"epochs": 3}, "plan": {"budget_s": 3.0}}
    path = tmp_path / "npcs_s0.json"
    check_reuse(rec, path, "a" * 64, {"epochs": 3}, 3.0)  # the same conditions: reused
    for kw, what in (({"data_hash": "b" * 64}, "dataset aaaaaaaaaaaa (asked: bbbbbbbbbbbb)"),
                     ({"values": {"epochs": 12}}, "schedule {'epochs': 3} (asked: {'epochs': 12})"),
                     ({"budget_s": 12.0}, "a budget of 0.05 minutes (asked: 0.2)")):
        args = {"data_hash": "a" * 64, "values": {"epochs": 3}, "budget_s": 3.0, **kw}
        with pytest.raises(ConfigError, match=r"finished cell .*npcs_s0.json was made with " + re.escape(what)):
            check_reuse(rec, path, args["data_hash"], args["values"], args["budget_s"])
    from scapo.provenance import cpu_kind  # a trained cell charged in core-seconds of another kind of CPU

    charged = {**rec, "ledger": {"unit": "core-seconds", "charged_s": 3.0}, "provenance": {"cpu_kind": cpu_kind()}}
    check_reuse(charged, path, "a" * 64, {"epochs": 3}, 3.0)
    for prov, what in (({"cpu_kind": "Other CPU, family 1 model 2, avx2"}, "core-seconds of Other CPU, family 1 model "
                        f"2, avx2 (this machine: {cpu_kind()})"), ({}, "core-seconds of a kind of CPU not recorded")):
        with pytest.raises(ConfigError, match=r"npcs_s0.json was made with " + re.escape(what)):
            check_reuse({**charged, "provenance": prov}, path, "a" * 64, {"epochs": 3}, 3.0)
    for text, why in (('{"method": "np', "Unterminated string"), ("[]", "a JSON list, not an object"),
                      (json.dumps({**rec, "S": float("nan")}), "field 'S' is nan"),
                      (json.dumps({k: v for k, v in rec.items() if k != "dataset_hash"}), "no field 'dataset_hash'")):
        path.write_text(text)
        with pytest.raises(ConfigError, match=rf"the cell record .*npcs_s0.json is damaged \({why}"):
            read_record(path)


def test_a_speed_file_of_another_dataset_or_damaged_is_refused_naming_it(tmp_path):
    """The ladder's speed file is named by the dataset it was measured on (two categories' ladders share a work
    folder); one whose rows name another dataset, or a damaged one, is refused with what to do."""
    from scapo.bench.ladder import _speed_rows, speed_file
    from scapo.errors import ConfigError

    data = tmp_path / "laptop_one_i10_v2_t8_s0"
    assert speed_file(tmp_path, "npcs", data=data).name == "speed_npcs_laptop_one_i10_v2_t8_s0.json"

    class Split(list):
        pass

    import scapo.data as sd

    orig = sd.load
    sd.load = lambda d, split: Split(range(40))
    try:
        row = {"method": "npcs", "batch_size": 4, "stage1_clouds_per_s": 10.0, "data": str(data), "train_clouds": 40}
        path = tmp_path / "speed.json"
        path.write_text(json.dumps([row]))
        assert _speed_rows(path, "npcs", data) == [row]
        path.write_text(json.dumps([{**row, "data": "/w/eyeglasses_one_i10_v2_t8_s0"}]))
        with pytest.raises(ConfigError, match=r"speed.json belongs to another dataset .*laptop_one_i10_v2_t8_s0 \(40"):
            _speed_rows(path, "npcs", data)
        assert _speed_rows(path, "npcs", data, check=False) is None
        for text, why in (("[]", "no row of npcs"), ("{}", "not a list of rows"),
                          (json.dumps([{**row, "stage1_clouds_per_s": float("nan")}]), "field 'stage1_clouds_per_s'")):
            path.write_text(text)
            with pytest.raises(ConfigError, match=rf"speed.json is damaged \({why}"):
                _speed_rows(path, "npcs", data)
    finally:
        sd.load = orig


def test_a_budget_folder_is_named_by_the_exact_budget():
    """``--budgets 0.05,0.05000001`` once put two budgets in one cell folder (``b{budget:g}``)."""
    from scapo.bench.compute import budget_dir

    assert budget_dir("w", 5.0).name == "b5" and budget_dir("w", 2.5).name == "b2.5"
    assert budget_dir("w", 0.05).name == "b0.05" and budget_dir("w", 0.05000001).name == "b0.05000001"


def test_a_narrower_rerun_does_not_replace_a_table_and_zero_sizes_are_refused(tmp_path, capsys):
    """A rerun into the same --out that would rewrite the table without rows it holds is refused before any work
    (``--methods icp`` once dropped the npcs rows); ``--views 0`` and its kin are errors, not the defaults; the ladder's
    default output is the work folder's, never the committed results/."""
    from scapo.bench.ladder import check_table_rows
    from scapo.cli.main import main
    from scapo.errors import ConfigError

    table = tmp_path / "ladder_laptop.json"
    table.write_text(json.dumps({"records": [{"rung": "one", "method": "npcs", "seed": 0},
                                             {"rung": "one", "method": "icp", "seed": 0}]}))
    check_table_rows(table, {("one", "npcs", 0), ("one", "icp", 0), ("one", "icp", 1)}, ("rung", "method", "seed"),
                     "scapo bench ladder")  # a wider run: fine
    with pytest.raises(ConfigError, match=r"holds 1 row\(s\) this run does not make \(\('one', 'npcs', 0\); as rung, "
                                          r"method, seed\), which rewriting it would lose"):
        check_table_rows(table, {("one", "icp", 0)}, ("rung", "method", "seed"), "scapo bench ladder")
    args = ["bench", "ladder", "--category", "laptop", "--rungs", "one", "--methods", "icp", "--work",
            str(tmp_path / "w"), "--out", str(tmp_path), "--dry-run"]
    assert main(args) == 0  # a dry run writes nothing, so it is not refused
    assert main([*args[:-1]]) == 2
    assert "holds 1 row(s) this run does not make" in capsys.readouterr().err
    for flag in ("--views", "--instances", "--train-views"):
        assert main([*args, flag, "0"]) == 2
        assert f"{flag} must be >= 1, got 0" in capsys.readouterr().err
    assert main(["bench", "ladder", "--category", "laptop", "--rungs", "one", "--methods", "icp", "--work",
                 str(tmp_path / "w"), "--dry-run"]) == 0
    assert (tmp_path / "w" / "results").is_dir()  # the default --out: the work folder's results/


def test_too_few_training_clouds_for_the_speed_run_name_the_ladders_own_options(tmp_path, monkeypatch, capsys):
    """The speed run's error once advised "a smaller --steps", which the ladder does not take; the demo's advised
    "set batch_size", which ``scapo demo`` does not take."""
    import scapo.data
    from scapo.bench.ladder import _training_presets
    from scapo.cli.main import main
    from scapo.errors import ConfigError

    monkeypatch.setattr(scapo.data, "load", lambda data, split: [0, 1, 2])  # 3 training clouds, batch 4 (test)
    with pytest.raises(ConfigError, match=r"3 training clouds, fewer than the two batches of 4 that measuring npcs's "
                                          r"training speed needs: give more --instances or --train-views"):
        _training_presets(["npcs"], tmp_path / "laptop_one_i10_v1_t1_s0", 1.0, "test", tmp_path)
    monkeypatch.undo()
    assert main(["demo", "--instances", "2", "--out", str(tmp_path / "demo")]) == 2
    assert "give 12 training clouds, fewer than the demo preset's batch of 16: give more --instances or --views" in \
        capsys.readouterr().err
    assert not (tmp_path / "demo").exists()


def test_a_variant_of_a_method_not_in_methods_is_refused(tmp_path, capsys):
    """A ``--variant`` of a method left out of ``--methods`` was dropped without a word."""
    from scapo.cli.main import main

    assert main(["bench", "ladder", "--category", "laptop", "--rungs", "one", "--methods", "icp", "--variant",
                 "npcs:wide:lr=0.002", "--work", str(tmp_path / "w"), "--out", str(tmp_path / "o"), "--dry-run"]) == 2
    assert "'npcs' is not among --methods (icp); a variant is compared with its method's row" in \
        capsys.readouterr().err


def test_a_work_folder_inside_a_dataset_or_run_folder_is_refused(laptop_data, tmp_path, capsys):
    """``--work`` inside a dataset (or run) folder was accepted (``--out`` refuses one): the bench's own datasets and
    runs would be written among the dataset's files."""
    from scapo.cli.main import main

    for work in (laptop_data / "w", laptop_data):
        assert main(["bench", "ladder", "--category", "laptop", "--rungs", "one", "--methods", "icp", "--work",
                     str(work), "--out", str(tmp_path / "o"), "--dry-run"]) == 2
        assert "the scapo dataset folder" in capsys.readouterr().err
    assert not (laptop_data / "w").exists()


def test_a_ladder_table_of_cells_from_several_commits_is_refused():
    """The first after side of the fair race mixed cells computed by three commits' code without a word; a ladder
    or compute-curve table of several commits is refused naming them, unless --allow-mixed-commits."""
    from scapo.bench.ladder import check_one_commit
    from scapo.errors import ConfigError

    recs = [{"rung": "paper", "method": "op-align", "seed": s, "provenance": {"commit": c}}
            for s, c in ((0, "8707392aaaaa"), (1, "3609d42bbbbb"), (2, "3609d42bbbbb"))]
    check_one_commit(recs[1:])  # one commit: fine
    with pytest.raises(ConfigError, match=r"the cells come from 2 commits \(3609d42bbbbb: paper/op-align_s1, "
                                          r"paper/op-align_s2; 8707392aaaaa: paper/op-align_s0\)"):
        check_one_commit(recs)
    check_one_commit(recs, allow=True)


def test_a_ladder_table_of_trained_cells_charged_on_several_kinds_of_cpu_is_refused(monkeypatch):
    """A core-second of one kind of CPU need not buy the steps one of another buys: the provenance names the kind
    (family, model, vector unit), a
    table of trained cells charged on several kinds is refused naming them (a record without the kind counts as one),
    untrained cells (no ledger) do not count, and --allow-mixed-commits writes it anyway."""
    from scapo.bench.ladder import check_one_commit
    from scapo.errors import ConfigError
    from scapo.provenance import cpu_kind, provenance

    kind = cpu_kind()
    assert kind == provenance()["cpu_kind"] and kind.count(",") >= 1  # the name and at least family / model
    a, b = "AMD EPYC, family 25 model 17, avx512", "AMD EPYC, family 25 model 1, avx2"
    recs = [{"rung": "paper", "method": m, "seed": s, "charged_min": 15.0, "provenance": {"commit": "c", "cpu_kind": k}}
            for m, s, k in (("op-align", 0, a), ("scapo", 0, a), ("op-align", 1, b))]
    icp = {"rung": "paper", "method": "icp", "seed": None, "provenance": {"commit": "c", "cpu_kind": b}}
    check_one_commit(recs[:2] + [icp])  # one kind among the trained cells
    with pytest.raises(ConfigError, match=r"charged on 2 kinds of CPU \(AMD EPYC, family 25 model 1, avx2: "
                                          r"paper/op-align_s1; AMD EPYC, family 25 model 17, avx512: "
                                          r"paper/op-align_s0, paper/scapo_s0\)"):
        check_one_commit(recs)
    old = {"rung": "paper", "method": "eap", "seed": 0, "charged_min": 15.0, "provenance": {"commit": "c"}}
    with pytest.raises(ConfigError, match="kind not recorded: paper/eap_s0"):
        check_one_commit(recs[:2] + [old])
    check_one_commit(recs, allow=True)


def test_a_speed_run_measured_on_a_busy_machine_is_set_aside_and_the_ladder_stops(tmp_path, monkeypatch):
    """A speed run that shared its cores (a test run beside the chains: its steps' wall seconds per CPU second above
    ``MAX_WALL_PER_CPU``) has inflated CPU times too, so every cell planned from it would stop short of its budget:
    the ladder keeps it aside as ``*.busy.json`` and stops, naming what to do; a quiet one is the speed file."""
    import scapo.bench.perf as perf
    import scapo.data as sd
    from scapo.bench.ladder import MAX_WALL_PER_CPU, _training_presets, speed_file
    from scapo.errors import ConfigError

    class Split(list):
        pass

    data = tmp_path / "laptop_one_i10_v2_t8_s0"
    monkeypatch.setattr(sd, "load", lambda d, split: Split(range(40)))
    row = {"method": "npcs", "preset": "test", "batch_size": 4, "stage1_clouds_per_s": 10.0, "stage1_epochs": 2,
           "max_steps_per_epoch": 2, "fixed_s": 0.5, "unit": "core-seconds", "data": str(data), "train_clouds": 40,
           "wall_per_cpu": MAX_WALL_PER_CPU + 0.3}
    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: [row])
    with pytest.raises(ConfigError, match=r"measured on a busy machine \(its steps took 1\.55 wall seconds per CPU "
                                          r"second.*Run scapo bench ladder again with nothing else busy"):
        _training_presets(["npcs"], data, 0.05, "test", tmp_path)
    path = speed_file(tmp_path, "npcs", "test", None, {}, data)
    assert not path.exists() and len(list(tmp_path.glob(path.stem + ".*.busy.json"))) == 1
    from scapo.provenance import cpu_kind

    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: [{**row, "wall_per_cpu": 1.05,
                                                                     "cpu_kind": cpu_kind()}])
    assert "npcs" in _training_presets(["npcs"], data, 0.05, "test", tmp_path) and path.is_file()
    # a speed run of a fraction of a second of steps (a test preset's) is not held to the guard
    from scapo.bench.ladder import MIN_GUARDED_CPU_S

    path.unlink()
    short = {**row, "wall_per_cpu": 2.03, "steps_cpu_s": MIN_GUARDED_CPU_S / 20, "cpu_kind": cpu_kind()}
    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: [short])
    assert "npcs" in _training_presets(["npcs"], data, 0.05, "test", tmp_path) and path.is_file()
    path.unlink()
    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: [{**short, "steps_cpu_s": MIN_GUARDED_CPU_S}])
    with pytest.raises(ConfigError, match="measured on a busy machine"):
        _training_presets(["npcs"], data, 0.05, "test", tmp_path)
