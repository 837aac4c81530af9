"""Symmetries measured (scapo.data.symmetry_measure, ``scapo assets symmetry``): declared symmetries hold on the meshes, no
undeclared one does, views of the procedural objects are not explained by an undeclared pose, and hand-made cases
with known answers (a z-buffer, an undeclared flip that must be flagged, the laptop's root-exchanging twin)."""

from __future__ import annotations

import numpy as np
import pytest

from scapo.data.symmetry_measure import (
    Tolerance,
    declared_rotation,
    declared_symmetry_error,
    measure_meshes,
    object_self_maps,
    part_motions,
    sample_surface,
    surface_count,
    view_ambiguity,
    visible,
)
from scapo.errors import ConfigError
from scapo.ops.rigid import invert_transform, transform_points
from scapo.sim.assets import build_instance, list_categories, load_template, parse_urdf
from scapo.sim.assets.symmetry import SYMMETRIES, Symmetry, twin
from scapo.sim.render import CameraConfig, ViewConfig, sample_camera_pose


def _spec(category: str, instance: int = 0):
    return parse_urdf(build_instance(category, instance, seed=5).urdf, category=category)


def _K() -> np.ndarray:
    c = CameraConfig()
    f = 0.5 * c.height / np.tan(np.radians(c.fovy_deg) / 2)
    return np.array([[f, 0, c.width / 2], [0, f, c.height / 2], [0, 0, 1.0]])


def synthetic_view(category: str, instance: int, key: int, spacing: float = 0.008, points: int = 1024):
    """A depth view without a renderer: the instance's dense surface at a drawn state, seen from a camera drawn
    from the category's view ranges, reduced to its visible points (:func:`visible`); returns (sample, surface)."""
    spec = _spec(category, instance)
    rng = np.random.default_rng([key, instance])
    surf = sample_surface(spec, surface_count(spec, spacing), rng)
    lim = spec.joint_limit
    state = rng.uniform(lim[:, 0], lim[:, 1])
    T_cam_obj = invert_transform(sample_camera_pose(ViewConfig.from_template(load_template(category).view),
                                                    spec.bbox_diag, rng))
    pose = T_cam_obj @ part_motions(spec, state)
    dense = np.empty_like(surf.points)
    for p in range(spec.num_parts):
        m = surf.labels == p
        dense[m] = transform_points(pose[p], surf.points[m])
    K = _K()
    seen = np.flatnonzero(visible(dense, K, depth_slack=0.004))
    pick = rng.choice(seen, min(points, len(seen)), replace=False)
    sample = {"points": dense[pick], "part_label": surf.labels[pick], "part_pose": pose, "joint_state": state,
              "T_cam_obj": T_cam_obj, "K": K, "bbox_diag": spec.bbox_diag}
    # the measurement's own model is an independent sampling of the same surface
    return sample, sample_surface(spec, surface_count(spec, spacing), np.random.default_rng([key, instance, 1]))


def test_visible_keeps_the_surface_nearest_the_camera():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.2, 0.2, (4000, 2))
    near = np.c_[xy[:2000], np.full(2000, 1.0)]
    far = np.c_[xy[2000:], np.full(2000, 1.5)]
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    seen = visible(np.vstack([near, far]), K)
    assert seen[:2000].mean() > 0.99 and seen[2000:].mean() < 0.02  # a few random holes of the sampling
    behind = np.c_[xy[:10], np.full(10, -1.0)]  # behind the camera: never visible
    assert not visible(np.vstack([near, behind]), K)[2000:].any()


def test_an_undeclared_symmetry_is_found_on_the_meshes_and_a_declared_one_is_not_reported():
    """The basket at rest is its own half turn about z with the handles exchanged (known answer): measured with no
    declaration it is an undeclared self-map turning by 180 deg that exchanges parts 1 and 2; declared, it is not."""
    spec = _spec("basket")
    rng = np.random.default_rng(1)
    surf = sample_surface(spec, surface_count(spec, 0.015), rng)
    rest = np.zeros(spec.num_joints)
    for icp_points in (1500, 500):  # the measurement's default and the lighter one the per-category test runs
        found = object_self_maps(surf, rest, rng, icp_points=icp_points)
        assert found and abs(found[0].angle_deg - 180.0) < 5.0 and found[0].parts == (0, 2, 1)
    assert all(m.declared for m in object_self_maps(surf, rest, rng, declared=(SYMMETRIES["basket"],)))


@pytest.mark.parametrize("category", list_categories())
def test_declared_symmetries_hold_on_the_meshes_and_no_undeclared_one_does(category):
    """Every category (issue 29): no undeclared self-map of the posed meshes at rest or a drawn state, and each
    declared symmetry (the laptop's exchange, the basket's half turn) holds within its stated slack
    (``scapo assets symmetry`` measures more instances, with 1500 ICP points, and the views; results/symmetry/).
    500 ICP points here: the undeclared half turn of the basket is found with them too (the test above)."""
    rep = measure_meshes(category, instances=1, states=2, spacing=0.016, icp_points=500)
    assert rep.declared_hold, rep.lines()
    assert not any(s["maps"] for s in rep.self_maps), rep.lines()
    assert len(rep.declared) == (category in SYMMETRIES)


def test_a_measurement_with_too_few_icp_points_is_a_clear_error():
    with pytest.raises(ConfigError, match="icp_points must be >= 3"):
        measure_meshes("laptop", instances=1, states=1, icp_points=2)


def test_the_baskets_declared_symmetry_holds_exactly_and_a_wrong_declaration_fails():
    spec = _spec("basket")
    rng = np.random.default_rng(2)
    surf = sample_surface(spec, surface_count(spec, 0.012), rng)
    chk = declared_symmetry_error(surf, SYMMETRIES["basket"], rng)
    assert chk.holds and chk.offset < 0.01 and chk.angle_deg < 2.0
    wrong = Symmetry(parts=(0, 1, 2), joints=(0, 1), rotation=((1.0, 0, 0), (0, -1.0, 0), (0, 0, -1.0)), front=None)
    assert not declared_symmetry_error(surf, wrong, rng).holds  # upside down: not the basket


@pytest.mark.parametrize("category,key", [("laptop", 0), ("scissors", 0), ("suitcase", 3)])
def test_a_view_is_explained_only_by_the_truth_or_a_declared_symmetry(category, key):
    sample, surf = synthetic_view(category, instance=key % 2, key=key)
    decl = (SYMMETRIES[category],) if category in SYMMETRIES else ()
    a = view_ambiguity(sample, surf, np.random.default_rng(key), declared=decl)
    assert not a.undeclared_one_sided and not a.undeclared_two_sided, a
    if category == "laptop":
        assert a.declared  # a depth cloud leaves the laptop's base and lid open: the declared exchange explains it
        b = view_ambiguity(sample, surf, np.random.default_rng(key))  # the same flip, undeclared, must be flagged
        assert b.undeclared_one_sided and b.undeclared_two_sided and b.angle_deg > 150


def test_the_laptops_twin_exchanges_base_and_lid_at_every_state():
    """The twin of a root-exchanging symmetry: its object frame is its new base's (part_pose[0] == T_cam_obj), it is
    an involution, and it puts each part's rest geometry where the asset's exchanged part is seen (within the
    measured twin position error, 0.05 bbox diagonals)."""
    sym = SYMMETRIES["laptop"]
    spec = _spec("laptop")
    surf = sample_surface(spec, 4000, np.random.default_rng(3))
    diag = spec.bbox_diag
    for q in (-1.0, 0.0, 0.9):
        sample, _ = synthetic_view("laptop", 0, key=4)
        pose = sample["T_cam_obj"] @ part_motions(spec, np.array([q]))
        jp = spec.joint_parts
        pivot = transform_points(pose[jp[0, 0]], np.asarray(spec.gt_joints[0].pivot_obj)[None])[0]
        gt = {"part_pose": pose, "T_cam_obj": sample["T_cam_obj"], "joint_pivot": pivot[None],
              "joint_state": np.array([q]), "bbox_diag": np.float64(diag),
              "npcs": surf.points[:5] / diag, "part_label": np.array([0, 1, 1, 0, -1])}
        tw = twin(gt, sym)
        np.testing.assert_allclose(tw["T_cam_obj"], tw["part_pose"][0])
        np.testing.assert_array_equal(tw["part_label"], [1, 0, 0, 1, -1])
        back = twin(tw, sym)
        for k in ("part_pose", "T_cam_obj", "npcs"):
            np.testing.assert_allclose(back[k], gt[k], atol=1e-9, err_msg=k)
        for p, other in ((0, 1), (1, 0)):
            placed = transform_points(tw["part_pose"][p], surf.points[surf.labels == p])
            seen = transform_points(pose[other], surf.points[surf.labels == other])
            from scipy.spatial import cKDTree

            assert cKDTree(seen).query(placed)[0].mean() < 0.05 * diag
        R = declared_rotation(sym, pose)  # the whole-object map onto the twin, seen in the camera frame
        assert abs(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))) - 180.0) < 1e-4


def test_symmetry_declarations_are_checked_and_the_baskets_card_entry_is_unchanged():
    with pytest.raises(ConfigError, match="labels by view"):
        Symmetry(parts=(1, 0), joints=(0,), rotation=np.eye(3).tolist(), front=(1.0, 0, 0), center="pivot:0")
    with pytest.raises(ConfigError, match="center"):
        Symmetry(parts=(1, 0), joints=(0,), rotation=np.eye(3).tolist(), front=None, center="pivot:3")
    assert set(SYMMETRIES["basket"].to_dict()) == {"parts", "joints", "rotation", "front"}  # dataset hashes kept
    lap = SYMMETRIES["laptop"]
    assert Symmetry.from_dict(lap.to_dict()) == lap and lap.front is None


def test_tolerance_rules():
    t = Tolerance()
    assert t.same(0.0129, 0.0072) and not t.same(0.0131, 0.0072)  # 1.25 x 0.0072 + 0.004 = 0.013
    assert t.coincide(0.02) and not t.coincide(0.021)


def test_scapo_assets_symmetry_prints_the_measurement_and_refuses_bad_input(capsys, tmp_path):
    from scapo.cli.main import main

    out = tmp_path / "s.json"
    assert main(["assets", "symmetry", "--category", "scissors", "--views", "0", "--mesh-instances", "1",
                 "--states", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "declared symmetries: none" in text and "undeclared self-maps of the posed meshes: 0 of 1" in text
    assert '"provenance"' in out.read_text()
    assert main(["assets", "symmetry", "--category", "scissors", "--instances", "0"]) == 2
    assert "--instances must be >= 1" in capsys.readouterr().err
