"""Parse and validate URDF files into an :class:`ArticulationSpec` (links -> parts, joints -> GT joints).

Used for procedural assets and for existing objects (plain URDF or the PartNet-Mobility layout
``mobility.urdf`` + ``textured_objs/`` + ``semantics.txt`` + ``meta.json``). SAPIEN does the
kinematics and rendering; this module decides what the ground truth means:

- *Parts* are groups of links joined by ``fixed`` joints. Links without any visual geometry
  (e.g. the helper link of a PartNet-Mobility screw joint) are not parts: their joints are
  attached to the nearest part above them.
- *GT joints* are the movable URDF joints (revolute, continuous, prismatic), in URDF order, each
  with ``(parent_part, child_part)``, type 0 revolute / 1 prismatic, and its state range.
- The *object frame* is the root link frame shifted to the centre of the rest-state bounding box.
- The *rest state* is ``qpos = 0`` clamped into the joint limits; states are measured from it.

Every problem (malformed XML, missing mesh file, joint without limits, unsupported joint type,
several roots, unknown link) raises :class:`URDFError` / :class:`MissingMeshError` naming it.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from scapo.errors import MissingMeshError, URDFError
from scapo.ops.rigid import as_transform, closest_point_on_line, joint_motion, normalize, transform_points

MOVABLE = {"revolute": 0, "continuous": 0, "prismatic": 1}
#: The longest slide a prismatic joint may have (URDF length units, from the rest state): far beyond any furniture or
#: appliance part, in metres or in PartNet-Mobility's unit-box scale.
MAX_SLIDE = 100.0
SUPPORTED = set(MOVABLE) | {"fixed"}


@dataclass(frozen=True)
class VisualSpec:
    """One visual mesh of a link: file and its pose in the link frame (4x4) and scale (3,)."""

    mesh: Path
    T_link_visual: np.ndarray
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class JointSpec:
    """A URDF joint: type, parent/child link, origin (parent link -> joint frame), axis, limits."""

    name: str
    type: str
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray
    limit: tuple[float, float] | None


@dataclass(frozen=True)
class GTJoint:
    """A movable joint as it appears in the ground truth.

    Attributes:
        name: URDF joint name. type: 0 revolute (incl. continuous), 1 prismatic.
        parent_part, child_part: part indices. axis_obj: (3,) unit axis in the object frame at
        rest. pivot_obj: (3,) object frame at rest; revolute: the point of the axis closest to the
        object origin (SPEC section 3); prismatic: a translation has no axis position, so the pivot
        locates the slide instead: the point of the joint's axis line (through the URDF joint
        origin) closest to the moving part's rest bounding-box centre, so that two drawers of one
        cabinet have two distinct lines. Protocols that score prismatic pivots (``op-align``) use
        it; ``scapo`` and ``eap`` report C as not applicable for prismatic joints. rest_qpos: the
        URDF joint value of the rest state. limit: (2,) state range relative to rest (rad or m).
    """

    name: str
    type: int
    parent_part: int
    child_part: int
    axis_obj: np.ndarray
    pivot_obj: np.ndarray
    rest_qpos: float
    limit: np.ndarray


@dataclass(frozen=True)
class ArticulationSpec:
    """Everything the renderer and the ground truth need to know about one articulated object.

    Attributes:
        urdf: path of the URDF. name: robot name. category: category label (from the caller,
        ``meta.json`` or the robot name). links: link name -> visuals. joints: all URDF joints in
        file order. root: root link. part_names: names of the parts, base part first.
        part_of_link: link -> part index (-1 for links without geometry). gt_joints: movable
        joints. T_obj_root: root link pose in the object frame (4x4). bbox_min/bbox_max: rest
        state bounding box in the object frame (m). bbox_diag: its diagonal (m).
    """

    urdf: Path
    name: str
    category: str
    links: dict[str, tuple[VisualSpec, ...]]
    joints: tuple[JointSpec, ...]
    root: str
    part_names: tuple[str, ...]
    part_of_link: dict[str, int]
    gt_joints: tuple[GTJoint, ...]
    T_obj_root: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    rest_link_poses: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    @property
    def bbox_diag(self) -> float:
        return float(np.linalg.norm(self.bbox_max - self.bbox_min))

    @property
    def num_parts(self) -> int:
        return len(self.part_names)

    @property
    def num_joints(self) -> int:
        return len(self.gt_joints)

    @property
    def joint_type(self) -> np.ndarray:
        """(J,) int64, 0 revolute / 1 prismatic."""
        return np.array([j.type for j in self.gt_joints], dtype=np.int64)

    @property
    def joint_parts(self) -> np.ndarray:
        """(J, 2) int64 (parent part, child part)."""
        return np.array([[j.parent_part, j.child_part] for j in self.gt_joints], dtype=np.int64).reshape(-1, 2)

    @property
    def joint_limit(self) -> np.ndarray:
        """(J, 2) float64 state ranges relative to rest."""
        return np.array([j.limit for j in self.gt_joints], dtype=np.float64).reshape(-1, 2)

    def link_poses(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Forward kinematics: object-frame pose (4x4) of every link at joint ``state (J,)`` from rest.

        Independent of SAPIEN; used for bounding boxes and to cross-check the simulator.
        """
        q = {j.name: j.rest_qpos + float(s) for j, s in zip(self.gt_joints, np.asarray(state, dtype=np.float64))}
        poses = {self.root: self.T_obj_root}
        pending = list(self.joints)
        while pending:
            rest = []
            for j in pending:
                if j.parent not in poses:
                    rest.append(j)
                    continue
                T = poses[j.parent] @ j.T_parent_joint
                if j.type in MOVABLE:
                    T = T @ joint_motion(MOVABLE[j.type], j.axis, np.zeros(3), q[j.name])
                poses[j.child] = T
            if len(rest) == len(pending):
                raise URDFError(f"{self.urdf}: links not connected to the root: {[j.child for j in rest]}")
            pending = rest
        return poses


def _floats(text: str | None, n: int, where: str, default: tuple[float, ...]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=np.float64)
    try:
        vals = [float(x) for x in text.split()]
    except ValueError:
        raise URDFError(f"{where}: expected {n} numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise URDFError(f"{where}: expected {n} finite numbers, got {text!r}")
    return np.array(vals, dtype=np.float64)


def _origin(elem: ET.Element | None, where: str) -> np.ndarray:
    if elem is None:
        return np.eye(4)
    xyz = _floats(elem.get("xyz"), 3, f"{where} origin xyz", (0.0, 0.0, 0.0))
    rpy = _floats(elem.get("rpy"), 3, f"{where} origin rpy", (0.0, 0.0, 0.0))
    # URDF rpy: fixed-axis roll (x), pitch (y), yaw (z) -> R = Rz(yaw) Ry(pitch) Rx(roll)
    return as_transform(Rotation.from_euler("xyz", rpy).as_matrix(), xyz)


def _mesh_path(filename: str, base: Path) -> Path:
    if filename.startswith("package://"):
        filename = filename[len("package://"):].split("/", 1)[-1]
    elif filename.startswith("file://"):
        filename = filename[len("file://"):]
    p = Path(filename)
    return p if p.is_absolute() else (base / p)


def parse_urdf(urdf: str | Path, category: str | None = None, part_names: dict[str, str] | None = None,
               continuous_range: tuple[float, float] = (-math.pi, math.pi)) -> ArticulationSpec:
    """Parse and validate a URDF into an :class:`ArticulationSpec`.

    Args:
        urdf: path of the ``.urdf`` file; mesh paths are resolved relative to its folder.
        category: category label; default: the robot name.
        part_names: optional link name -> part name (e.g. from PartNet-Mobility ``semantics.txt``).
        continuous_range: state range used for ``continuous`` joints (rad, from rest).

    Raises:
        URDFError: malformed XML, unsupported joint type, joint without limits, missing or
            repeated links, several roots, a moving part without geometry.
        MissingMeshError: a visual names a mesh file that does not exist (the message names it).
    """
    urdf = Path(urdf)
    if not urdf.is_file():
        raise URDFError(f"URDF file not found: {urdf}")
    try:
        root_el = ET.parse(urdf).getroot()
    except ET.ParseError as e:
        raise URDFError(f"{urdf}: malformed URDF XML ({e})") from e
    if root_el.tag != "robot":
        raise URDFError(f"{urdf}: top-level element is <{root_el.tag}>, expected <robot>")
    base = urdf.parent
    links: dict[str, tuple[VisualSpec, ...]] = {}
    for le in root_el.findall("link"):
        name = le.get("name")
        if not name:
            raise URDFError(f"{urdf}: a <link> has no name")
        if name in links:
            raise URDFError(f"{urdf}: link {name!r} is defined twice")
        vis = []
        for ve in le.findall("visual"):
            me = ve.find("geometry/mesh")
            if me is None:
                if ve.find("geometry") is None or len(list(ve.find("geometry"))) == 0:
                    raise URDFError(f"{urdf}: link {name!r} has a <visual> without geometry")
                raise URDFError(f"{urdf}: link {name!r}: only mesh visuals are supported "
                                f"(found <{list(ve.find('geometry'))[0].tag}>)")
            fn = me.get("filename")
            if not fn:
                raise URDFError(f"{urdf}: link {name!r} has a <mesh> without filename")
            path = _mesh_path(fn, base)
            if not path.is_file():
                raise MissingMeshError(f"{urdf}: link {name!r} names mesh file {fn!r}, which does not exist "
                                       f"(looked for {path})")
            scale = tuple(_floats(me.get("scale"), 3, f"{urdf}: link {name!r} mesh scale", (1.0, 1.0, 1.0)))
            vis.append(VisualSpec(path, _origin(ve.find("origin"), f"{urdf}: link {name!r} visual"), scale))
        links[name] = tuple(vis)
    if not links:
        raise URDFError(f"{urdf}: no <link> elements")
    joints = []
    for je in root_el.findall("joint"):
        name, jtype = je.get("name"), je.get("type")
        where = f"{urdf}: joint {name!r}"
        if jtype not in SUPPORTED:
            raise URDFError(f"{where}: unsupported type {jtype!r} (supported: {sorted(SUPPORTED)})")
        pe, ce = je.find("parent"), je.find("child")
        if pe is None or ce is None:
            raise URDFError(f"{where}: needs <parent> and <child>")
        parent, child = pe.get("link"), ce.get("link")
        for ln in (parent, child):
            if ln not in links:
                raise URDFError(f"{where}: refers to unknown link {ln!r}")
        axis = np.array([1.0, 0.0, 0.0])
        if jtype != "fixed":
            ae = je.find("axis")
            axis = _floats(None if ae is None else ae.get("xyz"), 3, f"{where} axis", (1.0, 0.0, 0.0))
            if np.linalg.norm(axis) < 1e-9:
                raise URDFError(f"{where}: zero-length axis")
            axis = normalize(axis)
        limit = None
        if jtype in ("revolute", "prismatic"):
            lim = je.find("limit")
            if lim is None or lim.get("lower") is None or lim.get("upper") is None:
                raise URDFError(f"{where}: {jtype} joint without <limit lower=.. upper=..>; add limits")
            try:
                limit = (float(lim.get("lower")), float(lim.get("upper")))
            except ValueError:
                raise URDFError(f"{where}: non-numeric limits") from None
            if not (math.isfinite(limit[0]) and math.isfinite(limit[1]) and limit[0] <= limit[1]):
                raise URDFError(f"{where}: limits must be finite with lower <= upper, got {limit}")
            if jtype == "prismatic" and max(abs(limit[0]), abs(limit[1])) > MAX_SLIDE:
                raise URDFError(f"{where}: prismatic limits {limit} reach beyond {MAX_SLIDE:g} units from the rest "
                                "state: a part slid that far cannot be in view with its object; give the real travel "
                                "(the object's lengths are scaled by --scale afterwards)")
            if jtype == "revolute" and limit[1] - limit[0] > 2 * math.pi + 1e-6:
                span = limit[1] - limit[0]
                raise URDFError(f"{where}: revolute limits {limit} span more than a full turn ({span:.1f} rad); give "
                                "limits within 2 pi, or make it a continuous joint (states in [-pi, pi])")
        if jtype != "fixed" and je.find("mimic") is not None:
            raise URDFError(f"{where}: <mimic> joints (a state tied to another joint's) are not supported: their "
                            "states would be drawn independently; make it fixed, or a joint of its own")
        joints.append(JointSpec(name, jtype, parent, child, _origin(je.find("origin"), where), axis, limit))
    children = [j.child for j in joints]
    if len(set(children)) != len(children):
        raise URDFError(f"{urdf}: a link is the child of several joints")
    roots = [n for n in links if n not in children]
    if not roots:
        raise URDFError(f"{urdf}: the joints form a loop (every link is some joint's child, so none is the root); "
                        "an articulated object is a tree: make one link the child of no joint")
    if len(roots) != 1:
        raise URDFError(f"{urdf}: expected exactly one root link, found {len(roots)} ({', '.join(roots[:6])}); "
                        "connect every link to the tree by a joint")
    root = roots[0]
    parent_of = {j.child: j.parent for j in joints}
    for start in links:  # a loop below the root (a link reached from itself) is not a tree either
        seen, at = {start}, start
        while at in parent_of:
            at = parent_of[at]
            if at in seen:
                raise URDFError(f"{urdf}: the joints form a loop through link {at!r}; an articulated object is a "
                                "tree")
            seen.add(at)
    return _build_spec(urdf, root_el.get("name") or urdf.stem, category, links, tuple(joints), root,
                       part_names or {}, continuous_range)


def _build_spec(urdf, name, category, links, joints, root, part_names, continuous_range) -> ArticulationSpec:
    # union links over fixed joints
    group = {ln: ln for ln in links}

    def find(x):
        while group[x] != x:
            group[x] = group[group[x]]
            x = group[x]
        return x

    for j in joints:
        if j.type == "fixed":
            group[find(j.child)] = find(j.parent)
    # order groups: root's group first, then by first appearance as a joint child
    order = [find(root)]
    for j in joints:
        g = find(j.child)
        if g not in order:
            order.append(g)
    for ln in links:
        if find(ln) not in order:
            order.append(find(ln))
    has_geom = {g: any(links[ln] for ln in links if find(ln) == g) for g in order}
    if not has_geom[find(root)]:
        raise URDFError(f"{urdf}: the root part (link {root!r} and links fixed to it) has no visual geometry")
    part_groups = [g for g in order if has_geom[g]]
    part_index = {g: i for i, g in enumerate(part_groups)}
    part_of_link = {ln: part_index.get(find(ln), -1) for ln in links}
    pnames = []
    for g in part_groups:
        members = [ln for ln in links if find(ln) == g]
        label = next((part_names[m] for m in members if m in part_names), g)
        pnames.append(label)
    parent_of = {j.child: j for j in joints}

    def owning_part(link: str) -> int:
        """Part index of ``link``, walking up through links without geometry."""
        while part_of_link[link] < 0:
            if link not in parent_of:
                raise URDFError(f"{urdf}: link {link!r} has no geometry and no parent")
            link = parent_of[link].parent
        return part_of_link[link]

    def first_part_at_or_below(link: str) -> int:
        """Part index of ``link`` or, for a helper link without geometry, of the first part below it."""
        queue = [link]
        while queue:
            ln = queue.pop(0)
            if part_of_link[ln] >= 0:
                return part_of_link[ln]
            queue += [k.child for k in joints if k.parent == ln]
        return -1

    gt_raw = []
    for j in joints:
        if j.type not in MOVABLE:
            continue
        child_part = first_part_at_or_below(j.child)
        if child_part < 0:
            raise URDFError(f"{urdf}: joint {j.name!r} moves no link with geometry")
        parent_part = owning_part(j.parent)
        if j.limit is not None:
            lo, hi = j.limit
        else:
            lo, hi = continuous_range
        rest = min(max(0.0, lo), hi) if j.limit is not None else 0.0
        gt_raw.append((j, MOVABLE[j.type], parent_part, child_part, rest, np.array([lo - rest, hi - rest])))

    # rest-state geometry: bounding box in the root frame, then centre it
    provisional = ArticulationSpec(urdf, name, category or name, links, joints, root, tuple(pnames), part_of_link,
                                   tuple(GTJoint(j.name, t, pp, cp, np.zeros(3), np.zeros(3), r, lim)
                                         for j, t, pp, cp, r, lim in gt_raw),
                                   np.eye(4), np.zeros(3), np.zeros(3))
    poses_root = provisional.link_poses(np.zeros(len(gt_raw)))
    pts, part_pts = [], {}
    for ln, vis in links.items():
        for v in vis:
            mesh = _load_mesh(str(v.mesh))
            local = mesh.vertices * np.asarray(v.scale)
            pts.append(transform_points(poses_root[ln] @ v.T_link_visual, local))
            part_pts.setdefault(part_of_link[ln], []).append(pts[-1])
    allpts = np.vstack(pts)
    lo, hi = allpts.min(0), allpts.max(0)
    center = (lo + hi) / 2
    T_obj_root = as_transform(np.eye(3), -center)
    gt = []
    for j, t, pp, cp, r, lim in gt_raw:
        T_obj_joint = T_obj_root @ poses_root[j.parent] @ j.T_parent_joint
        axis = normalize(T_obj_joint[:3, :3] @ j.axis)
        if t == 0:
            pivot = closest_point_on_line(T_obj_joint[:3, 3], axis)
        else:  # prismatic: locate the slide at the moving part (its rest bbox centre), see GTJoint
            cp_pts = np.vstack(part_pts[cp])
            centre = (cp_pts.min(0) + cp_pts.max(0)) / 2 - center
            pivot = closest_point_on_line(T_obj_joint[:3, 3], axis, centre)
        gt.append(GTJoint(j.name, t, pp, cp, axis, pivot, r, lim))
    spec = ArticulationSpec(urdf, name, category or name, links, joints, root, tuple(pnames), part_of_link,
                            tuple(gt), T_obj_root, lo - center, hi - center)
    return ArticulationSpec(**{**spec.__dict__, "rest_link_poses": spec.link_poses(np.zeros(len(gt)))})


@lru_cache(maxsize=256)
def _load_mesh(path: str) -> trimesh.Trimesh:
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for broken files
        raise URDFError(f"cannot read mesh file {path}: {e}") from e
    if not isinstance(m, trimesh.Trimesh) or len(m.vertices) == 0:
        raise URDFError(f"mesh file {path} contains no triangles")
    return m


def load_part_mesh(spec: ArticulationSpec, part: int, state: np.ndarray | None = None) -> trimesh.Trimesh:
    """All visual meshes of ``part`` merged, in the object frame at ``state`` (default: rest)."""
    poses = spec.rest_link_poses if state is None else spec.link_poses(state)
    meshes = []
    for ln, vis in spec.links.items():
        if spec.part_of_link[ln] != part:
            continue
        for v in vis:
            m = _load_mesh(str(v.mesh)).copy()
            if v.scale != (1.0, 1.0, 1.0):
                m.apply_transform(np.diag([*v.scale, 1.0]))
            m.apply_transform(poses[ln] @ v.T_link_visual)
            meshes.append(m)
    if not meshes:
        raise URDFError(f"{spec.urdf}: part {part} has no meshes")
    return trimesh.util.concatenate(meshes)


def load_partnet_mobility(folder: str | Path, **kwargs) -> ArticulationSpec:
    """Load an object in the PartNet-Mobility layout.

    ``folder`` holds ``mobility.urdf`` (meshes under ``textured_objs/``), optionally
    ``semantics.txt`` (lines ``<link> <joint kind> <part label>``, used to name parts) and
    ``meta.json`` (its ``model_cat`` is the category). ``urdf=PATH`` names another URDF of the folder (ManiSkill's
    copy has ``mobility_cvx.urdf``).

    Raises:
        URDFError / MissingMeshError: as :func:`parse_urdf`; URDFError if ``mobility.urdf`` is missing.
    """

    folder = Path(folder)
    urdf = Path(kwargs.pop("urdf", None) or folder / "mobility.urdf")
    if not urdf.is_file():
        raise URDFError(f"{folder}: no {urdf.name} (not a PartNet-Mobility object folder)")
    category = kwargs.pop("category", None)
    if category is None:
        category = read_meta_category(folder)
    return parse_urdf(urdf, category=category, part_names=read_semantics(folder), **kwargs)


def read_semantics(folder: str | Path) -> dict[str, str]:
    """Link name -> part label from a PartNet-Mobility ``semantics.txt`` (lines ``<link> <joint kind> <label>``);
    empty without one."""
    names = {}
    sem = Path(folder) / "semantics.txt"
    if sem.is_file():
        for line in sem.read_text().splitlines():
            f = line.split()
            if len(f) >= 3:
                names[f[0]] = f[2]
    return names


def read_meta_category(folder: str | Path) -> str | None:
    """The ``model_cat`` of a PartNet-Mobility ``meta.json`` (None without one).

    Raises:
        URDFError: ``meta.json`` is not valid JSON."""
    import json

    meta = Path(folder) / "meta.json"
    if not meta.is_file():
        return None
    try:
        d = json.loads(meta.read_text())
    except json.JSONDecodeError as e:
        raise URDFError(f"{meta}: not valid JSON ({e})") from e
    return d.get("model_cat") if isinstance(d, dict) else None
