"""The optional ManiSkill3 backend gives the SAPIEN backend's ground truth on the same object, state and camera."""

import importlib.util
import json

import numpy as np
import pytest
from gt_checks import check_sample
from scipy.spatial import cKDTree

from scapo.sim.assets import build_instance, load_template, parse_urdf
from scapo.sim.render import RenderConfig, ViewConfig, render_many

# skipped without ManiSkill3; scapo.sim.maniskill imports it in the tests, not at collection (2.5 s in each
# pytest-xdist worker)
pytestmark = [pytest.mark.render,
              pytest.mark.skipif(importlib.util.find_spec("mani_skill") is None, reason="no mani_skill")]

GT_FIELDS = ("part_pose", "joint_type", "joint_parts", "joint_axis", "joint_pivot", "joint_state", "joint_limit",
             "T_cam_obj", "bbox_diag")


@pytest.mark.parametrize("category", ["laptop", "eyeglasses", "drawer"])
def test_maniskill_ground_truth_equals_sapien(category, renderer):
    from scapo.sim.maniskill import ManiSkillRenderer, render_many_maniskill

    spec = parse_urdf(build_instance(category, 0, seed=5).urdf, category=category)
    cfg = RenderConfig()
    view = ViewConfig.from_template(load_template(category).view)
    jobs = [(v, spec, (5, 0, v)) for v in range(3)]
    ours = list(render_many(renderer, jobs, cfg, view))
    ms = ManiSkillRenderer(cfg.camera, shader=cfg.shader)
    try:
        theirs = list(render_many_maniskill(ms, jobs, cfg, view))
        np.testing.assert_allclose(ms.K, renderer.K, atol=1e-6)
    finally:
        ms.close()
    for (_, a, ra), (_, b, rb) in zip(ours, theirs):
        assert a["attempts"] == b["attempts"] and ra == rb  # the same views rejected for the same reasons
        for k in GT_FIELDS:
            np.testing.assert_allclose(a[k], b[k], atol=1e-6, err_msg=k)  # SAPIEN reports link poses in float32
        # the same surfaces: every ManiSkill point is on the SAPIEN cloud (to float rounding), with its label
        d, idx = cKDTree(a["points"]).query(b["points"])
        assert np.median(d) < 1e-5 and np.mean(d < 1e-3) > 0.98
        assert np.mean(a["part_label"][idx] == b["part_label"]) > 0.98
        check_sample(b, spec, cfg.min_part_points)


def test_generate_with_the_maniskill_backend_gives_sapiens_dataset_to_float_rounding(tmp_path):
    """``scapo generate --backend maniskill``: the same samples as SAPIEN's (ground truth to 1e-6, points on the same
    surfaces); the backend is part of the config, so a SAPIEN dataset does not resume with ManiSkill."""
    from scapo.cli.main import main
    from scapo.data import load

    args = ["generate", "--category", "laptop", "--instances", "2", "--views", "2", "--test-fraction", "0.5",
            "--val-fraction", "0", "--points", "256", "--no-progress"]
    assert main([*args, "--backend", "maniskill", "--out", str(tmp_path / "ms")]) == 0
    assert main([*args, "--out", str(tmp_path / "sp")]) == 0
    a, b = load(tmp_path / "ms", "all").arrays(), load(tmp_path / "sp", "all").arrays()
    for k in GT_FIELDS:
        np.testing.assert_allclose(a[k], b[k], atol=1e-6, err_msg=k)
    d = np.concatenate([cKDTree(q).query(p)[0] for p, q in zip(a["points"], b["points"])])
    assert np.median(d) < 1e-5 and np.mean(d < 1e-3) > 0.98
    assert json.loads((tmp_path / "ms" / "config.json").read_text())["backend"] == "maniskill"
    assert "backend" not in json.loads((tmp_path / "sp" / "config.json").read_text())  # as before the option
    assert main([*args, "--backend", "maniskill", "--out", str(tmp_path / "sp")]) == 2
    assert main([*args, "--num-envs", "4", "--out", str(tmp_path / "x")]) == 2  # sub-scenes are ManiSkill's
