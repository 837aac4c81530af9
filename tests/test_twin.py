"""From one view to a URDF: a twin exported from ground-truth-perfect predictions has the object's joints and
re-renders like the observation."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from scapo.errors import ConfigError, PredictionError
from scapo.eval.predictions import Predictions
from scapo.ops.rigid import invert_transform
from scapo.sim.assets import load_partnet_mobility
from scapo.sim.render import RenderConfig, ViewConfig, render_sample
from scapo.twin import export_twin

pytestmark = pytest.mark.render


def oracle(data, split="test"):
    from scapo.data import load

    ds = load(data, split)
    a = ds.arrays()
    return Predictions(method="oracle", instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(len(ds), split),
                       part_label=a["part_label"], part_pose=a["part_pose"], joint_parts=a["joint_parts"],
                       joint_type=a["joint_type"], joint_axis=a["joint_axis"], joint_pivot=a["joint_pivot"],
                       joint_state=a["joint_state"], T_cam_obj=a["T_cam_obj"], dataset_hash=ds.dataset_hash)


def rerender(twin_dir, renderer, state=None):
    """The twin rendered from the observed camera at the predicted state (or ``state``): camera-frame points."""
    spec = load_partnet_mobility(twin_dir)
    t = json.loads((twin_dir / "twin.json").read_text())
    q = np.array([j["state"] for j in t["joints"]]) if state is None else np.asarray(state)
    rest = np.array([j.rest_qpos for j in spec.gt_joints])
    T_world_cam = spec.T_obj_root @ invert_transform(np.array(t["T_cam_root"]))
    cfg = RenderConfig(min_part_fraction=0.0, num_points=4096)
    s = render_sample(renderer, spec, cfg, ViewConfig(), np.random.default_rng(0), q - rest, T_world_cam)
    return spec, s["points"].astype(np.float64)


def test_twin_of_perfect_predictions_has_the_objects_joints_and_looks_like_the_view(laptop_data, tmp_path, renderer):
    from scapo.data import load
    from scapo.sim.assets import build_instance, parse_urdf

    ds = load(laptop_data, "test")
    rep = export_twin(laptop_data, oracle(laptop_data), 0, tmp_path / "twin")
    item = ds[0]
    gt = parse_urdf(build_instance("laptop", item["instance_id"], seed=3).urdf)
    spec = load_partnet_mobility(tmp_path / "twin")
    assert spec.num_parts == 2 and spec.joint_type.tolist() == gt.joint_type.tolist()
    np.testing.assert_allclose(spec.gt_joints[0].axis_obj, gt.gt_joints[0].axis_obj, atol=1e-6)
    # the axis line is the object's: the GT pivot lies on the twin's axis (both in the rest frame, which the
    # twin's root frame is for perfect predictions, up to its own bbox centring)
    twin_pivot = spec.gt_joints[0].pivot_obj - spec.T_obj_root[:3, 3]
    gt_pivot = gt.gt_joints[0].pivot_obj - gt.T_obj_root[:3, 3]
    d = twin_pivot - gt_pivot
    assert np.linalg.norm(d - (d @ gt.gt_joints[0].axis_obj) * gt.gt_joints[0].axis_obj) < 1e-6
    # re-rendered at the observed state from the observed camera, it covers the observation
    _, pts = rerender(tmp_path / "twin", renderer)
    obs = item["points"].astype(np.float64)
    d_obs, _ = cKDTree(pts).query(obs)
    assert np.median(d_obs) < 0.01 * item["bbox_diag"] and np.mean(d_obs < 0.03 * item["bbox_diag"]) > 0.9
    assert rep.parts == ["base", "screen"] and rep.joints[0]["type"] == "revolute"
    # and it moves like the object: opened 0.3 rad further, both rendered from the observed camera
    from scapo.sim.render import render_sample as rs

    q = np.array([j["state"] for j in rep.joints]) + 0.3
    _, twin_pts = rerender(tmp_path / "twin", renderer, state=q)
    cfg = RenderConfig(min_part_fraction=0.0, num_points=4096)
    true = rs(renderer, gt, cfg, ViewConfig(), np.random.default_rng(0), item["joint_state"] + 0.3,
              invert_transform(item["T_cam_obj"]))["points"].astype(np.float64)
    d1, _ = cKDTree(true).query(twin_pts)
    assert np.median(d1) < 0.01 * item["bbox_diag"]  # what the twin shows is on the true object


def test_three_part_eyeglasses_export(tmp_path):
    from scapo.data import generate, make_config

    data = tmp_path / "eyeglasses"
    generate(make_config("eyeglasses", 2, 2, seed=1, test_fraction=0.5, val_fraction=0.0, cropped="keep",
                         min_part_fraction=0.03), data, progress=False)
    rep = export_twin(data, oracle(data), 1, tmp_path / "twin")
    spec = load_partnet_mobility(tmp_path / "twin")
    assert spec.num_parts == 3 and spec.joint_type.tolist() == [0, 0] and len(rep.joints) == 2
    from scapo.data import load

    gt_axes = load(data, "test")[1]
    R0 = np.asarray(rep.T_cam_root)[:3, :3]
    for j, joint in enumerate(spec.gt_joints):  # the twin's axes, in the camera, are the observed ones
        np.testing.assert_allclose(R0 @ joint.axis_obj, gt_axes["joint_axis"][j], atol=1e-6)


def test_bad_export_inputs(laptop_data, tmp_path):
    with pytest.raises(ConfigError, match="out of range"):
        export_twin(laptop_data, oracle(laptop_data), 10_000, tmp_path / "a")
    preds = oracle(laptop_data)
    preds.dataset_hash = "f" * 64
    with pytest.raises(PredictionError, match="not on"):
        export_twin(laptop_data, preds, 0, tmp_path / "b")


def test_cli_export_and_assets_check(laptop_data, tmp_path, capsys):
    from scapo.cli.main import main

    pred = tmp_path / "p.npz"
    oracle(laptop_data).save(pred)
    assert main(["export", "--data", str(laptop_data), "--pred", str(pred), "--sample", "1", "--out",
                 str(tmp_path / "twin")]) == 0
    assert "joint0 revolute 0->1" in capsys.readouterr().out
    assert main(["assets", "check", str(tmp_path / "twin")]) == 0
    assert "parts=['base', 'screen']" in capsys.readouterr().out
    assert main(["export", "--data", str(laptop_data), "--pred", str(pred), "--sample", "99", "--out",
                 str(tmp_path / "t2")]) == 2
    assert "out of range" in capsys.readouterr().err


def test_render_and_compare_scores_separate_a_right_from_a_wrong_articulation(laptop_data, tmp_path, renderer):
    from scapo.twin import score_twin

    right = oracle(laptop_data)
    export_twin(laptop_data, right, 2, tmp_path / "right")
    good = score_twin(tmp_path / "right", renderer)
    assert good["twin_mask_iou"] > 0.85 and good["twin_chamfer"] < 0.02 and good["twin_depth_cm"] < 1.0
    assert good["twin_moved_mask_iou"] > 0.8
    wrong = oracle(laptop_data)  # the same parts and poses, the hinge turned by 90 deg about the view axis
    from scapo.ops.rigid import normalize

    wrong.joint_axis = np.stack([normalize(np.cross(a, [0.0, 0.0, 1.0])) for a in wrong.joint_axis[:, 0]])[:, None]
    export_twin(laptop_data, wrong, 2, tmp_path / "wrong")
    bad = score_twin(tmp_path / "wrong", renderer)
    # the twin is its rest geometry moved by its joints: a wrong hinge shows at the observed state already (the
    # child turned about the wrong line) and more so once moved
    assert bad["twin_mask_iou"] < good["twin_mask_iou"] - 0.05
    assert bad["twin_moved_mask_iou"] < good["twin_moved_mask_iou"] - 0.05


def test_evaluate_twin_columns(laptop_data, tmp_path, capsys):
    from scapo.cli.main import main

    pred = tmp_path / "p.npz"
    oracle(laptop_data).save(pred)
    assert main(["evaluate", "--data", str(laptop_data), "--pred", str(pred), "--twin", "--twin-limit", "3",
                 "--out", str(tmp_path / "t")]) == 0
    assert "twin_moved_mask_iou" in capsys.readouterr().out
    import pandas as pd

    per = pd.read_csv(tmp_path / "t" / "table1_twin.csv")
    assert len(per) == 3 and (per["twin_mask_iou"] > 0.8).all()
    assert "Provenance" in (tmp_path / "t" / "table1_twin.md").read_text()


def test_twin_links_carry_mass_from_their_hull_and_a_second_export_leaves_no_stale_mesh(laptop_data, tmp_path):
    import xml.etree.ElementTree as ET

    import trimesh

    from scapo.twin.export import DENSITY

    out = tmp_path / "twin"
    (out / "meshes").mkdir(parents=True)
    (out / "twin.json").write_text("{}")  # an earlier twin, with a part this one does not have
    (out / "meshes" / "part7.obj").write_text("v 0 0 0\n")
    export_twin(laptop_data, oracle(laptop_data), 0, out)
    assert not (out / "meshes" / "part7.obj").exists()
    root = ET.parse(out / "mobility.urdf").getroot()
    for link in root.iter("link"):
        mesh = trimesh.load(out / link.find("visual/geometry/mesh").get("filename"), force="mesh")
        mass = float(link.find("inertial/mass").get("value"))
        assert mass == pytest.approx(max(mesh.volume * DENSITY, 1e-3), rel=1e-3)
        com = [float(v) for v in link.find("inertial/origin").get("xyz").split()]
        np.testing.assert_allclose(com, mesh.center_mass, atol=1e-6)
        inertia = link.find("inertial/inertia")
        assert all(float(inertia.get(k)) > 0 for k in ("ixx", "iyy", "izz"))


def test_a_twin_without_a_moving_part_is_a_clear_error(laptop_data, tmp_path):
    from scapo.errors import ConfigError

    preds = oracle(laptop_data)
    preds.part_label[:] = np.where(preds.part_label >= 0, 0, -1)  # every point given to the base
    with pytest.raises(ConfigError, match="no moving part"):
        export_twin(laptop_data, preds, 0, tmp_path / "twin")


def test_an_export_interrupted_by_a_full_disk_leaves_nothing_that_refuses_the_rerun(laptop_data, tmp_path,
                                                                                      monkeypatch):
    """After a disk-full export, freeing space and running it again was refused: the half-written folder's leftover
    temporary (the write probe's ``.scapo-write-test.tmp-<pid>``) counted as the user's file. The probe is removed
    even when its write fails, and an interrupted export's temporaries of dead processes are cleaned."""
    import errno
    import subprocess

    import scapo.files as files

    out = tmp_path / "twin"
    out.mkdir()
    real_open = open

    def full_disk(path, mode="r", *a, **k):
        f = real_open(path, mode, *a, **k)
        if ".scapo-write-test.tmp-" in str(path):
            f.close()
            raise OSError(errno.ENOSPC, "No space left on device")
        return f

    monkeypatch.setattr(files, "open", full_disk, raising=False)
    with pytest.raises(Exception, match="No space left on device"):
        export_twin(laptop_data, oracle(laptop_data), 0, out)
    monkeypatch.undo()
    assert list(out.iterdir()) == []  # the probe is gone
    dead = subprocess.Popen(["true"])
    dead.wait()
    (out / f".mobility.urdf.tmp-{dead.pid}").write_text("half")  # a temporary of a killed export
    export_twin(laptop_data, oracle(laptop_data), 0, out)
    assert (out / "twin.json").is_file() and not list(out.glob(".*tmp-*"))
