"""Procedural assets: every category builds, same seed gives the same bytes, instances vary."""

import json
import shutil

import numpy as np
import pytest

from scapo.errors import ConfigError, MissingMeshError, UnknownNameError, URDFError
from scapo.sim.assets import build_instance, design_instance, list_categories, load_template, parse_urdf
from scapo.sim.assets.templates import parse_template

SPEC_CATEGORIES = ["laptop", "safe", "oven", "washer", "eyeglasses", "basket", "drawer", "scissors", "suitcase"]
CATEGORIES = list_categories()  # every registered category: a new one is covered without an edit here


def test_all_spec_categories_are_registered():
    assert CATEGORIES[: len(SPEC_CATEGORIES)] == SPEC_CATEGORIES


@pytest.mark.parametrize("category", CATEGORIES)
def test_build_is_byte_identical_and_canonical(category, tmp_path):
    a = build_instance(category, 0, seed=7, cache_dir=tmp_path / "a")
    b = build_instance(category, 0, seed=7, cache_dir=tmp_path / "b")
    assert a.digest == b.digest
    for f in sorted(p.relative_to(a.directory) for p in a.directory.rglob("*") if p.is_file()):
        assert (a.directory / f).read_bytes() == (b.directory / f).read_bytes(), f
    spec = parse_urdf(a.urdf)
    tpl = load_template(category)
    assert list(spec.part_names) == list(tpl.parts)
    assert [j.name for j in spec.gt_joints] == [j.name for j in tpl.joints]
    # canonical frame: origin at the centre of the rest-state bounding box
    np.testing.assert_allclose((spec.bbox_min + spec.bbox_max) / 2, 0.0, atol=1e-6)
    assert spec.bbox_diag == pytest.approx(a.bbox_diag, abs=1e-6)  # OBJ vertices carry 6 decimals (0.5 um)
    for j, jt in zip(spec.gt_joints, tpl.joints):
        assert np.linalg.norm(j.axis_obj) == pytest.approx(1.0)
        assert j.limit[0] <= 0.0 <= j.limit[1] or j.limit[0] >= 0.0  # rest is the lower end or inside
        assert j.type == (0 if jt.type == "revolute" else 1)
        if j.type == 0:  # pivot = point of the axis closest to the origin
            assert abs(j.pivot_obj @ j.axis_obj) < 1e-6


@pytest.mark.parametrize("category", CATEGORIES)
def test_instances_vary_in_shape(category, tmp_path):
    metas = [build_instance(category, i, seed=1, cache_dir=tmp_path).metadata() for i in range(4)]
    params = [m["params"] for m in metas]
    continuous = [k for k, v in params[0].items() if isinstance(v, float)]
    assert continuous, "a category needs continuous shape parameters"
    for k in continuous:
        assert len({p[k] for p in params}) > 1, f"{k} does not vary"
    assert len({round(m["bbox_diag"], 6) for m in metas}) == 4
    # a different seed draws different instances
    other = build_instance(category, 0, seed=2, cache_dir=tmp_path).metadata()["params"]
    assert other != params[0]


def test_up_axis_and_front_are_consistent_for_doors():
    # doors and lids open towards -x (front) or +z (up): check the child moves that way
    from scapo.ops.rigid import joint_motion, transform_points

    for category in ["safe", "oven", "washer", "suitcase", "drawer", "laptop"]:
        d = design_instance(category, 0, 0)
        j = d.joints[0]
        child = d.part(j.child)
        v = np.vstack([m.vertices for m in child.meshes])
        lo, hi = j.limit
        moved = transform_points(joint_motion(0 if j.type == "revolute" else 1, np.array(j.axis),
                                              np.array(j.origin), hi), v)
        shift = moved.mean(0) - v.mean(0)
        if category == "laptop":
            assert shift[0] > 0  # screen tilts back (+x) when opening further
        elif category == "suitcase":
            assert shift[2] > 0  # lid goes up
        else:
            assert shift[0] < 0  # door / drawer comes out of the front (-x)


def test_template_errors_name_the_problem(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[category]\nname = "x"\nparts = ["a", "b"]\n[params]\nw = [0.3]\n')
    with pytest.raises(ConfigError, match="params.w"):
        parse_template(bad)
    bad.write_text('[category]\nname = "x"\nparts = ["a", "b"]\n[joints.j]\ntype = "ball"\nparent = "a"\nchild = "b"\n')
    with pytest.raises(ConfigError, match="type must be"):
        parse_template(bad)
    with pytest.raises(UnknownNameError, match="unknown category 'teapot'; known: basket, drawer"):
        build_instance("teapot", 0, 0, cache_dir=tmp_path)


def _copy_asset(tmp_path, category="laptop"):
    rec = build_instance(category, 0, 0, cache_dir=tmp_path / "c")
    dst = tmp_path / "asset"
    shutil.copytree(rec.directory, dst)
    return dst


def test_malformed_urdf(tmp_path):
    d = _copy_asset(tmp_path)
    text = (d / "model.urdf").read_text()
    (d / "model.urdf").write_text(text[: len(text) // 2])
    with pytest.raises(URDFError, match="malformed URDF XML"):
        parse_urdf(d / "model.urdf")


def test_missing_mesh_is_named(tmp_path):
    d = _copy_asset(tmp_path)
    (d / "meshes" / "screen.obj").unlink()
    with pytest.raises(MissingMeshError, match="meshes/screen.obj"):
        parse_urdf(d / "model.urdf")


def test_joint_without_limits_and_unsupported_types(tmp_path):
    d = _copy_asset(tmp_path)
    text = (d / "model.urdf").read_text()
    no_limit = "\n".join(line for line in text.splitlines() if "<limit" not in line)
    (d / "model.urdf").write_text(no_limit)
    with pytest.raises(URDFError, match="without <limit"):
        parse_urdf(d / "model.urdf")
    (d / "model.urdf").write_text(text.replace('type="revolute"', 'type="floating"'))
    with pytest.raises(URDFError, match="unsupported type 'floating'"):
        parse_urdf(d / "model.urdf")
    with pytest.raises(URDFError, match="not found"):
        parse_urdf(d / "nothere.urdf")


def test_asset_json_has_no_paths_or_times(tmp_path):
    rec = build_instance("safe", 3, 0, cache_dir=tmp_path)
    meta = json.loads((rec.directory / "asset.json").read_text())
    text = json.dumps(meta)
    assert str(tmp_path) not in text and "time" not in meta
    assert meta["seed"] == 0 and meta["instance_id"] == 3
