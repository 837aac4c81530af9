"""Loading existing objects: plain URDF and the PartNet-Mobility layout (fixed joints, screw helper links)."""

import json

import numpy as np
import pytest
import trimesh
from gt_checks import check_sample

from scapo.errors import MissingMeshError, URDFError
from scapo.sim.assets import load_partnet_mobility, parse_urdf
from scapo.sim.render import RenderConfig, ViewConfig, render_with_retries

MOBILITY = """<?xml version="1.0"?>
<robot name="fixture_cabinet">
  <link name="base"/>
  <link name="link_1">
    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename="textured_objs/body.obj"/></geometry></visual>
  </link>
  <link name="link_1_top">
    <visual><origin xyz="0 0 0.32" rpy="0 0 0"/><geometry><mesh filename="textured_objs/top.obj"/></geometry></visual>
  </link>
  <link name="link_0">
    <visual><origin xyz="-0.02 0.2 0" rpy="0 0 0"/><geometry><mesh filename="textured_objs/door.obj"/></geometry></visual>
  </link>
  <link name="link_2_helper"/>
  <link name="link_2">
    <visual><origin xyz="0 0 0" rpy="0 1.5707963 0"/><geometry><mesh filename="textured_objs/knob.obj"/></geometry></visual>
  </link>
  <joint name="joint_1" type="fixed">
    <origin xyz="0 0 0" rpy="1.5707963 0 -1.5707963"/><parent link="base"/><child link="link_1"/>
  </joint>
  <joint name="joint_top" type="fixed">
    <origin xyz="0 0 0" rpy="0 0 0"/><parent link="link_1"/><child link="link_1_top"/>
  </joint>
  <joint name="joint_0" type="revolute">
    <origin xyz="-0.2 -0.2 0" rpy="0 0 0"/><axis xyz="0 0 1"/><parent link="link_1"/><child link="link_0"/>
    <limit lower="0" upper="1.5" effort="1" velocity="1"/>
  </joint>
  <joint name="joint_2a" type="prismatic">
    <origin xyz="0.05 0 0.2" rpy="0 0 0"/><axis xyz="0 0 1"/><parent link="link_1"/><child link="link_2_helper"/>
    <limit lower="0" upper="0.05" effort="1" velocity="1"/>
  </joint>
  <joint name="joint_2b" type="continuous">
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><parent link="link_2_helper"/><child link="link_2"/>
  </joint>
</robot>
"""


def make_partnet_fixture(root):
    """A small PartNet-Mobility-style object: y-up body (rotated by the fixed root joint), a door,
    and a knob on a screw joint (prismatic + continuous through a helper link without geometry)."""
    d = root / "fixture"
    (d / "textured_objs").mkdir(parents=True)
    trimesh.creation.box([0.4, 0.4, 0.3]).export(d / "textured_objs" / "body.obj")
    trimesh.creation.box([0.4, 0.4, 0.04]).export(d / "textured_objs" / "top.obj")
    trimesh.creation.box([0.02, 0.4, 0.3]).export(d / "textured_objs" / "door.obj")
    trimesh.creation.cylinder(radius=0.06, height=0.08).export(d / "textured_objs" / "knob.obj")
    (d / "mobility.urdf").write_text(MOBILITY)
    (d / "semantics.txt").write_text("link_0 hinge door\nlink_1 free body\nlink_2 screw knob\n")
    (d / "meta.json").write_text(json.dumps({"model_cat": "FixtureCabinet"}))
    return d


def test_partnet_layout_parts_and_joints(tmp_path):
    spec = load_partnet_mobility(make_partnet_fixture(tmp_path))
    assert spec.category == "FixtureCabinet"
    assert list(spec.part_names) == ["body", "door", "knob"]
    assert [(j.name, j.type, j.parent_part, j.child_part) for j in spec.gt_joints] == [
        ("joint_0", 0, 0, 1), ("joint_2a", 1, 0, 2), ("joint_2b", 0, 0, 2)]
    np.testing.assert_allclose(spec.gt_joints[2].limit, [-np.pi, np.pi])  # continuous: default range
    np.testing.assert_allclose((spec.bbox_min + spec.bbox_max) / 2, 0, atol=1e-9)


def test_partnet_object_renders_with_consistent_ground_truth(tmp_path, renderer):
    spec = load_partnet_mobility(make_partnet_fixture(tmp_path))
    cfg = RenderConfig(min_part_fraction=0.02)
    view = ViewConfig(azimuth_deg=(-180, 180), elevation_deg=(-60, 60))
    for v in range(4):
        s, _ = render_with_retries(renderer, spec, cfg, view, (9, v))
        check_sample(s, spec, cfg.min_part_points)


def test_partnet_errors(tmp_path):
    d = make_partnet_fixture(tmp_path)
    (d / "textured_objs" / "knob.obj").unlink()
    with pytest.raises(MissingMeshError, match="textured_objs/knob.obj"):
        load_partnet_mobility(d)
    with pytest.raises(URDFError, match="no mobility.urdf"):
        load_partnet_mobility(tmp_path)


def test_plain_urdf_with_package_paths_and_scale(tmp_path):
    (tmp_path / "m").mkdir()
    trimesh.creation.box([1.0, 1.0, 1.0]).export(tmp_path / "m" / "a.obj")
    (tmp_path / "r.urdf").write_text("""<robot name="r">
      <link name="a"><visual><geometry><mesh filename="package://pkg/m/a.obj" scale="0.2 0.2 0.2"/></geometry></visual></link>
      <link name="b"><visual><origin xyz="0 0 0.2"/><geometry><mesh filename="m/a.obj" scale="0.1 0.1 0.1"/></geometry></visual></link>
      <joint name="j" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="0 0 2"/>
        <limit lower="-0.05" upper="0.1"/></joint>
    </robot>""")
    # package://pkg/m/a.obj resolves relative to the URDF folder after dropping the package name
    spec = parse_urdf(tmp_path / "r.urdf")
    assert spec.part_names == ("a", "b")
    np.testing.assert_allclose(spec.gt_joints[0].axis_obj, [0, 0, 1])
    np.testing.assert_allclose(spec.bbox_max - spec.bbox_min, [0.2, 0.2, 0.35], atol=1e-9)


TWO_DRAWERS = """<?xml version="1.0"?>
<robot name="two_drawers">
  <link name="body"><visual><geometry><mesh filename="body.obj"/></geometry></visual></link>
  <link name="top"><visual><origin xyz="0.1 0 0"/><geometry><mesh filename="drawer.obj"/></geometry></visual></link>
  <link name="bottom"><visual><origin xyz="0.1 0 0"/><geometry><mesh filename="drawer.obj"/></geometry></visual></link>
  <joint name="slide_top" type="prismatic"><origin xyz="0.2 0 0.15"/><axis xyz="1 0 0"/>
    <parent link="body"/><child link="top"/><limit lower="0" upper="0.3"/></joint>
  <joint name="slide_bottom" type="prismatic"><origin xyz="0.2 0 -0.15"/><axis xyz="1 0 0"/>
    <parent link="body"/><child link="bottom"/><limit lower="0" upper="0.3"/></joint>
</robot>
"""


def test_prismatic_pivot_locates_the_slide_at_the_moving_part(tmp_path):
    """GTJoint: a prismatic joint's pivot is the point of its axis line closest to the moving part's rest bbox
    centre, so two drawers of one cabinet have two distinct lines (before: both at the object origin)."""
    from scapo.sim.assets import load_part_mesh

    trimesh.creation.box([0.4, 0.5, 0.6]).export(tmp_path / "body.obj")
    trimesh.creation.box([0.2, 0.4, 0.2]).export(tmp_path / "drawer.obj")
    (tmp_path / "o.urdf").write_text(TWO_DRAWERS)
    spec = parse_urdf(tmp_path / "o.urdf")
    # rest bbox x in [-0.2, 0.4] (the drawers stick out to 0.4), so the object frame is the URDF's shifted by
    # -0.1 in x; each drawer's centre is at (0.2, 0, +-0.15), on its own axis line
    for j, z in zip(spec.gt_joints, (0.15, -0.15)):
        assert j.type == 1
        np.testing.assert_allclose(j.axis_obj, [1, 0, 0], atol=1e-12)
        np.testing.assert_allclose(j.pivot_obj, [0.2, 0.0, z], atol=1e-9)
    # the screw joint's prismatic half of the fixture: the pivot is level with the knob along the axis
    spec = load_partnet_mobility(make_partnet_fixture(tmp_path / "p"))
    door, knob = spec.gt_joints[0], spec.gt_joints[1]
    assert abs(door.pivot_obj @ door.axis_obj) < 1e-9  # revolute: closest to the origin, as before
    b = load_part_mesh(spec, 2).bounds
    assert abs(((b[0] + b[1]) / 2 - knob.pivot_obj) @ knob.axis_obj) < 1e-9
