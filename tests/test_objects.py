"""Datasets from existing objects (URDF / PartNet-Mobility): part map, scale, per-object views, previews."""

import json

import pandas as pd
import pytest
import trimesh
from gt_checks import check_sample
from test_partnet import make_partnet_fixture

from scapo.cli.main import main
from scapo.data import generate, load, make_config
from scapo.data.generate import instance_asset_path, load_instance
from scapo.errors import ConfigError

pytestmark = pytest.mark.render

CABINET = """<?xml version="1.0"?>
<robot name="cabinet_b">
  <link name="base"/>
  <link name="link_body"><visual><geometry><mesh filename="textured_objs/body.obj"/></geometry></visual></link>
  <link name="link_door"><visual><origin xyz="0 0.25 0"/><geometry><mesh filename="textured_objs/door.obj"/></geometry>
    </visual></link>
  <link name="link_d1"><visual><geometry><mesh filename="textured_objs/drawer.obj"/></geometry></visual></link>
  <link name="link_d2"><visual><geometry><mesh filename="textured_objs/drawer.obj"/></geometry></visual></link>
  <joint name="j_body" type="fixed"><parent link="base"/><child link="link_body"/></joint>
  <joint name="j_door" type="revolute"><origin xyz="-0.31 -0.25 0.2"/><axis xyz="0 0 1"/>
    <parent link="link_body"/><child link="link_door"/><limit lower="-1.6" upper="0"/></joint>
  <joint name="j_d1" type="prismatic"><origin xyz="-0.2 0 -0.05"/><axis xyz="-1 0 0"/>
    <parent link="link_body"/><child link="link_d1"/><limit lower="0" upper="0.3"/></joint>
  <joint name="j_d2" type="prismatic"><origin xyz="-0.2 0 -0.25"/><axis xyz="-1 0 0"/>
    <parent link="link_body"/><child link="link_d2"/><limit lower="0" upper="0.3"/></joint>
</robot>
"""


def make_cabinet(root):
    """A cabinet with a door (labelled 'door') over two drawers (both 'drawer'): 4 parts, not metric-sized
    differently from the fixture of test_partnet (which has 3 parts: body, door, knob on a screw joint)."""
    d = root / "cabinet_b"
    (d / "textured_objs").mkdir(parents=True)
    trimesh.creation.box([0.6, 0.5, 0.8]).export(d / "textured_objs" / "body.obj")
    trimesh.creation.box([0.02, 0.5, 0.3]).export(d / "textured_objs" / "door.obj")
    trimesh.creation.box([0.4, 0.45, 0.15]).export(d / "textured_objs" / "drawer.obj")
    (d / "mobility.urdf").write_text(CABINET)
    (d / "semantics.txt").write_text("link_body free cabinet\nlink_door hinge door\nlink_d1 slider drawer\n"
                                     "link_d2 slider drawer\n")
    (d / "meta.json").write_text(json.dumps({"model_cat": "StorageFurniture"}))
    return d


@pytest.fixture(scope="module")
def two_objects(tmp_path_factory):
    root = tmp_path_factory.mktemp("objects")
    return make_partnet_fixture(root), make_cabinet(root)


def test_objects_with_different_part_counts_form_one_category_dataset(two_objects, tmp_path):
    a, b = two_objects
    cfg = make_config(None, 0, 3, seed=1, objects=[a, b], parts="door", scale="fit:0.8", test_fraction=0.5,
                      val_fraction=0.0, min_part_fraction=0.03, view={"azimuth_deg": [-40, 40]})
    assert cfg.category == "fixturecabinet" and cfg.instances == 2
    out = tmp_path / "d"
    generate(cfg, out, progress=False)
    card = json.loads((out / "card.json").read_text())
    assert card["part_names"] == ["base", "door"] and card["joint_type"] == [0]
    assert [o["source"] for o in card["objects"]] == [str(a), str(b)]
    for split in ("train", "test"):
        ds = load(out, split)
        for i in range(len(ds)):
            s = ds[i]
            spec = load_instance(cfg, instance_asset_path(cfg, out, s["instance_id"]))
            check_sample(s, spec, cfg.render.min_part_points)  # the same GT checks as procedural assets
            assert float(s["bbox_diag"]) == pytest.approx(0.8)  # --scale fit:0.8 (metres)
    # the drawers of cabinet b and the knob of the fixture were merged into the base, at rest
    spec_b = load_instance(cfg, instance_asset_path(cfg, out, 1))
    assert spec_b.part_of_link["link_d1"] == spec_b.part_of_link["link_d2"] == 0
    assert spec_b.part_names == ("base", "door")
    # rerunning is a no-op (derived objects are rebuilt identically; their digests match the journal)
    before = (out / "card.json").read_text()
    rep = generate(cfg, out, progress=False)
    assert rep.rendered == 0 and (out / "card.json").read_text() == before


def test_part_map_errors_name_the_parts(two_objects, tmp_path):
    a, b = two_objects
    with pytest.raises(ConfigError, match=r"(?s)slot 'drawer' .* matches 2 movable parts.*part 2 'drawer'"):
        generate(make_config(None, 0, 1, objects=[b], parts="drawer"), tmp_path / "x", progress=False)
    with pytest.raises(ConfigError, match="must agree on their parts"):
        generate(make_config(None, 0, 1, objects=[a, b]), tmp_path / "y", progress=False)
    with pytest.raises(ConfigError, match="matches no movable part"):
        generate(make_config(None, 0, 1, objects=[a], parts="lid"), tmp_path / "z", progress=False)
    # a per-object pattern picks one drawer (the upper one) and the door, in slot order
    from scapo.sim.assets.objects import ObjectSource, derive_object

    d = derive_object(ObjectSource(str(b), (("drawer", "j_d1"),)), (("door", "door"), ("drawer", "drawer")), "1",
                      tmp_path / "der", "cabinet")
    assert d.spec.part_names == ("base", "door", "drawer") and d.spec.joint_type.tolist() == [0, 1]
    assert d.spec.part_of_link["link_d2"] == 0
    with pytest.raises(ConfigError, match="positive factor"):
        make_config(None, 0, 1, objects=[a], scale="fit:-1")


def test_cli_generates_and_previews_an_object_dataset(two_objects, tmp_path, capsys):
    a, b = two_objects
    opts = tmp_path / "opts.json"
    opts.write_text(json.dumps({"cabinet_b": {"view": {"azimuth_deg": [-30, 30]}}}))
    d = tmp_path / "ds"
    args = ["generate", "--object", str(a), "--object", str(b), "--parts", "door", "--scale", "fit:0.8", "--views",
            "2", "--test-fraction", "0.5", "--val-fraction", "0", "--min-part-fraction", "0.03", "--object-options",
            str(opts), "--category", "cabinet", "--out", str(d), "--no-progress"]
    assert main(args) == 0
    assert json.loads((d / "config.json").read_text())["objects"][1]["view"] == {"azimuth_deg": [-30, 30]}
    assert main(["preview", "--data", str(d), "--split", "all", "--count", "2", "--out", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").stat().st_size > 4_000  # drawn (a blank 256-colour PNG is about 1 KB)
    assert main(["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--parts", "door", "--out",
                 str(tmp_path / "bad")]) == 2
    assert "apply to existing objects" in capsys.readouterr().err
    opts.write_text(json.dumps({"cabinet_c": {}}))
    assert main(args[:-3] + ["--out", str(tmp_path / "bad2")]) == 2
    assert "not in this dataset" in capsys.readouterr().err
    m = pd.read_parquet(d / "manifest.parquet")
    assert sorted(m["instance_id"].unique()) == [0, 1] and (m["category"] == "cabinet").all()


def test_revolute_and_prismatic_parts_with_repeated_names(two_objects, tmp_path):
    """Cabinet b: a door and two drawers both labelled 'drawer' (relative mesh paths in textured_objs). A part
    map keeps the door and the upper drawer (chosen by joint name); the GT passes the procedural checks, the
    prismatic joint included. Without a part map every part is kept and the repeated names are told apart by
    index in previews."""
    from scapo.sim.assets.objects import ObjectSource
    from scapo.sim.preview import part_legend

    _, b = two_objects
    src = ObjectSource(str(b), (("drawer", "j_d1"),))
    cfg = make_config(None, 0, 4, seed=2, objects=[src], parts="door,drawer", test_fraction=0.0, val_fraction=0.0,
                      min_part_fraction=0.02, view={"azimuth_deg": [-50, 50], "distance": [1.6, 2.4]})
    out = tmp_path / "d"
    generate(cfg, out, progress=False)
    card = json.loads((out / "card.json").read_text())
    assert card["part_names"] == ["base", "door", "drawer"] and card["joint_type"] == [0, 1]
    spec = load_instance(cfg, instance_asset_path(cfg, out, 0))
    ds = load(out, "train")
    for i in range(len(ds)):
        check_sample(ds[i], spec, cfg.render.min_part_points)
    whole = make_config(None, 0, 1, objects=[b], test_fraction=0.0, val_fraction=0.0, min_part_fraction=0.01,
                        cropped="keep")
    generate(whole, tmp_path / "w", progress=False)
    names = json.loads((tmp_path / "w" / "card.json").read_text())["part_names"]
    assert names == ["base", "door", "drawer", "drawer"]  # the base of a derived object is always "base"
    assert part_legend(names) == ["base", "door", "2 drawer", "3 drawer"]


def test_bad_object_inputs(two_objects, tmp_path, capsys):
    a, _ = two_objects
    with pytest.raises(ConfigError, match="positive factor"):
        make_config(None, 0, 1, objects=[a], scale="0")
    with pytest.raises(ConfigError, match=r"(?s)matches no movable part.*joints joint_0.*joint_2a, joint_2b"):
        generate(make_config(None, 0, 1, objects=[a], parts="lid=joint_9"), tmp_path / "x", progress=False)
    broken = make_partnet_fixture(tmp_path / "broken")
    (broken / "textured_objs" / "door.obj").unlink()
    assert main(["generate", "--object", str(broken), "--views", "1", "--out", str(tmp_path / "y")]) == 2
    assert "textured_objs/door.obj" in capsys.readouterr().err
    assert main(["generate", "--object", str(tmp_path / "nothing"), "--views", "1", "--out", str(tmp_path / "z")]) == 2
    assert "no such file or folder" in capsys.readouterr().err


def test_an_object_without_a_movable_joint_is_refused_at_generation(tmp_path, capsys):
    """A rigid object once made a dataset (exit 0) on which ``scapo train`` then ended in an internal error: it is
    refused when the dataset is generated, naming the object, and nothing is written."""
    d = tmp_path / "box"
    (d / "textured_objs").mkdir(parents=True)
    trimesh.creation.box([0.3, 0.3, 0.3]).export(d / "textured_objs" / "body.obj")
    (d / "mobility.urdf").write_text('<?xml version="1.0"?><robot name="box"><link name="base"/><link name="body">'
                                     '<visual><geometry><mesh filename="textured_objs/body.obj"/></geometry></visual>'
                                     '</link><joint name="j" type="fixed"><parent link="base"/><child link="body"/>'
                                     '</joint></robot>')
    assert main(["generate", "--object", str(d), "--views", "2", "--out", str(tmp_path / "data")]) == 2
    err = capsys.readouterr().err
    assert "box" in err and "has no movable joint (a rigid object)" in err and err.count("\n") == 1
    assert not (tmp_path / "data" / "card.json").exists()


def test_the_card_says_paper_or_mixed_viewpoints_when_objects_turn_their_own_views():
    """An object's own ``object_euler_deg`` (``--object-options``) renders it in the paper's viewpoints; a dataset of
    such objects had a card saying ``upright``. Every object turned: "paper"; some: "mixed"; none: the dataset's."""
    from types import SimpleNamespace

    from scapo.data.generate import _card_viewpoints
    from scapo.sim.render import ViewConfig

    euler = {"object_euler_deg": ((-20, 20), (-180, 180), (-10, 10))}

    def cfg(viewpoints, *views):  # GenerateConfig's view_config and view_for, on ViewConfig's own translation
        own = ViewConfig(viewpoints=viewpoints, object_euler_deg=euler["object_euler_deg"]
                         if viewpoints == "paper" else None)
        return SimpleNamespace(view_config=own, objects=views, view_for=lambda i: own.with_fields(views[i]))

    assert _card_viewpoints(cfg("upright", euler, euler)) == "paper"
    assert _card_viewpoints(cfg("upright", euler, {})) == "mixed"
    assert _card_viewpoints(cfg("upright", {}, {"azimuth_deg": (-30, 30)})) == "upright"
    assert _card_viewpoints(cfg("paper", euler, {})) == "paper"
    assert _card_viewpoints(cfg("sphere")) == "sphere"
    assert _card_viewpoints(cfg("upright", {"random_rotation": True})) == "sphere"  # the older spelling
