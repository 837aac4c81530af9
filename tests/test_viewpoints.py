"""The three viewpoint settings of ``scapo generate --viewpoints`` (upright, paper, sphere) and views per training
instance (``--train-views``): the paper's Euler ranges and their composition, the redraw rule, the configs and
templates that record them, and datasets made with them."""

import dataclasses
import hashlib
import json
import math

import numpy as np
import pytest

from scapo.data.config import GenerateConfig, make_config
from scapo.errors import ConfigError, RejectedViewError
from scapo.ops.rigid import invert_transform
from scapo.sim.assets import build_instance, load_template, parse_urdf
from scapo.sim.assets.templates import asset_digest_text, parse_template, sim_assets_dir
from scapo.sim.render import (
    RenderConfig,
    ViewConfig,
    _rest_mesh,
    front_view_angle_deg,
    object_rotation,
    render_sample,
    sample_camera_pose,
)


def _angles(view: ViewConfig, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([front_view_angle_deg(invert_transform(sample_camera_pose(view, 0.5, rng))) for _ in range(n)])


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_paper_euler_ranges_give_eaps_angles_from_the_front_view():
    """+-22.5 deg per axis (HOI4D: laptop, safe): 21.6 deg from the front view on average, at most 41 deg;
    [-90, 90] per axis (Shape2Motion: eyeglasses, oven, washer): about 83 deg on average."""
    hoi = _angles(ViewConfig(viewpoints="paper", object_euler_deg=((-22.5, 22.5),) * 3), 4000)
    assert abs(hoi.mean() - 21.6) < 0.6 and hoi.max() < 41.5
    s2m = _angles(ViewConfig(viewpoints="paper", object_euler_deg=((-90.0, 90.0),) * 3), 4000)
    assert abs(s2m.mean() - 83.0) < 2.0
    for cat, ranges in (("laptop", ((-22.5, 22.5),) * 3), ("safe", ((-22.5, 22.5),) * 3),
                        ("eyeglasses", ((-90.0, 90.0),) * 3), ("oven", ((-90.0, 90.0),) * 3),
                        ("washer", ((-90.0, 90.0),) * 3)):
        pv = load_template(cat).paper_view
        assert pv.euler_deg == ranges and "equi-articulated-pose" in pv.source


def test_paper_view_is_the_level_front_view_turned_by_rz_ry_rx():
    """Hand-built: pinned angles give T_cam_obj = inv(T_front) @ [Rz Ry Rx | 0] exactly (jitter moves the camera
    without turning it), the front view looks along the object's +x with its z up, and the angle measured from
    T_cam_obj is the turn's."""
    rng = np.random.default_rng(0)
    R = object_rotation(((10.0, 10.0), (-20.0, -20.0), (30.0, 30.0)), rng)
    np.testing.assert_allclose(R, _rot("z", 30) @ _rot("y", -20) @ _rot("x", 10), atol=1e-12)
    front = ViewConfig(viewpoints="paper", object_euler_deg=((0.0, 0.0),) * 3, target_jitter=0.05)
    T = invert_transform(sample_camera_pose(front, 0.5, rng))  # T_cam_obj
    np.testing.assert_allclose(T[:3, :3] @ [1.0, 0, 0], [0, 0, 1.0], atol=1e-12)  # object +x away from the camera
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1.0], [0, -1.0, 0], atol=1e-12)  # object +z up in the picture
    assert front_view_angle_deg(T) < 1e-6
    turned = ViewConfig(viewpoints="paper", object_euler_deg=((0.0, 0.0), (0.0, 0.0), (35.0, 35.0)))
    Tt = invert_transform(sample_camera_pose(turned, 0.5, np.random.default_rng(1)))
    assert abs(front_view_angle_deg(Tt) - 35.0) < 1e-6
    np.testing.assert_allclose(Tt[:3, :3], T[:3, :3] @ _rot("z", 35), atol=1e-12)
    # the bbox centre (object origin) stays on the optical axis, at the drawn distance (no jitter)
    tc = invert_transform(sample_camera_pose(dataclasses.replace(turned, target_jitter=0.0), 0.5,
                                             np.random.default_rng(2)))[:3, 3]
    assert abs(tc[0]) < 1e-9 and abs(tc[1]) < 1e-9 and 1.4 * 0.5 <= tc[2] <= 2.4 * 0.5


def test_a_view_that_hides_a_part_is_rejected_and_redrawn(renderer):
    """Hand-built: the safe seen from its front keeps its door; turned half a turn about z (its back to the camera)
    the door is hidden and the view is rejected, so that the generator draws another one."""
    spec = parse_urdf(build_instance("safe", 0, seed=0).urdf)
    state = np.zeros(len(spec.gt_joints))
    cfg = RenderConfig()
    for yaw, hidden in ((0.0, False), (180.0, True)):
        view = ViewConfig(distance=(1.8, 1.8), viewpoints="paper",
                          object_euler_deg=((0.0, 0.0), (0.0, 0.0), (yaw, yaw)))
        rng = np.random.default_rng(0)
        T_world_cam = sample_camera_pose(view, spec.bbox_diag, rng)
        if hidden:
            with pytest.raises(RejectedViewError, match="part 1 'door'"):
                render_sample(renderer, spec, cfg, view, rng, state=state, T_world_cam=T_world_cam)
        else:
            s = render_sample(renderer, spec, cfg, view, rng, state=state, T_world_cam=T_world_cam)
            assert np.bincount(s["part_label"], minlength=2).min() >= cfg.min_part_points


def test_viewpoint_configs_keep_older_hashes_and_refuse_contradictions():
    """upright and sphere configs are those of datasets made before the settings existed (no new keys: their hashes
    and the archived datasets stay valid); paper records its ranges and round-trips; contradictions and missing
    ranges are refused with the flag to use."""
    up = make_config("laptop", 10, 4, 0).to_dict()
    sphere = make_config("laptop", 10, 4, 0, random_rotation=True)
    assert "object_euler_deg" not in up["view"] and "train_views" not in up
    assert sphere.to_json() == make_config("laptop", 10, 4, 0, viewpoints="sphere").to_json()
    assert "object_euler_deg" not in sphere.to_dict()["view"]
    paper = make_config("oven", 10, 4, 0, viewpoints="paper", train_views=9)
    again = GenerateConfig.from_dict(json.loads(paper.to_json()))
    assert again.to_json() == paper.to_json() and again.view == paper.view and again.views_train == 9
    assert again.view_config.viewpoints == "paper"
    assert paper.to_dict()["view"]["object_euler_deg"] == [[-90.0, 90.0]] * 3
    own = make_config("laptop", 10, 4, 0, viewpoints="paper", euler_deg=((-5.0, 5.0), (0.0, 0.0), (-90.0, 90.0)))
    assert own.view_config.object_euler_deg == ((-5.0, 5.0), (0.0, 0.0), (-90.0, 90.0))
    assert make_config("laptop", 10, 4, 0, train_views=4).to_json() == make_config("laptop", 10, 4, 0).to_json()
    with pytest.raises(ConfigError, match="contradicts --viewpoints paper"):
        make_config("laptop", 10, 4, 0, viewpoints="paper", random_rotation=True)
    with pytest.raises(ConfigError, match="--euler"):
        make_config("basket", 10, 4, 0, viewpoints="paper")  # no [paper_view] in its template
    with pytest.raises(ConfigError, match="give it with --viewpoints paper"):
        make_config("laptop", 10, 4, 0, euler_deg=((0.0, 1.0),) * 3)
    with pytest.raises(ConfigError, match="unknown viewpoints"):
        make_config("laptop", 10, 4, 0, viewpoints="hemisphere")
    with pytest.raises(ConfigError, match="object_euler_deg"):
        ViewConfig(viewpoints="paper", object_euler_deg=((0.0, 200.0),) * 3)
    with pytest.raises(ConfigError, match="train_views"):
        make_config("laptop", 10, 4, 0, train_views=-1)


def test_the_paper_view_table_is_not_part_of_the_asset_digest(tmp_path):
    """Adding the viewpoint-only [paper_view] table kept every category's template digest (the asset cache key), so
    that the instances and the datasets rendered from them are the same."""
    path = sim_assets_dir() / "categories" / "laptop.toml"
    text = path.read_text()
    assert "[paper_view]" in text
    stripped = asset_digest_text(text)
    assert "[paper_view]" not in stripped and stripped.endswith("roll_deg = [-5.0, 5.0]\n")
    assert parse_template(path).digest == hashlib.sha256(stripped.encode()).hexdigest()
    bad = tmp_path / "laptop.toml"
    bad.write_text(stripped + "\n[paper_view]\neuler_deg = [[-10, 10], [0, 1]]\n")
    with pytest.raises(ConfigError, match="three"):
        parse_template(bad)
    bad.write_text(stripped + "\n[paper_view]\neuler_deg = [[-10, 10], [0, 1], [0, 400]]\n")
    with pytest.raises(ConfigError, match="within|\\[-180, 180\\]"):
        parse_template(bad)


@pytest.mark.parametrize("category,mean,tol,most", [("laptop", 21.6, 4.0, 45.0), ("oven", 83.0, 12.0, 180.0)])
def test_generate_paper_viewpoints_and_training_views(tmp_path, category, mean, tol, most):
    """``scapo generate --viewpoints paper``: every sample's rotation away from the level front view, measured from
    its T_cam_obj, averages the paper's (laptop about 22 deg and none over 45; oven about 83); training instances get
    ``--train-views`` views, val and test ``--views``; the card says which setting made the dataset."""
    from scapo.cli.main import main
    from scapo.data import load

    out = tmp_path / category
    assert main(["generate", "--category", category, "--instances", "5", "--views", "4", "--train-views", "12",
                 "--viewpoints", "paper", "--val-fraction", "0.2", "--test-fraction", "0.2", "--out", str(out),
                 "--no-progress"]) == 0
    card = json.loads((out / "card.json").read_text())
    assert card["viewpoints"] == "paper" and card["views_per_instance"] == {"train": 12, "val": 4, "test": 4}
    angles = []
    for split, views in (("train", 12), ("val", 4), ("test", 4)):
        ds = load(out, split)
        assert len(ds) == views * len(card["splits"][split]["instances"])
        angles += [front_view_angle_deg(ds[i]["T_cam_obj"]) for i in range(len(ds))]
    assert abs(np.mean(angles) - mean) < tol and max(angles) <= most


def test_per_object_euler_ranges_are_checked():
    """An object dataset's per-object view overrides (--object-options) take the paper's Euler ranges too, checked
    like --euler; a malformed one is a clear error naming the field."""
    from scapo.sim.assets.objects import view_overrides

    assert view_overrides({"object_euler_deg": [[-10, 10], [0, 0], [-5, 5]]}) == (
        ("object_euler_deg", ((-10.0, 10.0), (0.0, 0.0), (-5.0, 5.0))),)
    for bad in ([1, 2], [[0, 1]] * 2, [[0, 400]] * 3, "x"):
        with pytest.raises(ConfigError, match="object_euler_deg"):
            view_overrides({"object_euler_deg": bad})


def test_the_viewpoint_setting_reaches_the_renderer_as_itself():
    """``--viewpoints`` is the view's own field from make_config to sample_camera_pose (no translation into
    booleans and back); the stored config keeps the older keys (their hashes hold) and reads back as the setting;
    a setting and ranges that do not go together are clear errors."""
    from scapo.sim.assets.objects import view_overrides

    for vp in ("upright", "sphere", "paper"):
        cfg = make_config("laptop", 10, 4, 0, viewpoints=vp)
        assert cfg.view_config.viewpoints == vp
        stored = cfg.to_dict()["view"]
        assert "viewpoints" not in stored and stored["random_rotation"] is (vp == "sphere")
        assert GenerateConfig.from_dict(json.loads(cfg.to_json())).view_config == cfg.view_config
    paper = make_config("laptop", 10, 4, 0, viewpoints="paper").view_config
    T = invert_transform(sample_camera_pose(dataclasses.replace(paper, target_jitter=0.0), 0.5,
                                            np.random.default_rng(0)))
    assert front_view_angle_deg(T) < 42  # the turn of the laptop's +-22.5 deg ranges, never the upright elevation
    with pytest.raises(ConfigError, match="need the object's Euler ranges"):
        ViewConfig(viewpoints="paper")
    with pytest.raises(ConfigError, match="need the object's Euler ranges"):
        ViewConfig(object_euler_deg=((0.0, 0.0),) * 3)  # ranges without the setting
    with pytest.raises(ConfigError, match="unknown viewpoints"):
        ViewConfig(viewpoints="hemisphere")
    assert view_overrides({"viewpoints": "sphere"}) == (("viewpoints", "sphere"),)
    assert ViewConfig().with_fields(dict(view_overrides({"random_rotation": True}))).viewpoints == "sphere"
    with pytest.raises(ConfigError, match="needs the object's Euler ranges too"):
        view_overrides({"viewpoints": "paper"})
    with pytest.raises(ConfigError, match="is not one of"):
        view_overrides({"viewpoints": "above"})


def test_parts_alone_renders_every_part_in_a_scene_of_its_own(renderer):
    """Hand-built (EAP's data regime, --parts-alone): the safe seen from its back hides its door (a scene view is
    rejected), while the door rendered alone is seen from behind; from the front the door hides the body's cavity,
    which the body rendered alone shows (more body points). Every pooled point lies on its own part (its rest
    coordinates inside that part's mesh bounds), and the loaded object keeps every part visible afterwards."""
    spec = parse_urdf(build_instance("safe", 0, seed=0).urdf)
    state = np.zeros(len(spec.gt_joints))
    alone = RenderConfig(parts_alone=True)

    def view(yaw):
        return ViewConfig(distance=(1.8, 1.8), viewpoints="paper", object_euler_deg=((0.0, 0.0), (0.0, 0.0),
                                                                                      (yaw, yaw)))

    with pytest.raises(RejectedViewError, match="part 1 'door'"):
        render_sample(renderer, spec, RenderConfig(), view(180.0), np.random.default_rng(0), state=state)
    back = render_sample(renderer, spec, alone, view(180.0), np.random.default_rng(0), state=state)
    assert np.bincount(back["part_label"], minlength=2).min() >= alone.min_part_points
    front = render_sample(renderer, spec, RenderConfig(), view(0.0), np.random.default_rng(0), state=state)
    front_alone = render_sample(renderer, spec, alone, view(0.0), np.random.default_rng(0), state=state,
                                keep_images=True)
    assert (front_alone["part_label"] == 0).sum() > (front["part_label"] == 0).sum() + 100
    assert front_alone["image_part_map"].shape == (RenderConfig().camera.height, RenderConfig().camera.width)
    for s in (back, front_alone):
        for p in range(spec.num_parts):
            mesh = _rest_mesh(spec, p)
            lo, hi = mesh.bounds / spec.bbox_diag
            q = s["npcs"][s["part_label"] == p]
            assert ((q > lo - 0.01) & (q < hi + 0.01)).all()
    again = render_sample(renderer, spec, RenderConfig(), view(0.0), np.random.default_rng(0), state=state)
    np.testing.assert_array_equal(again["points"], front["points"])


def test_parts_alone_is_recorded_and_refused_where_it_cannot_apply(tmp_path):
    """The config and card record --parts-alone (a config without it keeps its hash); it needs rendered views with
    the clean sensor and the SAPIEN backend."""
    from scapo.data import generate

    plain = make_config("laptop", 4, 2, 0)
    assert "parts_alone" not in plain.to_dict()["render"]
    cfg = make_config("laptop", 3, 2, 0, parts_alone=True, num_points=256, val_fraction=0.0, test_fraction=0.34)
    assert cfg.to_dict()["render"]["parts_alone"] is True and cfg.to_json() != plain.to_json()
    assert GenerateConfig.from_dict(json.loads(cfg.to_json())).render.parts_alone
    generate(cfg, tmp_path / "d", progress=False)
    card = json.loads((tmp_path / "d" / "card.json").read_text())
    assert card["parts_alone"] is True and card["config"]["render"]["parts_alone"] is True
    for kw, msg in (({"complete": True}, "--parts-alone"), ({"sensor": "realistic"}, "--parts-alone"),
                    ({"backend": "maniskill"}, "leave out --backend maniskill")):
        with pytest.raises(ConfigError, match=msg):
            make_config("laptop", 4, 2, 0, parts_alone=True, **kw)
