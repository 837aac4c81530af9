"""On-disk dataset layout: shards of stacked arrays, a Parquet manifest and a JSON card.

::

    DIR/config.json            GenerateConfig (written first; a resumed run must match it)
    DIR/shards/<split>-<k>.npz one shard: the fixed-shape arrays of up to shard_size samples
    DIR/manifest.parquet       one row per sample: sample_id, split, shard, row, category, ...
    DIR/card.json              generator version, config, checksums, counts (written last)

A shard is written to a hidden temporary file and renamed into place, so a shard file that
exists is complete; the card exists only when every shard does.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path

import numpy as np

from scapo.errors import CorruptShardError
from scapo.files import atomic_write_bytes, write_json  # noqa: F401  (re-exported)

#: Per-sample array fields stored in shards, with their dtype (SPEC section 5 names).
ARRAY_FIELDS: dict[str, np.dtype] = {
    "points": np.dtype(np.float32),
    "part_label": np.dtype(np.int16),
    "npcs": np.dtype(np.float32),
    "part_pose": np.dtype(np.float64),
    "joint_type": np.dtype(np.int8),
    "joint_parts": np.dtype(np.int16),
    "joint_axis": np.dtype(np.float64),
    "joint_pivot": np.dtype(np.float64),
    "joint_state": np.dtype(np.float64),
    "joint_limit": np.dtype(np.float64),
    "T_cam_obj": np.dtype(np.float64),
    "K": np.dtype(np.float64),
    "bbox_diag": np.dtype(np.float64),
}
#: Per-sample metadata stored in shards next to the arrays.
META_FIELDS: dict[str, np.dtype] = {
    "sample_id": np.dtype(np.int64),
    "instance_id": np.dtype(np.int32),
    "view_id": np.dtype(np.int32),
    "attempts": np.dtype(np.int16),
}

#: Per-sample metadata written only by some configs (``cropped``: the object touches the image border, with
#: ``--cropped flag``).
OPTIONAL_META_FIELDS: dict[str, np.dtype] = {"cropped": np.dtype(np.bool_)}


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_shard(path: Path, samples: list[dict], meta: dict[str, np.ndarray], rejections: dict | None = None) -> str:
    """Stack ``samples`` (dicts with :data:`ARRAY_FIELDS`) and write them atomically; returns the sha256.

    ``rejections`` (reason -> count of rejected views while rendering this shard) is stored as
    JSON text in the field ``rejections``.
    """
    data = shard_bytes(samples, meta, rejections)
    atomic_write_bytes(path, data)
    return hashlib.sha256(data).hexdigest()


def shard_bytes(samples: list[dict], meta: dict[str, np.ndarray], rejections: dict | None = None) -> bytes:
    """The bytes of a shard file (see :func:`write_shard`): deterministic for equal inputs."""
    arrays = {k: np.stack([np.asarray(s[k]) for s in samples]).astype(dt, copy=False) for k, dt in ARRAY_FIELDS.items()}
    for k, dt in META_FIELDS.items():
        arrays[k] = np.asarray(meta[k]).astype(dt)
    for k, dt in OPTIONAL_META_FIELDS.items():
        if k in meta:
            arrays[k] = np.asarray(meta[k]).astype(dt)
    arrays["rejections"] = np.array(json.dumps(dict(sorted((rejections or {}).items()))))
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def read_shard(path: Path, expected_sha256: str | None = None) -> dict[str, np.ndarray]:
    """Load every array of a shard.

    Raises:
        CorruptShardError: the file is missing, truncated, not an npz, lacks fields, has
            inconsistent lengths, or does not match ``expected_sha256`` (message names the shard).
    """
    path = Path(path)
    if not path.is_file():
        raise CorruptShardError(f"shard {path} is missing; rerun 'scapo generate' with the same arguments to redo it")
    if expected_sha256 is not None:
        got = sha256_file(path)
        if got != expected_sha256:
            raise CorruptShardError(
                f"shard {path} is corrupted (sha256 {got[:12]}... differs from the card's {expected_sha256[:12]}...); "
                "rerun 'scapo generate' with the dataset's arguments: it moves the shard to rejected/ and renders it "
                "again")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as e:
        raise CorruptShardError(f"shard {path} cannot be read ({type(e).__name__}: {e}); rerun 'scapo generate' "
                                "with the dataset's arguments: it moves the shard to rejected/ and renders it "
                                "again") from e
    missing = (set(ARRAY_FIELDS) | set(META_FIELDS)) - set(arrays)
    if missing:
        raise CorruptShardError(f"shard {path} lacks fields {sorted(missing)}")
    n = {len(v) for k, v in arrays.items() if k != "rejections"}
    if len(n) != 1:
        raise CorruptShardError(f"shard {path} has fields of different lengths")
    return arrays
