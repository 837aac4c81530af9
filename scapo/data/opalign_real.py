"""Reader of OP-Align's real-world dataset, converted into a scapo dataset (for users who have it).

The dataset of Che, Furukawa and Kanezaki, "OP-Align", ECCV 2024 (github.com/YC-Che/OP-Align, its README
section "Dataset"; read in ``SPConvNets/datasets/RealDataset.py``, ``getitem``) holds single RGB-D frames in
``<root>/<split>/<A>/<B>/input_2/*.npz`` (``<root>`` is a category folder such as ``laptop_output``;
``<split>`` is ``train`` or ``test``). Each file holds one pickled dict,
``np.load(p, allow_pickle=True)["arr_0"].item()``, with

- ``pc (H*W, 3)``: organised xyz of the 480 x 640 image, camera frame; a zero row is no depth;
- ``color (H*W, 3)``, ``detection (H*W,)`` (the detector's object mask: Mask R-CNN / SAM),
  ``segmentation (H*W,)`` (0 background, 1..P parts);
- ``part (P, 15)``: per part rows 0-8 the rotation (row-major, part to camera), 9-11 the translation,
  12-14 the scale;
- ``joint (J, 6)``: per joint the pivot (columns 0-2) then the direction (3-5). OP-Align's README lists
  "direction, pivot"; its loader reads ``joint[:, :3]`` as the joint position and ``joint[:, 3:6]`` as the
  direction, and we follow the loader.

Conversion, per frame (deterministic for a seed): the points are the pixels with depth inside the
detection mask (as OP-Align's loader does), farthest-point sampled to N; ``part_label`` is the
segmentation minus one (background: -1); ``part_pose[p] = [R_p | t_p]`` (the part's annotated canonical
frame to the camera); ``joint_pivot`` / ``joint_axis`` as stored (camera frame); joint types and parts
come from the category (:data:`REAL_CATEGORIES`, or given); ``joint_state`` is the relative motion of
child and parent part poses about / along the joint (so 0 is the annotated canonical articulation);
``joint_limit`` is unknown (NaN); ``K`` is fitted to the organised pixels (least squares of
``u = fx x / z + cx``, ``v = fy y / z + cy``); ``bbox_diag`` is the diagonal of the axis-aligned box, in the
camera frame, of the parts' boxes (the scale taken as the box extents) placed by their poses;
``T_cam_obj = part_pose[0]``; ``npcs`` the points mapped by their part's inverse pose, over ``bbox_diag``.
Frames with fewer than N object pixels are skipped and counted in the card. Units are the file's (metres).

Instances are the ``<A>`` folders; the validation split is drawn from the training instances (by
instance, seeded), since every choice is made on val.
"""

from __future__ import annotations

import hashlib
import io
import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from scapo import __version__
from scapo.data.config import FORMAT_VERSION
from scapo.data.storage import write_json, write_shard
from scapo.errors import ConfigError, DatasetError, InputError
from scapo.files import atomic_write_bytes, check_output_dir, load_npz_object
from scapo.ops.rigid import invert_transform, project_to_so3
from scapo.ops.sampling import farthest_point_indices
from scapo.sim.render import npcs_of

#: Joint types (0 revolute, 1 prismatic) and (parent, child) parts of the categories of OP-Align's real data
#: (SPEC section 4 table; the paper's Table 2 categories).
REAL_CATEGORIES: dict[str, tuple[list[int], list[list[int]]]] = {
    "basket": ([0, 0], [[0, 1], [0, 2]]),
    "drawer": ([1], [[0, 1]]),
    "laptop": ([0], [[0, 1]]),
    "scissors": ([0], [[0, 1]]),
    "suitcase": ([0], [[0, 1]]),
}
#: Part names of those categories (as our procedural assets of the same names).
REAL_PART_NAMES = {"basket": ["body", "handle_a", "handle_b"], "drawer": ["cabinet", "drawer"],
                   "laptop": ["base", "screen"], "scissors": ["blade_a", "blade_b"], "suitcase": ["shell", "lid"]}
IMAGE_SIZE = (480, 640)
FRAME_KEYS = ("pc", "detection", "segmentation", "part", "joint")


def read_frame(path: str | Path) -> dict:
    """Load one frame file and check its fields.

    Raises:
        DatasetError: unreadable, not a dict, a field missing or of the wrong shape (names the file and field).
    """
    path = Path(path)
    try:
        raw = load_npz_object(path)  # never runs code from the file (a restricted unpickler)
    except Exception as e:  # noqa: BLE001 - np.load raises many kinds for a damaged file
        raise DatasetError(f"{path}: not an OP-Align frame file ({type(e).__name__}: {e})") from None
    if not isinstance(raw, dict):
        raise DatasetError(f"{path}: arr_0 holds a {type(raw).__name__}, expected a dict")
    missing = [k for k in FRAME_KEYS if k not in raw]
    if missing:
        raise DatasetError(f"{path}: lacks fields {missing} (has {sorted(raw)}; an OP-Align frame holds "
                           f"{', '.join(FRAME_KEYS)} and color)")
    pc = np.asarray(raw["pc"], dtype=np.float64)
    n = len(pc)
    if pc.ndim != 2 or pc.shape[1] != 3:
        raise DatasetError(f"{path}: pc has shape {pc.shape}, expected (H*W, 3)")
    for k in ("detection", "segmentation"):
        if np.asarray(raw[k]).shape != (n,):
            raise DatasetError(f"{path}: {k} has shape {np.asarray(raw[k]).shape}, expected ({n},)")
    part, joint = np.asarray(raw["part"], dtype=np.float64), np.asarray(raw["joint"], dtype=np.float64)
    if part.ndim != 2 or part.shape[1] != 15 or joint.ndim != 2 or joint.shape[1] != 6:
        raise DatasetError(f"{path}: part {part.shape} / joint {joint.shape}, expected (P, 15) / (J, 6)")
    if not (np.isfinite(pc).all() and np.isfinite(part).all() and np.isfinite(joint).all()):
        raise DatasetError(f"{path}: non-finite values in pc, part or joint")
    return {"pc": pc, "detection": np.asarray(raw["detection"]).astype(bool),
            "segmentation": np.asarray(raw["segmentation"]).astype(np.int64), "part": part, "joint": joint}


def fit_intrinsics(pc: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """``K (3, 3)`` fitted to an organised point image ``pc (H*W, 3)`` (pixels without depth are zero rows).

    Raises:
        InputError: fewer than 10 pixels in front of the camera, or a size that does not match ``pc``.
    """
    H, W = image_size
    if len(pc) != H * W:
        raise InputError(f"an organised image of {H} x {W} pixels has {H * W} points, the frame has {len(pc)}; "
                         "give the image size (--image-size HxW)")
    idx = np.nonzero(pc[:, 2] > 1e-6)[0]
    if len(idx) < 10:
        raise InputError("fewer than 10 pixels with depth: cannot fit the camera intrinsics")
    u, v = (idx % W).astype(np.float64), (idx // W).astype(np.float64)
    x, y = pc[idx, 0] / pc[idx, 2], pc[idx, 1] / pc[idx, 2]
    fx, cx = np.linalg.lstsq(np.stack([x, np.ones_like(x)], 1), u, rcond=None)[0]
    fy, cy = np.linalg.lstsq(np.stack([y, np.ones_like(y)], 1), v, rcond=None)[0]
    err = np.median(np.hypot(fx * x + cx - u, fy * y + cy - v))
    if not err < 2.0:  # pixels do not sit where a pinhole camera of this size puts them
        raise InputError(f"the organised cloud does not fit a pinhole camera of {H} x {W} pixels (median "
                         f"reprojection error {err:.1f} px); is --image-size HxW transposed (try {W}x{H})?")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def frame_to_sample(frame: dict, joint_type: Sequence[int], joint_parts: Sequence[Sequence[int]], num_points: int,
                    rng: np.random.Generator, image_size: tuple[int, int] = IMAGE_SIZE) -> dict:
    """One frame (:func:`read_frame`) -> a sample dict with the SPEC section 5 fields (see the module docstring).

    Raises:
        InputError: fewer than ``num_points`` object pixels, part / joint counts that differ from the category's,
            or a part rotation that is not a rotation.
    """
    jt = np.asarray(joint_type, dtype=np.int64)
    jp = np.asarray(joint_parts, dtype=np.int64).reshape(-1, 2)
    part, joint = frame["part"], frame["joint"]
    P, J = len(part), len(joint)
    if J != len(jt) or P != int(jp.max(initial=0)) + 1:
        raise InputError(f"the frame has {P} parts and {J} joints; the category expects {int(jp.max(initial=0)) + 1} "
                         f"and {len(jt)} (give --joint-types / --joint-parts for another category)")
    pc = frame["pc"]
    mask = np.any(pc != 0, axis=1) & frame["detection"]
    n_obj = int(mask.sum())
    if n_obj < num_points:
        raise InputError(f"too few object pixels ({n_obj} < {num_points})")
    R = part[:, :9].reshape(P, 3, 3)
    if np.abs(np.linalg.det(R) - 1.0).max() > 1e-2:
        raise InputError(f"part rotations with determinants {np.linalg.det(R).round(3).tolist()} are not rotations")
    pose = np.tile(np.eye(4), (P, 1, 1))
    pose[:, :3, :3] = np.stack([project_to_so3(r) for r in R])
    pose[:, :3, 3] = part[:, 9:12]
    points_all = pc[mask]
    labels_all = frame["segmentation"][mask] - 1
    idx = farthest_point_indices(points_all, num_points, rng)
    points = points_all[idx].astype(np.float32)
    label = np.where(labels_all[idx] >= 0, labels_all[idx], -1).astype(np.int64)
    if (labels_all >= P).any():
        raise InputError(f"segmentation ids up to {int(labels_all.max()) + 1} but the frame has {P} parts "
                         "(ids 1..P, 0 background)")
    if (labels_all < -1).any():
        raise InputError(f"segmentation ids down to {int(labels_all.min()) + 1}: ids are 1..{P} for the parts and 0 "
                         "for background")
    if not (labels_all >= 0).any():
        raise InputError("no pixel of the detected object carries a part id (its segmentation is all background): "
                         "nothing to score a segmentation against")
    half = np.abs(part[:, 12:15]) / 2
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    box = np.concatenate([(corners * half[p]) @ pose[p, :3, :3].T + pose[p, :3, 3] for p in range(P)])
    bbox_diag = float(np.linalg.norm(box.max(0) - box.min(0)))
    if not bbox_diag > 0:
        raise InputError("the parts' scales are zero: cannot size the object")
    norms = np.linalg.norm(joint[:, 3:6], axis=1, keepdims=True)
    if (norms < 1e-6).any():
        raise InputError(f"joint(s) {np.nonzero(norms[:, 0] < 1e-6)[0].tolist()} have a zero-length axis")
    axis = joint[:, 3:6] / norms
    state = np.zeros(J)
    for j in range(J):
        M = invert_transform(pose[jp[j, 0]]) @ pose[jp[j, 1]]
        a_parent = pose[jp[j, 0], :3, :3].T @ axis[j]
        state[j] = (Rotation.from_matrix(M[:3, :3]).as_rotvec() @ a_parent) if jt[j] == 0 else (M[:3, 3] @ a_parent)
    npcs = npcs_of(points, label, pose, bbox_diag)
    return {"points": points, "part_label": label, "npcs": npcs, "part_pose": pose,
            "joint_type": jt, "joint_parts": jp, "joint_axis": axis, "joint_pivot": joint[:, :3].copy(),
            "joint_state": state, "joint_limit": np.full((J, 2), np.nan), "T_cam_obj": pose[0].copy(),
            "K": fit_intrinsics(pc, image_size), "bbox_diag": np.float64(bbox_diag)}


def find_frames(root: str | Path) -> dict[str, list[tuple[str, Path]]]:
    """``split -> [(instance folder name, frame path)]`` of ``root/<split>/<A>/<B>/input_2/*.npz``, sorted.

    Raises:
        ConfigError: ``root`` has no frames in that layout.
    """
    root = Path(root)
    out = {}
    for split in ("train", "test"):
        files = sorted((root / split).glob("*/*/input_2/*.npz"))
        out[split] = [(f.relative_to(root / split).parts[0], f) for f in files]
    if not any(out.values()):
        raise ConfigError(f"{root}: no frames in OP-Align's layout <root>/{{train,test}}/*/*/input_2/*.npz; give the "
                          "category folder (e.g. laptop_output)")
    return out


def convert_opalign_real(root: str | Path, category: str, out: str | Path, num_points: int = 1024, seed: int = 0,
                         val_fraction: float = 0.1, joint_type: Sequence[int] | None = None,
                         joint_parts: Sequence[Sequence[int]] | None = None, image_size=IMAGE_SIZE,
                         shard_size: int = 64, part_names: Sequence[str] | None = None) -> dict:
    """Convert OP-Align's real data of one category into a scapo dataset at ``out``; returns the card.

    Args:
        root: the category folder (``<root>/{train,test}/<A>/<B>/input_2/*.npz``). category: our category name
            (joint types and parts from :data:`REAL_CATEGORIES` unless given). out: new dataset folder (a folder
            holding a conversion of the same arguments is rewritten identically). num_points: N.
        seed: seeds the val split and every frame's FPS. val_fraction: of the training instances.

    Raises:
        ConfigError: an unknown category without joint types, no frames, an --out holding something else.
        DatasetError: a damaged frame file (named). OutputError: ``out`` cannot be written.
    """
    t0 = time.time()
    if category in REAL_CATEGORIES and joint_type is not None:
        known_types, known_parts = REAL_CATEGORIES[category]
        if list(map(int, joint_type)) != known_types or (joint_parts is not None and
                                                         [list(map(int, p)) for p in joint_parts] != known_parts):
            raise ConfigError(f"{category}'s joints are known (types {known_types}, parts {known_parts}; 0 revolute, "
                              "1 prismatic): --joint-types / --joint-parts would relabel them (a hinge as a slide); "
                              "leave them out, or give the data another category name")
    if joint_type is None or joint_parts is None:
        if category not in REAL_CATEGORIES:
            raise ConfigError(f"category {category!r} has no known joints; known: {', '.join(REAL_CATEGORIES)} (or "
                              "give --joint-types and --joint-parts)")
        joint_type, joint_parts = REAL_CATEGORIES[category]
    if num_points < 16:
        raise ConfigError(f"--points must be >= 16, got {num_points}")
    if not 0 <= int(seed) < 2 ** 63:
        raise ConfigError(f"--seed must be in [0, 2**63), got {seed}")
    if len(image_size) != 2 or min(image_size) < 1:
        raise ConfigError(f"--image-size must be HxW with positive sizes, got {image_size}")
    if not 0.0 <= val_fraction < 1.0:
        raise ConfigError(f"val_fraction must be in [0, 1), got {val_fraction}")
    frames = find_frames(root)
    out = Path(out)
    source = {"kind": "op-align-real", "root": str(Path(root).resolve()), "num_points": num_points, "seed": seed,
              "val_fraction": val_fraction, "joint_type": list(map(int, joint_type)),
              "joint_parts": [list(map(int, p)) for p in joint_parts], "image_size": list(image_size)}
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; give a folder")
    if out.exists() and any(p for p in out.iterdir()):
        try:
            old = json.loads((out / "card.json").read_text()).get("source")
        except (OSError, ValueError, AttributeError):
            old = None
        half_made = not (out / "card.json").exists() and {p.name for p in out.iterdir()} <= {"shards", ".scapo.lock"} \
            and all(p.suffix == ".npz" or p.name.startswith(".") for p in (out / "shards").glob("*"))
        if half_made:  # a conversion that failed before its card: a corrected rerun takes the folder over
            for p in (out / "shards").glob("*"):
                p.unlink()
        elif old != source:
            raise ConfigError(f"--out {out} is not empty and holds no conversion with these arguments; choose a new "
                              f"folder (or remove it: rm -r {out})")
    check_output_dir(out, "dataset folder", own="dataset")
    (out / "shards").mkdir(parents=True, exist_ok=True)
    train_inst = sorted({a for a, _ in frames["train"]})
    rng = np.random.default_rng([int(seed), 0x0A11])
    n_val = int(round(val_fraction * len(train_inst))) if len(train_inst) >= 2 and val_fraction > 0 else 0
    n_val = min(max(n_val, 1 if val_fraction > 0 and len(train_inst) >= 2 else 0), max(len(train_inst) - 1, 0))
    val_inst = set(rng.choice(train_inst, size=n_val, replace=False).tolist()) if n_val else set()
    inst_id: dict[tuple[str, str], int] = {}
    views: dict[int, int] = {}
    root = Path(root)
    rows, shards, skipped, sid = [], {}, {}, 0
    for split_name in ("train", "val", "test"):
        src = "test" if split_name == "test" else "train"
        items = [(a, f) for a, f in frames[src] if (a in val_inst) == (split_name == "val") or src == "test"]
        samples, meta = [], []
        for a, f in items:
            key = (src, a)
            if key not in inst_id:
                inst_id[key] = len(inst_id)
            vid = views.get(inst_id[key], 0)
            frng = np.random.default_rng([int(seed), int(hashlib.sha256(str(f.relative_to(root)).encode())
                                                         .hexdigest()[:8], 16)])
            try:
                s = frame_to_sample(read_frame(f), joint_type, joint_parts, num_points, frng, tuple(image_size))
            except InputError as e:
                reason = str(e).split(" (")[0]
                skipped[reason] = skipped.get(reason, 0) + 1
                continue
            samples.append(s)
            views[inst_id[key]] = vid + 1
            meta.append((sid, inst_id[key], vid, str(f.relative_to(root))))
            sid += 1
        for k in range(0, len(samples), shard_size):
            name = f"{split_name}-{k // shard_size:05d}"
            chunk, cmeta = samples[k:k + shard_size], meta[k:k + shard_size]
            m = {"sample_id": np.array([c[0] for c in cmeta]), "instance_id": np.array([c[1] for c in cmeta]),
                 "view_id": np.array([c[2] for c in cmeta]), "attempts": np.ones(len(cmeta), dtype=np.int64)}
            digest = write_shard(out / "shards" / f"{name}.npz", chunk, m, {})
            shards[name] = {"sha256": digest, "samples": len(chunk), "split": split_name}
            for r, c in enumerate(cmeta):
                rows.append({"sample_id": c[0], "split": split_name, "shard": name, "row": r, "category": category,
                             "instance_id": c[1], "view_id": c[2], "seed": int(seed), "attempts": 1,
                             "joint_state": [float(x) for x in chunk[r]["joint_state"]], "source_file": c[3]})
    if not rows:
        raise ConfigError(f"{root}: every frame was skipped ({skipped}); lower --points")
    manifest = pd.DataFrame(rows)
    buf = io.BytesIO()
    manifest.to_parquet(buf, index=False)
    atomic_write_bytes(out / "manifest.parquet", buf.getvalue())
    P = int(np.asarray(joint_parts).max()) + 1
    h = hashlib.sha256(json.dumps(source, sort_keys=True).encode())
    for name in sorted(shards):
        h.update(shards[name]["sha256"].encode())
    splits = {}
    for split_name in ("train", "val", "test"):
        ids = sorted({r["instance_id"] for r in rows if r["split"] == split_name})
        splits[split_name] = {"instances": ids, "samples": int((manifest["split"] == split_name).sum())}
    card = {
        "scapo_version": __version__, "format_version": FORMAT_VERSION, "category": category,
        "part_names": list(part_names or REAL_PART_NAMES.get(category, ["base"] + [f"part{p}" for p in range(1, P)])),
        "joint_names": [f"joint{j}" for j in range(len(joint_type))], "joint_type": list(map(int, joint_type)),
        "joint_parts": [list(map(int, p)) for p in joint_parts], "num_points": num_points, "source": source,
        "splits": splits, "shards": shards, "skipped_frames": dict(sorted(skipped.items())),
        "instances": {str(v): f"{s}/{a}" for (s, a), v in sorted(inst_id.items(), key=lambda kv: kv[1])},
        "dataset_hash": h.hexdigest(),
    }
    write_json(out / "card.json", card)
    with open(out / "run_log.jsonl", "a") as f:
        f.write(json.dumps({"time": time.strftime("%Y-%m-%dT%H:%M:%S"), "samples": len(rows),
                            "skipped": skipped, "seconds": round(time.time() - t0, 3)}) + "\n")
    return card
