"""The one predictions format every method writes and the evaluator reads.

A predictions file is an ``.npz`` with stacked arrays over M predicted samples and a JSON
header in the field ``meta``:

============== ================= =========================================================
name           shape / dtype     meaning
============== ================= =========================================================
instance_id    (M,) int64        sample key, with view_id (matches the dataset manifest)
view_id        (M,) int64
split          (M,) str          "train" or "test"
part_label     (M, N) int64      predicted slot per input point (-1 = not object)
part_pose      (M, S, 4, 4) f64  slot pose: predicted canonical frame -> camera (m)
joint_parts    (M, J, 2) int64   (parent slot, child slot) of each predicted joint
joint_type     (M, J) int64      0 revolute, 1 prismatic
joint_axis     (M, J, 3) f64     unit axis, camera frame
joint_pivot    (M, J, 3) f64     point on the axis, camera frame (m)
joint_state    (M, J) f64        rad / m, relative to the method's canonical rest state
T_cam_obj      (M, 4, 4) f64     predicted object (canonical) pose
============== ================= =========================================================

``meta`` holds ``method``, ``needs_alignment`` (True for self-supervised methods whose canonical
frame is arbitrary), ``supervision`` ({"pose", "segmentation", "joint"} -> bool), ``dataset_hash``
and free-form ``info`` (config, preset, timing).
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scapo.data.storage import atomic_write_bytes
from scapo.errors import PredictionError

_FIELDS = {
    "part_label": (np.int64, 2),
    "part_pose": (np.float64, 4),
    "joint_parts": (np.int64, 3),
    "joint_type": (np.int64, 2),
    "joint_axis": (np.float64, 3),
    "joint_pivot": (np.float64, 3),
    "joint_state": (np.float64, 2),
    "T_cam_obj": (np.float64, 3),
}


@dataclass
class Predictions:
    """Predictions of one method on (part of) one dataset; see the module docstring for fields."""

    method: str
    instance_id: np.ndarray
    view_id: np.ndarray
    split: np.ndarray
    part_label: np.ndarray
    part_pose: np.ndarray
    joint_parts: np.ndarray
    joint_type: np.ndarray
    joint_axis: np.ndarray
    joint_pivot: np.ndarray
    joint_state: np.ndarray
    T_cam_obj: np.ndarray
    needs_alignment: bool = False
    supervision: dict = field(default_factory=lambda: {"pose": False, "segmentation": False, "joint": False})
    dataset_hash: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.validate()

    def __len__(self) -> int:
        return len(self.instance_id)

    def validate(self) -> None:
        """Check shapes, dtypes and finiteness.

        Raises:
            PredictionError: naming the offending field.
        """
        M = len(self.instance_id)
        for name in ("view_id", "split"):
            if len(getattr(self, name)) != M:
                raise PredictionError(f"predictions field {name!r} has {len(getattr(self, name))} rows, expected {M}")
        for name, (dt, ndim) in _FIELDS.items():
            arr = np.asarray(getattr(self, name))
            if arr.ndim != ndim or arr.shape[0] != M:
                raise PredictionError(f"predictions field {name!r} has shape {arr.shape}, expected {ndim} dims "
                                      f"with {M} rows")
            if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(arr).all():
                bad = int(np.count_nonzero(~np.isfinite(arr).reshape(M, -1).all(1)))
                raise PredictionError(f"predictions field {name!r} holds NaN/inf in {bad} of {M} samples")
            setattr(self, name, arr.astype(dt, copy=False))
        if self.part_pose.shape[-2:] != (4, 4) or self.T_cam_obj.shape[-2:] != (4, 4):
            raise PredictionError(f"part_pose and T_cam_obj must have shape (..., 4, 4), got {self.part_pose.shape} "
                                  f"and {self.T_cam_obj.shape}")
        J = self.joint_axis.shape[1]
        if self.joint_pivot.shape[1] != J or self.joint_state.shape[1] != J or self.joint_parts.shape[1:] != (J, 2):
            raise PredictionError("joint_axis, joint_pivot, joint_state and joint_parts disagree on J")
        S = self.part_pose.shape[1]
        if self.joint_parts.size and (self.joint_parts.min() < 0 or self.joint_parts.max() >= S):
            raise PredictionError(f"joint_parts refers to slots outside 0..{S - 1}")
        if self.part_label.size and self.part_label.max() >= S:
            raise PredictionError(f"part_label refers to slots outside -1..{S - 1}")
        self.split = np.asarray(self.split).astype(str)
        self.instance_id = np.asarray(self.instance_id, dtype=np.int64)
        self.view_id = np.asarray(self.view_id, dtype=np.int64)

    # ---------------------------------------------------------------- io
    def meta(self) -> dict:
        return {"method": self.method, "needs_alignment": bool(self.needs_alignment),
                "supervision": self.supervision, "dataset_hash": self.dataset_hash, "info": self.info,
                "format": "scapo-predictions-1"}

    def save(self, path: str | Path) -> Path:
        """Write atomically to ``path`` (``.npz``)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {k: getattr(self, k) for k in _FIELDS}
        arrays.update(instance_id=self.instance_id, view_id=self.view_id, split=self.split.astype("U8"),
                      meta=np.array(json.dumps(self.meta(), default=str)))
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        return path

    @classmethod
    def load(cls, path: str | Path) -> Predictions:
        """Read a predictions file.

        Raises:
            PredictionError: unreadable file, missing fields, bad shapes or NaN (names the problem).
        """
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise PredictionError(f"predictions file {path} does not exist") from None
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
            raise PredictionError(f"predictions file {path} cannot be read: {e}") from e
        missing = ({"meta", "instance_id", "view_id", "split"} | set(_FIELDS)) - set(arrays)
        if missing:
            raise PredictionError(f"predictions file {path} lacks fields {sorted(missing)}")
        meta = json.loads(str(arrays.pop("meta")))
        if meta.get("format") != "scapo-predictions-1":
            raise PredictionError(f"{path} is not a scapo predictions file (format {meta.get('format')!r})")
        return cls(method=meta["method"], needs_alignment=meta["needs_alignment"], supervision=meta["supervision"],
                   dataset_hash=meta.get("dataset_hash", ""), info=meta.get("info", {}), **arrays)

    def select(self, mask: np.ndarray) -> Predictions:
        """Rows where ``mask`` is True."""
        kw = {k: getattr(self, k)[mask] for k in (*_FIELDS, "instance_id", "view_id", "split")}
        return Predictions(method=self.method, needs_alignment=self.needs_alignment, supervision=self.supervision,
                           dataset_hash=self.dataset_hash, info=self.info, **kw)

    @staticmethod
    def concatenate(parts: list[Predictions]) -> Predictions:
        first = parts[0]
        kw = {k: np.concatenate([getattr(p, k) for p in parts]) for k in (*_FIELDS, "instance_id", "view_id", "split")}
        return Predictions(method=first.method, needs_alignment=first.needs_alignment, supervision=first.supervision,
                           dataset_hash=first.dataset_hash, info=first.info, **kw)
