"""Export one view's prediction as an articulated model: a URDF a simulator loads (``scapo export``).

What the twin is made of, all from the prediction of one sample (a method's segmentation, part poses and
joints; a trained run is not needed once its predictions exist):

- **Frame.** Every part pose maps the method's canonical object frame *at rest* to the camera, so the points
  of part p taken back through ``inv(part_pose[p])`` lie in that common rest frame. The twin's root link is
  that frame (its base part, slot 0 after matching, is the root).
- **Links.** One link per part, with a mesh made from the part's points in the rest frame: the convex hull
  (``trimesh``, qhull with joggle so that flat patches still give a closed thin solid), the simplest surface
  that a simulator can render and collide; parts without points are left out with the joints that need them.
- **Joints.** Each predicted joint (parent and child part, type, axis, pivot in the camera frame) is taken into
  the rest frame through the parent's pose: a revolute joint turns about the line through the pivot along
  the axis, a prismatic one slides along the axis (its origin at the pivot, which locates the slide). The
  child link's frame is the joint frame at rest, so its mesh is placed relative to the pivot.
- **Mass.** Each link has an ``<inertial>``: its hull's volume at :data:`DENSITY` (1000 kg/m^3 unless given), the
  hull's centre of mass and inertia tensor, so a simulator does not invent them.
- **Limits.** A joint's range is the dataset's state range for the matching joint (``joint_limit``, relative to
  rest), widened to include the observed (predicted) state; without one, the observed state +- pi (revolute) or
  +- one bbox diagonal (prismatic).
- **State.** ``twin.json`` records the predicted joint states: at that state the twin should look like the
  observation (``scapo evaluate --twin`` scores how well it does).

The folder holds ``mobility.urdf``, ``meshes/part<k>.obj``, ``semantics.txt`` (part names) and ``twin.json``,
the PartNet-Mobility layout, so ``scapo assets check TWIN/`` and ``scapo generate --object TWIN/`` read it;
``twin.json`` also records which predicted slot matched each GT part on this view (point IoU), for scoring.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scapo.data.dataset import load
from scapo.errors import ConfigError, PredictionError
from scapo.eval.metrics import match_parts
from scapo.eval.predictions import Predictions
from scapo.files import atomic_write_text, check_output_dir, clean_stale_temps
from scapo.ops.rigid import invert_transform, normalize, transform_points
from scapo.sim.assets.objects import origin_strings


@dataclass(frozen=True)
class TwinReport:
    """What :func:`export_twin` wrote.

    Attributes:
        folder: the twin folder. urdf: its URDF. parts: part names written (link order). joints: per joint
        ``{"name", "type", "parent", "child", "axis", "origin", "limit", "state"}`` in the twin's root frame.
        T_cam_root: ``(4, 4)`` the twin's root frame in the observed camera (the base part's predicted pose).
    """

    folder: Path
    urdf: Path
    parts: list[str]
    joints: list[dict]
    T_cam_root: np.ndarray


def _frame_along(axis: np.ndarray) -> np.ndarray:
    """A rotation whose x axis is ``axis`` (the URDF joint axis is then (1, 0, 0) in the joint frame)."""
    x = normalize(np.asarray(axis, dtype=np.float64))
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    y = normalize(np.cross(helper, x))
    return np.stack([x, y, np.cross(x, y)], axis=1)


#: the density (kg/m^3) a twin's links are given, over their convex hulls: about a household object's average
#: (a laptop's 0.33 x 0.23 x 0.02 m hull then weighs 1.5 kg, as real ones do)
DENSITY = 1000.0
#: the least mass (kg) and inertia (kg m^2) of a link, so that a thin part's hull still simulates
MIN_MASS, MIN_INERTIA = 1e-3, 1e-7


def _inertial(link: ET.Element, hull, density: float) -> None:
    """``<inertial>`` of a link from its convex hull (link frame) at ``density``: mass, centre of mass and the
    inertia tensor about it (trimesh's mass properties; floors :data:`MIN_MASS`, :data:`MIN_INERTIA`)."""
    hull.density = density
    mass = max(float(hull.mass), MIN_MASS)
    com = np.asarray(hull.center_mass, dtype=np.float64)
    inertia = np.asarray(hull.moment_inertia, dtype=np.float64) * (mass / max(float(hull.mass), 1e-12))
    inertia = 0.5 * (inertia + inertia.T) + MIN_INERTIA * np.eye(3)
    ie = ET.SubElement(link, "inertial")
    ET.SubElement(ie, "origin", xyz=" ".join(repr(float(v)) for v in com), rpy="0 0 0")
    ET.SubElement(ie, "mass", value=repr(mass))
    ET.SubElement(ie, "inertia", **{k: repr(float(inertia[i, j])) for k, (i, j) in
                                    {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2),
                                     "izz": (2, 2)}.items()})


def export_twin(data: str | Path, predictions: str | Path | Predictions, sample: int, out: str | Path,
                split: str = "test", min_points: int = 8, density: float = DENSITY) -> TwinReport:
    """Write the articulated twin of sample ``sample`` of ``split`` of ``data`` from ``predictions`` into ``out``.

    Args:
        data: the dataset folder. predictions: a predictions file (``scapo predict``) or object covering that
            sample. sample: index into the split (0-based). out: the twin folder (created; a folder holding a
            twin is replaced). min_points: a part with fewer predicted points gets no link. density: kg/m^3 of the
            links' convex hulls, for their ``<inertial>`` (mass, centre of mass, inertia tensor).

    Returns:
        :class:`TwinReport`.

    Raises:
        ConfigError: ``sample`` out of range (the message gives the split's size), a method's part split that
            leaves the base part without points, or one that leaves no moving part (a one-link twin, which
            simulators refuse); a density that is not positive.
        PredictionError: predictions of another dataset (hash), or without that sample.
        OutputError: ``out`` cannot be written or is a foreign non-empty folder.
    """
    import trimesh

    ds = load(data, split)
    if not 0 <= int(sample) < len(ds):
        raise ConfigError(f"--sample {sample} is out of range: the {split} split of {data} has {len(ds)} samples "
                          f"(0..{len(ds) - 1})")
    preds = predictions if isinstance(predictions, Predictions) else Predictions.load(predictions)
    if preds.dataset_hash != ds.dataset_hash:  # no hash: nothing shows they were made on this dataset
        raise PredictionError(f"these predictions of {preds.method!r} were made on dataset {preds.dataset_hash[:12]}"
                              f"..., not on {data} ({ds.dataset_hash[:12]}...); predict on this dataset first")
    item = ds[int(sample)]
    rows = np.flatnonzero((preds.instance_id == item["instance_id"]) & (preds.view_id == item["view_id"])
                          & (preds.split == split))
    if len(rows) == 0:
        raise PredictionError(f"the predictions of {preds.method!r} do not cover {split} sample {sample} (instance "
                              f"{item['instance_id']}, view {item['view_id']}) of {data}")
    r = int(rows[0])
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; give a folder for the twin")
    ours = {"meshes", "mobility.urdf", "semantics.txt", "twin.json"}  # what an export writes (twin.json last)
    if out.is_dir():  # the temporaries of an interrupted export (a full disk, a kill) are its own, not the user's
        clean_stale_temps(out)
    if out.is_dir() and not (out / "twin.json").is_file() and not {p.name for p in out.iterdir()} <= ours:
        raise ConfigError(f"--out {out} is a non-empty folder without a twin; give a new or empty folder")
    if not (np.isfinite(density) and density > 0):
        raise ConfigError(f"density must be a positive number of kg/m^3, got {density}")
    check_output_dir(out, "twin folder")
    (out / "meshes").mkdir(exist_ok=True)
    points = item["points"].astype(np.float64)
    label = preds.part_label[r]
    pose = preds.part_pose[r]
    S = pose.shape[0]
    names = list(ds.part_names) if len(ds.part_names) == S else [f"part{k}" for k in range(S)]
    counts = np.bincount(label[label >= 0], minlength=S)
    if counts[0] < min_points:
        raise ConfigError(f"the prediction gives the base part {counts[0]} points (< {min_points}); no twin can be "
                          "built around it")
    kept = [s for s in range(S) if counts[s] >= min_points]
    rest_pts = {s: transform_points(invert_transform(pose[s]), points[label == s]) for s in kept}
    diag = float(item["bbox_diag"])
    # joints in the twin's root frame (the base part's rest frame)
    joints, link_frame = [], {0: np.eye(4)}
    jp, jt = preds.joint_parts[r], preds.joint_type[r]
    limits = np.asarray(item["joint_limit"], dtype=np.float64).reshape(-1, 2)
    for j in range(len(jt)):
        a, b = int(jp[j, 0]), int(jp[j, 1])
        if a not in kept or b not in kept or b == 0 or b in link_frame:
            continue  # a part without points, the root as a child, or a part reached twice: no joint
        Ta = pose[a]
        axis = normalize(Ta[:3, :3].T @ preds.joint_axis[r, j])  # parent rest frame = root frame at rest
        pivot = Ta[:3, :3].T @ (preds.joint_pivot[r, j] - Ta[:3, 3])
        state = float(preds.joint_state[r, j])
        if j < len(limits) and np.isfinite(limits[j]).all():
            lo, hi = float(min(limits[j, 0], state)), float(max(limits[j, 1], state))
        else:
            half = np.pi if int(jt[j]) == 0 else diag
            lo, hi = state - half, state + half
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = _frame_along(axis), pivot
        link_frame[b] = T
        joints.append({"name": f"joint{j}", "type": "revolute" if int(jt[j]) == 0 else "prismatic", "parent": a,
                       "child": b, "axis": axis.tolist(), "origin": pivot.tolist(), "limit": [lo, hi],
                       "state": state})
    kept = [s for s in kept if s in link_frame]
    if len(kept) < 2:
        few = {names[s]: int(counts[s]) for s in range(1, S)}
        raise ConfigError(f"the prediction of sample {sample} leaves no moving part with {min_points} or more points "
                          f"(points per part: {few}): a twin needs a base and at least one jointed part")
    robot = ET.Element("robot", name=f"twin_{ds.category}_{item['instance_id']}_{item['view_id']}")
    for s in kept:
        local = transform_points(invert_transform(link_frame[s]), rest_pts[s])
        try:
            hull = trimesh.convex.convex_hull(local, qhull_options="QJ")
        except Exception as e:  # noqa: BLE001 - qhull raises its own kinds for degenerate input
            raise ConfigError(f"part {s} ({names[s]!r}): no surface from its {len(local)} points ({e})") from None
        mesh_path = out / "meshes" / f"part{s}.obj"
        atomic_write_text(mesh_path, trimesh.exchange.obj.export_obj(hull, include_normals=False,
                                                                       include_texture=False))
        le = ET.SubElement(robot, "link", name=f"link{s}")
        _inertial(le, hull, density)
        for tag in ("visual", "collision"):
            ve = ET.SubElement(le, tag)
            ET.SubElement(ve, "origin", xyz="0 0 0", rpy="0 0 0")
            ET.SubElement(ET.SubElement(ve, "geometry"), "mesh", filename=f"meshes/part{s}.obj")
    for jd in joints:
        a, b = jd["parent"], jd["child"]
        T_rel = invert_transform(link_frame[a]) @ link_frame[b]  # parent link frame -> joint frame
        je = ET.SubElement(robot, "joint", name=jd["name"], type=jd["type"])
        xyz, rpy = origin_strings(T_rel)
        ET.SubElement(je, "origin", xyz=xyz, rpy=rpy)
        ET.SubElement(je, "parent", link=f"link{a}")
        ET.SubElement(je, "child", link=f"link{b}")
        ET.SubElement(je, "axis", xyz="1 0 0")
        ET.SubElement(je, "limit", lower=repr(jd["limit"][0]), upper=repr(jd["limit"][1]), effort="100", velocity="1")
    for old in (out / "meshes").glob("part*.obj"):  # an earlier twin's meshes of parts this one does not have
        if old.stem not in {f"part{s}" for s in kept}:
            old.unlink()
    ET.indent(robot)
    urdf = out / "mobility.urdf"
    atomic_write_text(urdf, '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n")
    atomic_write_text(out / "semantics.txt", "".join(f"link{s} {'free' if s == 0 else 'slot'} {names[s]}\n"
                                                     for s in kept))
    twin = {"dataset": str(Path(data).resolve()), "dataset_hash": ds.dataset_hash, "split": split,
            "sample": int(sample), "instance_id": int(item["instance_id"]), "view_id": int(item["view_id"]),
            "method": preds.method, "parts": [names[s] for s in kept], "slots": kept, "joints": joints,
            "gt_part_slots": match_parts(label, item["part_label"], ds.num_parts, S).tolist(),
            "T_cam_root": pose[0].tolist(), "K": np.asarray(item["K"]).tolist(),
            "image_size": [int(round(2 * item["K"][1, 2])), int(round(2 * item["K"][0, 2]))]}
    atomic_write_text(out / "twin.json", json.dumps(twin, indent=1) + "\n")
    return TwinReport(out, urdf, [names[s] for s in kept], joints, pose[0].copy())
