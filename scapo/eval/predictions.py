"""The one predictions format every method writes and the evaluator reads.

A predictions file is an ``.npz`` with stacked arrays over M predicted samples and a JSON
header in the field ``meta``:

============== ================= =========================================================
name           shape / dtype     meaning
============== ================= =========================================================
instance_id    (M,) int64        sample key, with view_id (matches the dataset manifest)
view_id        (M,) int64
split          (M,) str          "train", "val" or "test"
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

from scapo.errors import PredictionError
from scapo.files import atomic_write_bytes, check_output_file, clean_stale_temps

#: Positions (translations, pivots) a prediction may hold, in metres from the camera: far beyond any scene.
MAX_DISTANCE_M = 1e4
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
#: Fields that must hold integers (a float array is refused, never truncated).
_INTEGER_FIELDS = ("part_label", "joint_parts", "joint_type")
#: Tolerances of the checks on load: |axis| = 1 and R^T R = I, det R = +1 (float32 outputs pass).
AXIS_TOL = 1e-3
RIGID_TOL = 1e-3


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

    def _where(self, row: int) -> str:
        try:
            return f"sample {row} (instance {int(self.instance_id[row])}, view {int(self.view_id[row])})"
        except (IndexError, TypeError, ValueError):
            return f"sample {row}"

    def validate(self) -> None:
        """Check shapes, dtypes, finiteness and meaning of every field.

        Checked: every field has M rows and its documented shape (``part_pose (M, S, 4, 4)``,
        ``joint_axis`` and ``joint_pivot (M, J, 3)``, ``joint_parts (M, J, 2)``, ``joint_state`` and
        ``joint_type (M, J)``, ``T_cam_obj (M, 4, 4)``); labels, slots and joint types are integers
        (float arrays are refused, never truncated); labels are -1 or a slot index; joint types are 0 or
        1; joint axes are unit vectors (within :data:`AXIS_TOL`); poses are rigid (rotation block
        orthonormal with determinant +1 within :data:`RIGID_TOL`, last row ``0 0 0 1``); no NaN/inf;
        each (instance, view, split) appears once.

        Raises:
            PredictionError: naming the offending field and the first offending sample.
        """
        M = len(self.instance_id)
        for name in ("view_id", "split"):
            if len(getattr(self, name)) != M:
                raise PredictionError(f"predictions field {name!r} has {len(getattr(self, name))} rows, expected {M}")
        for name in ("instance_id", "view_id"):
            arr = np.asarray(getattr(self, name))
            if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
                raise PredictionError(f"predictions field {name!r} must be a 1-D integer array, got {arr.dtype} "
                                      f"of shape {arr.shape}")
        for name, (dt, ndim) in _FIELDS.items():
            arr = np.asarray(getattr(self, name))
            if arr.ndim != ndim or arr.shape[0] != M:
                raise PredictionError(f"predictions field {name!r} has shape {arr.shape}, expected {ndim} dims "
                                      f"with {M} rows")
            if name in _INTEGER_FIELDS and arr.size and not (np.issubdtype(arr.dtype, np.integer)
                                                              or arr.dtype == bool):
                raise PredictionError(f"predictions field {name!r} must hold integers, got dtype {arr.dtype}")
            if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
                raise PredictionError(f"predictions field {name!r} must be numeric, got dtype {arr.dtype}")
            if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(arr).all():
                rows = ~np.isfinite(arr).reshape(M, -1).all(1)
                raise PredictionError(f"predictions field {name!r} holds NaN/inf in {int(rows.sum())} of {M} samples "
                                      f"(first: {self._where(int(np.argmax(rows)))})")
            setattr(self, name, arr.astype(dt, copy=False))
        if self.part_pose.shape[-2:] != (4, 4) or self.T_cam_obj.shape[-2:] != (4, 4):
            raise PredictionError(f"part_pose and T_cam_obj must have shape (M, S, 4, 4) and (M, 4, 4), got "
                                  f"{self.part_pose.shape} and {self.T_cam_obj.shape}")
        for name, coords in (("T_cam_obj", self.T_cam_obj[..., :3, 3]), ("part_pose", self.part_pose[..., :3, 3]),
                             ("joint_pivot", self.joint_pivot)):
            far = np.abs(np.asarray(coords, dtype=np.float64)).reshape(M, -1).max(1, initial=0.0) > MAX_DISTANCE_M
            if far.any():  # a score in metres of such a value overflows, and would show as '-' in a table
                first = self._where(int(np.argmax(far)))
                raise PredictionError(f"predictions field {name!r} places {int(far.sum())} of {M} samples more than "
                                      f"{MAX_DISTANCE_M:g} m from the camera (first: {first}); positions are in "
                                      "metres in the camera frame")
        J = self.joint_axis.shape[1]
        for name, shape in (("joint_axis", (J, 3)), ("joint_pivot", (J, 3)), ("joint_parts", (J, 2)),
                            ("joint_state", (J,)), ("joint_type", (J,))):
            if getattr(self, name).shape[1:] != shape:
                raise PredictionError(f"predictions field {name!r} has shape {getattr(self, name).shape}, expected "
                                      f"(M, {', '.join(map(str, shape))}) with J = {J} joints (from joint_axis)")
        S = self.part_pose.shape[1]
        if self.joint_parts.size and (self.joint_parts.min() < 0 or self.joint_parts.max() >= S):
            row = int(np.argmax(((self.joint_parts < 0) | (self.joint_parts >= S)).reshape(M, -1).any(1)))
            raise PredictionError(f"joint_parts refers to slots outside 0..{S - 1} ({self._where(row)})")
        if self.part_label.size and (self.part_label.min() < -1 or self.part_label.max() >= S):
            row = int(np.argmax(((self.part_label < -1) | (self.part_label >= S)).any(1)))
            raise PredictionError(f"part_label must be -1 (not object) or a slot in 0..{S - 1}; "
                                  f"{self._where(row)} has {sorted(set(self.part_label[row].tolist()))[:6]}")
        if self.joint_type.size and not np.isin(self.joint_type, (0, 1)).all():
            row = int(np.argmax(~np.isin(self.joint_type, (0, 1)).all(1)))
            raise PredictionError(f"joint_type must be 0 (revolute) or 1 (prismatic); {self._where(row)} has "
                                  f"{self.joint_type[row].tolist()}")
        if self.joint_axis.size:
            err = np.abs(np.linalg.norm(self.joint_axis, axis=-1) - 1.0)
            if (err > AXIS_TOL).any():
                row, j = np.unravel_index(int(np.argmax(err)), err.shape)
                raise PredictionError(f"joint_axis must hold unit vectors; joint {j} of {self._where(int(row))} has "
                                      f"length {np.linalg.norm(self.joint_axis[row, j]):.4g} (a zero axis cannot be "
                                      "scored)")
        for name, T in (("part_pose", self.part_pose), ("T_cam_obj", self.T_cam_obj[:, None])):
            if not T.size:
                continue
            R = T[..., :3, :3]
            ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max((-1, -2))
            bad = (ortho > RIGID_TOL) | (np.linalg.det(R) < 0) | \
                (np.abs(T[..., 3, :] - [0.0, 0.0, 0.0, 1.0]).max(-1) > 1e-6)
            if bad.any():
                row, k = np.unravel_index(int(np.argmax(bad)), bad.shape)
                slot = f" slot {k}" if name == "part_pose" else ""
                raise PredictionError(f"predictions field {name!r} must hold rigid transforms (rotation with "
                                      f"R^T R = I, det +1, last row 0 0 0 1);{slot} of {self._where(int(row))} is not "
                                      f"(|R^T R - I| = {ortho[row, k]:.3g}, det = {np.linalg.det(R[row, k]):.3g})")
        self.split = np.asarray(self.split).astype(str)
        self.instance_id = np.asarray(self.instance_id, dtype=np.int64)
        self.view_id = np.asarray(self.view_id, dtype=np.int64)
        keys = np.rec.fromarrays([self.instance_id, self.view_id, self.split])
        uniq, first, counts = np.unique(keys, return_index=True, return_counts=True)
        if (counts > 1).any():
            row = int(first[np.argmax(counts > 1)])
            raise PredictionError(f"predictions fields instance_id, view_id, split hold {int((counts - 1).sum())} "
                                  f"duplicate samples (e.g. {self._where(row)}, {self.split[row]} split); each "
                                  "sample may appear once")

    # ---------------------------------------------------------------- io
    def meta(self) -> dict:
        return {"method": self.method, "needs_alignment": bool(self.needs_alignment),
                "supervision": self.supervision, "dataset_hash": self.dataset_hash, "info": self.info,
                "format": "scapo-predictions-1"}

    def save(self, path: str | Path) -> Path:
        """Write atomically to ``path`` (``.npz``).

        Raises:
            OutputError: ``path`` cannot be written (nothing is left under its name).
        """
        path = Path(path)
        check_output_file(path, "predictions file", "predictions.npz", replaceable=is_predictions_file)
        clean_stale_temps(path.parent, only=path.name)
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
        if path.is_file() and not zipfile.is_zipfile(path):  # np.load would read other formats (and advise pickle)
            raise PredictionError(f"predictions file {path} cannot be read: it is not an .npz archive (the format "
                                  "'scapo predict' writes)")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise PredictionError(f"predictions file {path} does not exist") from None
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
            raise PredictionError(f"predictions file {path} cannot be read: {e}") from e
        known = {"meta", "instance_id", "view_id", "split"} | set(_FIELDS)
        missing = known - set(arrays)
        if missing:
            raise PredictionError(f"predictions file {path} lacks fields {sorted(missing)}")
        extra = sorted(set(arrays) - known)
        if extra:  # not written by scapo (a file of another tool, or edited): nothing in it is guessed at
            raise PredictionError(f"predictions file {path} holds arrays a scapo predictions file has not "
                                  f"({', '.join(extra[:5])}); write it with Predictions.save (its fields: "
                                  f"{', '.join(sorted(known))})")
        try:
            meta = json.loads(str(arrays.pop("meta")))
        except ValueError as e:
            raise PredictionError(f"predictions file {path} has an unreadable header (meta: {e})") from None
        if not isinstance(meta, dict) or meta.get("format") != "scapo-predictions-1":
            fmt = meta.get("format") if isinstance(meta, dict) else None
            raise PredictionError(f"{path} is not a scapo predictions file (format {fmt!r})")
        lacking = [k for k in ("method", "needs_alignment", "supervision") if k not in meta]
        if lacking:
            raise PredictionError(f"predictions file {path}: header lacks {lacking}")
        try:
            return cls(method=str(meta["method"]), needs_alignment=bool(meta["needs_alignment"]),
                       supervision=dict(meta["supervision"]), dataset_hash=str(meta.get("dataset_hash", "")),
                       info=dict(meta.get("info", {})), **arrays)
        except PredictionError as e:
            raise PredictionError(f"predictions file {path}: {e}") from None

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


def is_predictions_file(path: str | Path) -> bool:
    """Whether ``path`` is a predictions file scapo wrote (an ``.npz`` holding its ``meta`` record), so that a new
    prediction may replace it; a dataset shard, a checkpoint or another program's file may not be replaced."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return "meta.npy" in z.namelist() and "part_pose.npy" in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False
