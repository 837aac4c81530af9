"""In-memory articulated designs and their export to URDF + OBJ meshes.

A generator returns an :class:`ArticulatedDesign` whose meshes and joints are expressed in the
object frame at rest. :func:`finalize` moves the origin to the centre of the rest-state
bounding box (the canonical frame of SPEC section 3), and :func:`write_asset` writes
``model.urdf``, ``meshes/<part>.obj`` and ``asset.json`` with byte-identical output for equal
designs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from scapo.ops.rigid import closest_point_on_line, normalize
from scapo.sim.assets.meshes import merge, to_obj_bytes

JOINT_TYPES = {"revolute": 0, "prismatic": 1}


@dataclass
class PartDesign:
    """One rigid part: a name and its meshes in the object frame at rest (metres)."""

    name: str
    meshes: list[trimesh.Trimesh]


@dataclass(frozen=True)
class JointDesign:
    """One joint between two parts, in the object frame at rest.

    Attributes:
        name: URDF joint name. type: "revolute" or "prismatic".
        parent, child: part names. axis: (3,) unit direction; positive states turn (right-hand
            rule) or slide along it. origin: (3,) a point on the axis (m). limit: (lo, hi) state
            range from rest, rad or m.
    """

    name: str
    type: str
    parent: str
    child: str
    axis: tuple[float, float, float]
    origin: tuple[float, float, float]
    limit: tuple[float, float]


@dataclass
class ArticulatedDesign:
    """A complete articulated object: parts (base part first), joints and the drawn parameters."""

    category: str
    parts: list[PartDesign]
    joints: list[JointDesign]
    params: dict = field(default_factory=dict)

    def part(self, name: str) -> PartDesign:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(f"design of {self.category!r} has no part {name!r}")

    def bounds(self) -> np.ndarray:
        """(2, 3) min/max corners of all meshes at rest."""
        allb = np.array([m.bounds for p in self.parts for m in p.meshes])
        return np.stack([allb[:, 0].min(0), allb[:, 1].max(0)])


def finalize(design: ArticulatedDesign) -> ArticulatedDesign:
    """Return a copy centred on its rest-state bounding box, with pivots closest to the origin.

    Also checks the kinematic tree: the first part is the root, each other part is the child of
    exactly one joint, and axes are unit vectors.

    Raises:
        ValueError: for an inconsistent design (a generator bug).
    """
    names = [p.name for p in design.parts]
    if len(set(names)) != len(names):
        raise ValueError(f"{design.category}: duplicate part names {names}")
    children = [j.child for j in design.joints]
    if sorted(children) != sorted(names[1:]):
        raise ValueError(f"{design.category}: every non-root part needs exactly one parent joint")
    center = design.bounds().mean(0)
    parts = []
    for p in design.parts:
        meshes = []
        for m in p.meshes:
            m = m.copy()
            m.apply_translation(-center)
            meshes.append(m)
        parts.append(PartDesign(p.name, meshes))
    joints = []
    for j in design.joints:
        axis = normalize(np.asarray(j.axis, dtype=np.float64))
        pivot = closest_point_on_line(np.asarray(j.origin) - center, axis)
        if j.type == "prismatic":
            pivot = np.zeros(3)
        joints.append(replace(j, axis=tuple(_r(axis)), origin=tuple(_r(pivot))))
    return ArticulatedDesign(design.category, parts, joints, dict(design.params))


def _r(v: np.ndarray) -> list[float]:
    """Round to 1e-9 and drop negative zeros so that text output is stable."""
    return [float(x) + 0.0 for x in np.round(np.asarray(v, dtype=np.float64), 9)]


def _fmt(v) -> str:
    return " ".join(f"{x:.9g}" for x in v)


def _link_origins(design: ArticulatedDesign) -> dict[str, np.ndarray]:
    """Object-frame position of each link frame: the root at the origin, children at their pivot."""
    out = {design.parts[0].name: np.zeros(3)}
    for j in design.joints:
        out[j.child] = np.asarray(j.origin, dtype=np.float64)
    return out


def urdf_text(design: ArticulatedDesign) -> str:
    """URDF (XML) of a finalized design; every link frame is axis-aligned with the object frame."""
    origins = _link_origins(design)
    lines = ['<?xml version="1.0"?>', f'<robot name="{design.category}">']
    for p in design.parts:
        lines += [
            f'  <link name="{p.name}">',
            "    <visual>",
            '      <origin xyz="0 0 0" rpy="0 0 0"/>',
            f'      <geometry><mesh filename="meshes/{p.name}.obj"/></geometry>',
            "    </visual>",
            "  </link>",
        ]
    for j in design.joints:
        xyz = origins[j.child] - origins[j.parent]
        lines += [
            f'  <joint name="{j.name}" type="{j.type}">',
            f'    <parent link="{j.parent}"/>',
            f'    <child link="{j.child}"/>',
            f'    <origin xyz="{_fmt(_r(xyz))}" rpy="0 0 0"/>',
            f'    <axis xyz="{_fmt(j.axis)}"/>',
            f'    <limit lower="{j.limit[0]:.9g}" upper="{j.limit[1]:.9g}" effort="100" velocity="1"/>',
            "  </joint>",
        ]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def asset_metadata(design: ArticulatedDesign, extra: dict) -> dict:
    """JSON-serialisable description of a finalized design (no paths, no timestamps)."""
    lo, hi = design.bounds()
    return {
        **extra,
        "category": design.category,
        "parts": [p.name for p in design.parts],
        "joints": [
            {
                "name": j.name,
                "type": j.type,
                "parent": j.parent,
                "child": j.child,
                "axis": list(j.axis),
                "pivot": list(j.origin),
                "limit": [float(j.limit[0]), float(j.limit[1])],
            }
            for j in design.joints
        ],
        "bbox_min": _r(lo),
        "bbox_max": _r(hi),
        "bbox_diag": float(np.round(np.linalg.norm(hi - lo), 9)),
        "params": design.params,
    }


def write_asset(design: ArticulatedDesign, out_dir: Path, extra: dict) -> dict:
    """Write ``model.urdf``, ``meshes/<part>.obj`` and ``asset.json`` into ``out_dir``.

    Each part's meshes are merged into one OBJ expressed in that part's link frame. Returns the
    metadata dict written to ``asset.json``.
    """
    out_dir = Path(out_dir)
    (out_dir / "meshes").mkdir(parents=True, exist_ok=True)
    origins = _link_origins(design)
    for p in design.parts:
        m = merge(p.meshes)
        m.apply_translation(-origins[p.name])
        (out_dir / "meshes" / f"{p.name}.obj").write_bytes(to_obj_bytes(m))
    (out_dir / "model.urdf").write_text(urdf_text(design))
    meta = asset_metadata(design, extra)
    (out_dir / "asset.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return meta
