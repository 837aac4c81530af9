"""Datasets from existing objects: URDF files and PartNet-Mobility folders (also ManiSkill's copy).

Real objects of one category differ in their parts (cabinets with 3, 4 or 5 parts) and units
(PartNet-Mobility is not metric). To make one category dataset from several of them, each object is
turned into a *derived object* that the renderer and the ground truth use like a procedural asset:

- **Part map.** A dataset has part *slots* (``--parts door`` or ``--parts door=link_1,drawer=*drawer*``):
  slot k is part k (the base is part 0). In each object a slot selects exactly one movable part by a
  pattern (:func:`fnmatch.fnmatch`, case-insensitive) matched against the part's semantic label
  (PartNet-Mobility ``semantics.txt``), its link names and the names of the movable joints that move
  it; by default the slot's own name, so ``--parts door`` takes the part labelled "door". The joints
  that move a selected part stay movable; every other movable joint becomes fixed at its rest state
  (``qpos = 0`` clamped into its limits), so its part merges into the part it hangs from, in the end
  the base. Per-object overrides (a cabinet whose door is labelled "rotation_door") come from an
  options file. Without slots every movable part is kept, and all objects must then agree.
- **Scale.** Every length (joint and visual origins, mesh scales, prismatic limits) is multiplied by a
  factor, either given (``--scale 0.01``) or chosen per object so that its rest bounding box has a
  given diagonal in metres (``--scale fit:0.6``), so that a metric sensor model applies.
- The derived object is written as a PartNet-Mobility-layout folder (``mobility.urdf`` naming the
  source's meshes by absolute path, ``semantics.txt`` with the slot names, ``meta.json``) inside the
  dataset folder (``objects/<instance>/``), and parsed and rendered with the same code and checked by
  the same tests as procedural assets. Its digest covers the derived files and the bytes of every mesh
  it uses, so a changed source object is noticed on resume.

All objects of a dataset must end with the same parts and joint types (checked; the error names the
object and what differs).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import json
import math
import shutil
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from scapo.errors import ConfigError, URDFError
from scapo.files import atomic_write_text
from scapo.ops.rigid import joint_motion
from scapo.sim.assets.urdf import (
    MOVABLE,
    ArticulationSpec,
    load_partnet_mobility,
    parse_urdf,
)

#: URDF names tried in an object folder, in order (PartNet-Mobility; ManiSkill's copy also has the others).
URDF_NAMES = ("mobility.urdf", "mobility_cvx.urdf", "mobility_fixed.urdf")
BASE = "base"


@dataclass(frozen=True)
class ObjectSource:
    """One existing object of an object dataset.

    Attributes:
        path: absolute path of a URDF file or of an object folder (PartNet-Mobility layout, or a folder
            holding one ``.urdf``).
        parts: per-object ``(slot, pattern)`` overrides of the dataset's part map.
        view: per-object viewpoint ranges (a dict of :class:`~scapo.sim.render.ViewConfig` fields), or None
            for the dataset's.
    """

    path: str
    parts: tuple[tuple[str, str], ...] = ()
    view: tuple[tuple[str, object], ...] = ()

    @property
    def name(self) -> str:
        """The object's name: the URDF file's stem or the folder's name."""
        p = Path(self.path)
        return p.stem if p.suffix == ".urdf" else p.name

    def to_dict(self) -> dict:
        d: dict = {"path": self.path}
        if self.parts:
            d["parts"] = {k: v for k, v in self.parts}
        if self.view:
            d["view"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.view}
        return d

    @classmethod
    def from_dict(cls, d: dict | str) -> ObjectSource:
        if isinstance(d, str):
            return cls(d)
        view = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in (d.get("view") or {}).items()))
        return cls(str(d["path"]), tuple(sorted((d.get("parts") or {}).items())), view)


def parse_parts(text: str | None) -> tuple[tuple[str, str], ...]:
    """``"door,drawer=*drawer*"`` -> ``(("door", "door"), ("drawer", "*drawer*"))`` (slot order kept).

    Raises:
        ConfigError: an empty or repeated slot name, or a slot named "base".
    """
    if not text:
        return ()
    out = []
    for item in text.split(","):
        name, _, pattern = item.strip().partition("=")
        name, pattern = name.strip(), (pattern.strip() or name.strip())
        if not name:
            raise ConfigError(f"--parts {text!r}: an empty slot name; write e.g. --parts door or door=link_1")
        if name == BASE or name in [n for n, _ in out]:
            raise ConfigError(f"--parts {text!r}: slot name {name!r} is {'reserved' if name == BASE else 'repeated'}")
        out.append((name, pattern))
    return tuple(out)


def parse_scale(text: str | float) -> tuple[str, float]:
    """``"0.01"`` -> ``("factor", 0.01)``; ``"fit:0.6"`` -> ``("fit", 0.6)`` (rest bbox diagonal in metres).

    Raises:
        ConfigError: not a positive number / ``fit:<positive number>``.
    """
    s = str(text).strip()
    kind, value = ("fit", s[4:]) if s.startswith("fit:") else ("factor", s)
    try:
        v = float(value)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(f"--scale {text!r}: give a positive factor (e.g. 0.01) or fit:<bbox diagonal in metres> "
                          "(e.g. fit:0.6)")
    return kind, v


def find_urdf(path: str | Path) -> Path:
    """The URDF of an object: ``path`` itself, or in a folder :data:`URDF_NAMES` / its only ``.urdf``.

    Raises:
        URDFError: nothing found, or several candidate URDFs in a folder without a PartNet-Mobility name.
    """
    p = Path(path)
    if p.is_file():
        return p
    if not p.is_dir():
        raise URDFError(f"object {p} does not exist (give a URDF file or an object folder)")
    for n in URDF_NAMES:
        if (p / n).is_file():
            return p / n
    found = sorted(p.glob("*.urdf"))
    if len(found) == 1:
        return found[0]
    raise URDFError(f"object folder {p} holds {'no' if not found else len(found)} .urdf files"
                    + (f" ({', '.join(f.name for f in found[:4])})" if found else "")
                    + "; give the URDF file itself with --object")


def load_object(path: str | Path, category: str | None = None) -> ArticulationSpec:
    """Parse an object (URDF file or folder; semantic part names from ``semantics.txt`` when present).

    Raises:
        URDFError / MissingMeshError: as :func:`~scapo.sim.assets.urdf.parse_urdf`.
    """
    urdf = find_urdf(path)
    if (urdf.parent / "semantics.txt").is_file() or (urdf.parent / "meta.json").is_file():
        return load_partnet_mobility(urdf.parent, urdf=urdf, category=category)
    return parse_urdf(urdf, category=category)


def describe_parts(spec: ArticulationSpec) -> list[str]:
    """One line per movable part: index, semantic name, links and the joints that move it (for messages)."""
    out = []
    for k in range(1, spec.num_parts):
        links = [ln for ln, p in spec.part_of_link.items() if p == k]
        joints = [j.name for j in spec.gt_joints if j.child_part == k]
        out.append(f"part {k} {spec.part_names[k]!r} (links {', '.join(links)}; joints {', '.join(joints)})")
    return out


def select_parts(spec: ArticulationSpec, slots: tuple[tuple[str, str], ...], where: str) -> list[int]:
    """Part index of ``spec`` chosen by each slot's pattern (see the module docstring).

    Raises:
        ConfigError: a slot matches no movable part or several, or two slots the same part (the message
            lists the object's movable parts and how to choose one).
    """
    chosen = []
    for name, pattern in slots:
        pat = pattern.lower()
        hits = []
        for k in range(1, spec.num_parts):
            keys = [spec.part_names[k]] + [ln for ln, p in spec.part_of_link.items() if p == k]
            keys += [j.name for j in spec.gt_joints if j.child_part == k]
            if any(fnmatch.fnmatchcase(x.lower(), pat) for x in keys):
                hits.append(k)
        parts = "\n  ".join(describe_parts(spec)) or "(none)"
        if len(hits) != 1:
            got = "no movable part" if not hits else f"{len(hits)} movable parts ({', '.join(map(str, hits))})"
            raise ConfigError(f"{where}: part slot {name!r} (pattern {pattern!r}) matches {got}; its movable parts:\n"
                              f"  {parts}\nchoose one per object with a pattern on a label, link or joint name "
                              f"(--parts {name}=<pattern>, or 'parts' in an --object-options file)")
        if hits[0] in chosen:
            raise ConfigError(f"{where}: part slots {slots[chosen.index(hits[0])][0]!r} and {name!r} select the same "
                              f"part {hits[0]} {spec.part_names[hits[0]]!r}")
        chosen.append(hits[0])
    return chosen


def origin_strings(T: np.ndarray) -> tuple[str, str]:
    """URDF origin strings of a 4x4 pose (rpy as URDF reads it, see urdf._origin)."""
    with warnings.catch_warnings():  # at pitch +-90 deg scipy warns that roll and yaw are not unique: any pair is
        warnings.simplefilter("ignore", UserWarning)  # fine here, only the composed rotation matters
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    return " ".join(repr(float(x)) for x in T[:3, 3]), " ".join(repr(float(x)) for x in rpy)


@dataclass(frozen=True)
class DerivedObject:
    """A derived object on disk (see the module docstring).

    Attributes:
        folder: its folder (``mobility.urdf``, ``semantics.txt``, ``meta.json``). scale: the factor applied.
        digest: sha256 over its files and the meshes they name. source: the :class:`ObjectSource`.
        spec: the parsed derived object.
    """

    folder: Path
    scale: float
    digest: str
    source: ObjectSource
    spec: ArticulationSpec


def derive_object(source: ObjectSource, slots: tuple[tuple[str, str], ...], scale: str, dest: str | Path,
                  category: str) -> DerivedObject:
    """Write the derived object of ``source`` into ``dest`` (replacing it) and parse it.

    Args:
        source: the object. slots: the dataset's part map (overridden per object by ``source.parts``);
            empty keeps every movable part. scale: see :func:`parse_scale`. dest: output folder.
            category: category label of the dataset.

    Raises:
        URDFError / MissingMeshError: the source object is malformed (the message names the file).
        ConfigError: the part map cannot be applied (see :func:`select_parts`), or the object has no movable joint.
    """
    src = load_object(source.path)
    where = f"object {source.path}"
    over = dict(source.parts)
    unknown = sorted(set(over) - {n for n, _ in slots})
    if unknown:
        raise ConfigError(f"{where}: its options name part slot(s) {unknown} that the dataset does not have "
                          f"({[n for n, _ in slots] or 'no --parts'})")
    slots = tuple((n, over.get(n, p)) for n, p in slots)
    if slots:
        chosen = select_parts(src, slots, where)
        names = [n for n, _ in slots]
    else:
        chosen = list(range(1, src.num_parts))
        names = [src.part_names[k] for k in chosen]
    if not chosen or not any(j.child_part in chosen for j in src.gt_joints):
        raise ConfigError(f"{where} has no movable joint (a rigid object): the datasets are of articulated objects "
                          "(parts and joints to estimate); give an object with a revolute or prismatic joint")
    kind, value = parse_scale(scale)
    s = value / src.bbox_diag if kind == "fit" else value
    kept = [j.name for j in src.gt_joints if j.child_part in chosen]
    rest = {j.name: j.rest_qpos for j in src.gt_joints}
    slot_of = {k: i for i, k in enumerate(chosen)}
    order = {j.name: (slot_of[j.child_part], n) for n, j in enumerate(src.gt_joints) if j.name in kept}
    robot = ET.Element("robot", name=f"{source.name}")
    label = {}
    for ln, part in src.part_of_link.items():
        label[ln] = names[slot_of[part]] if part in slot_of else BASE
    for ln, vis in src.links.items():
        le = ET.SubElement(robot, "link", name=ln)
        for v in vis:
            T = v.T_link_visual.copy()
            T[:3, 3] *= s
            ve = ET.SubElement(le, "visual")
            xyz, rpy = origin_strings(T)
            ET.SubElement(ve, "origin", xyz=xyz, rpy=rpy)
            ge = ET.SubElement(ve, "geometry")
            ET.SubElement(ge, "mesh", filename=str(Path(v.mesh).resolve()),
                          scale=" ".join(repr(float(x) * s) for x in v.scale))
    joints = sorted(src.joints, key=lambda j: (0, *order[j.name]) if j.name in order else (1, 0, 0))
    for j in joints:
        T = j.T_parent_joint.copy()
        movable = j.type in MOVABLE
        if movable and j.name not in kept:  # merged: fixed at its rest state
            T = T @ joint_motion(MOVABLE[j.type], j.axis, np.zeros(3), rest[j.name])
        T[:3, 3] *= s
        jtype = j.type if (movable and j.name in kept) else "fixed"
        je = ET.SubElement(robot, "joint", name=j.name, type=jtype)
        xyz, rpy = origin_strings(T)
        ET.SubElement(je, "origin", xyz=xyz, rpy=rpy)
        ET.SubElement(je, "parent", link=j.parent)
        ET.SubElement(je, "child", link=j.child)
        if jtype != "fixed":
            ET.SubElement(je, "axis", xyz=" ".join(repr(float(x)) for x in j.axis))
        if jtype in ("revolute", "prismatic"):
            lo, hi = j.limit
            f = s if jtype == "prismatic" else 1.0
            ET.SubElement(je, "limit", lower=repr(lo * f), upper=repr(hi * f), effort="100", velocity="1")
    ET.indent(robot)
    dest = Path(dest)
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    urdf_text = '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
    sem_text = "".join(f"{ln} {'free' if label[ln] == BASE else 'slot'} {label[ln]}\n" for ln in src.links)
    meta_text = json.dumps({"model_cat": category, "source": source.path, "scale": s, "parts": names},
                           indent=1, sort_keys=True) + "\n"
    atomic_write_text(dest / "mobility.urdf", urdf_text)
    atomic_write_text(dest / "semantics.txt", sem_text)
    atomic_write_text(dest / "meta.json", meta_text)
    spec = load_partnet_mobility(dest, category=category)
    expected = (BASE, *names)
    if tuple(spec.part_names) != expected:  # a selected part without geometry of its own, or similar
        raise ConfigError(f"{where}: the derived object has parts {list(spec.part_names)}, expected {list(expected)}")
    h = hashlib.sha256()
    for text in (urdf_text, sem_text, meta_text):
        h.update(text.encode())
    for mesh in sorted({str(Path(v.mesh).resolve()) for vis in src.links.values() for v in vis}):
        h.update(hashlib.sha256(Path(mesh).read_bytes()).hexdigest().encode())
    return DerivedObject(dest, s, h.hexdigest(), source, spec)


def check_compatible(objects: list[DerivedObject]) -> None:
    """All derived objects of a dataset have the same part names, joint types and joint parts.

    Raises:
        ConfigError: naming the first object that differs from the first one and how.
    """
    ref = objects[0].spec
    for o in objects[1:]:
        s = o.spec
        for what, a, b in (("parts", list(ref.part_names), list(s.part_names)),
                           ("joint types (0 revolute, 1 prismatic)", ref.joint_type.tolist(), s.joint_type.tolist()),
                           ("joints (parent part, child part)", ref.joint_parts.tolist(), s.joint_parts.tolist())):
            if a != b:
                raise ConfigError(f"objects of one dataset must agree on their {what}: {objects[0].source.path} has "
                                  f"{a}, {o.source.path} has {b}; choose the parts with --parts so that they agree")


def list_objects(folder: str | Path) -> list[str]:
    """Objects in ``folder`` (``--objects``): its sub-folders holding a URDF and its ``.urdf`` files, sorted.

    Raises:
        ConfigError: the folder does not exist or holds no object.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"--objects {folder}: not a folder")
    out = []
    for p in sorted(folder.iterdir()):
        if p.is_dir() and (any((p / n).is_file() for n in URDF_NAMES) or len(list(p.glob("*.urdf"))) == 1):
            out.append(str(p.resolve()))
        elif p.is_file() and p.suffix == ".urdf":
            out.append(str(p.resolve()))
    if not out:
        raise ConfigError(f"--objects {folder}: no object folders (with mobility.urdf or one .urdf) or .urdf files")
    return out


def view_overrides(view: dict | None) -> tuple[tuple[str, object], ...]:
    """A per-object view dict checked against :class:`~scapo.sim.render.ViewConfig`'s fields."""
    from scapo.sim.render import VIEWPOINTS, ViewConfig

    if not view:
        return ()
    if not isinstance(view, dict):
        raise ConfigError(f"a per-object view must be a JSON object of ViewConfig fields, got {view!r}")
    fields = {f.name: f for f in dataclasses.fields(ViewConfig)}
    bad = sorted(set(view) - set(fields) - {"random_rotation"})  # random_rotation: the older "viewpoints": "sphere"
    if bad:
        raise ConfigError(f"unknown view field(s) {bad}; known: {sorted(fields)}")
    out = {}
    for k, v in view.items():
        default = fields[k].default if k in fields else False
        if k == "viewpoints":
            if v not in VIEWPOINTS:
                raise ConfigError(f"view field 'viewpoints': {v!r} is not one of {', '.join(VIEWPOINTS)}")
        elif k == "object_euler_deg":  # the paper's viewpoints: three [low, high] ranges, checked by ViewConfig
            try:
                v = ViewConfig(viewpoints="paper", object_euler_deg=v).object_euler_deg
            except (ConfigError, TypeError):
                raise ConfigError(f"view field 'object_euler_deg': {v!r} is not three ranges [low, high] of degrees "
                                  "(x, y, z) within [-180, 180], e.g. [[-22.5, 22.5], [-22.5, 22.5], [-22.5, 22.5]]"
                                  ) from None
        elif isinstance(default, tuple):  # a range: [low, high], finite, low <= high
            ok = (isinstance(v, (list, tuple)) and len(v) == 2
                  and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
                  and v[0] <= v[1])
            if not ok:
                raise ConfigError(f"view field {k!r}: {v!r} is not a range [low, high] of two finite numbers with "
                                  f"low <= high (e.g. {list(default)})")
            if k == "distance" and v[0] <= 0:
                raise ConfigError(f"view field 'distance': {v!r} must be positive (bbox diagonals)")
            v = (float(v[0]), float(v[1]))
        elif isinstance(default, bool):
            if not isinstance(v, bool):
                raise ConfigError(f"view field {k!r}: {v!r} is not true or false")
        elif not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0):
            raise ConfigError(f"view field {k!r}: {v!r} is not a non-negative number")
        out[k] = v
    if out.get("viewpoints") == "paper" and "object_euler_deg" not in out:
        raise ConfigError("a per-object view with 'viewpoints': 'paper' needs the object's Euler ranges too: add "
                          "'object_euler_deg': [[low, high], [low, high], [low, high]] (degrees, x, y, z)")
    return tuple(sorted(out.items()))
