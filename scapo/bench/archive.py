"""A cells archive: the small files of every finished bench cell, kept outside the work folder so that a work folder
lost with its machine costs only the datasets' generation, never a trained cell.

A bench work folder holds large files (datasets, checkpoints) that cannot be committed, and a machine whose
processes and disks end with its session loses them; a table regenerated over many sessions then
recomputes every cell. The archive keeps, per finished cell, what makes its record valid again
(:func:`scapo.bench.cells._read_record`) beside a regenerated dataset::

    <archive>/<dataset folder name>/
        cells/<key>.<protocol>.json       the cell's record (scores, provenance, dataset hash, predictions' sha256)
        cells/per_sample.parquet          every cell's per-sample metrics in one compressed columnar file (a column
                                          ``_cell`` names the cell, ``<key>.<protocol>``; floats stored as float32 and
                                          unit columns such as ``t_cm`` derived, :data:`PRECISION`; the schema's
                                          metadata keeps each cell's columns, dtypes and derived columns, so that its
                                          own table comes back, :func:`archived_per_sample`); an older archive's
                                          ``<key>.<protocol>.parquet`` per cell, or float64 packed file, is still read,
                                          and :func:`pack_archive` packs it
        predictions_<key>.npz.xz          only with ``predictions=True``: its predictions, xz-compressed (restored
                                          byte for byte: the sha256 holds)
        run_<run key>/run.json            the trained run's identity (preset fields, dataset, seed) ...
        run_<run key>/timing.json         ... and its training wall time and steps (no checkpoint)

:func:`archive_cell` adds a done cell (the bench calls it after every cell when ``--archive DIR`` is given);
:func:`restore_cells` copies the archived cells of a dataset back into a work folder whose dataset has the same
hash (a dataset is generated deterministically from its config; one of another hash gets nothing restored, and
its cells are computed again). Restoring never overwrites a file of the work folder, and a record is written last,
so an interrupted restore leaves no cell that looks done without its per-sample metrics. Predictions are most of an
archive's size and are reproducible from the commit, the dataset and the seed, so they are kept only on request: a
cell restored without them is tabled from its record and per-sample metrics (its predictions' sha256 stays in the
record, so predictions made again can be checked against it), and one whose record the evaluator no longer accepts is
computed again. :func:`adopt_dataset` and :func:`rescore_cell` need archived predictions. Nothing in the archive is run:
records and run files are JSON, predictions are loaded by :meth:`scapo.eval.Predictions.load` with its checks.

The archive also pins each dataset's bytes (:func:`archive_dataset`, :func:`reconcile_dataset`)::

    <archive>/<dataset folder name>/dataset/
        card.json        the card of the dataset the cells were computed on (its hash, every shard's sha256)
        fields.json      per shard, the order of its arrays and each array's digest (dtype, shape, bytes)
        double.npz.xz    per shard, its double-precision ground truth (part poses, joint axes, pivots, states,
                         limits, camera pose, intrinsics, box diagonal), xz-compressed

A dataset is generated deterministically from its config on one kind of CPU, but not bit for bit across kinds:
numpy's and the renderer's vector kernels round the last bit of some double-precision values differently (measured
on the tables' datasets: ICP's poses and segmentation on the two machines' laptop datasets were bit-identical, its
joint axes 1.6e-15 apart, and the dataset hashes differed). A cell belongs to the bytes it was computed on, so
:func:`reconcile_dataset` makes a regenerated dataset byte-identical to the archived one when it differs only so:
every array that is not double-precision ground truth must be bit-identical, every double-precision array within
``rtol`` / ``atol`` of the archived one (which then replaces it), a float32 field derived from that ground truth
(``npcs``: :data:`DERIVED`) within float32 rounding of the one computed again from the archived ground truth (which
then replaces it, and must have the archived digest), and every shard so re-written must have the archived sha256;
otherwise nothing is changed and the cells of the archived dataset are computed again.

Cells archived before datasets were pinned name a dataset that no file keeps. A machine of another CPU kind
regenerates that dataset under another hash and cannot reconcile it (nothing is pinned to reconcile with), so
:func:`adopt_dataset` asks the cells themselves whether the regenerated dataset is theirs: every archived
prediction is scored again on it (the scores read the labels of every point and all the ground truth) and must
give the archived per-sample metrics (segmentation exactly, every error within ``atol``), and the archived cells
of deterministic untrained methods (ICP) are computed again on its inputs and must give the archived predictions
(integers exactly, floats within ``atol``: a float32 input one ulp off moves them by 1e-8, far more). Only then
are the cells re-labelled with the regenerated dataset's hash (predictions' headers, runs' identities, records
re-scored on it, with an ``adopted`` field) and that dataset is pinned; ``dataset/adopted.json`` keeps the
evidence and the replaced records' and predictions' sha256. The predictions themselves are never changed.
"""

from __future__ import annotations

import hashlib
import io
import json
import lzma
import tempfile
import time
from pathlib import Path

import numpy as np

from scapo.bench.cells import Cell, CellPaths, cell_paths
from scapo.errors import ConfigError, DatasetError, OutputError
from scapo.files import FolderLock, atomic_write_bytes, read_json, write_json

#: The files of a trained run that the archive keeps (its identity and timing; checkpoints stay in the work folder).
RUN_FILES = ("run.json", "timing.json")


def _cell_of(rec: dict) -> Cell:
    c = dict(rec.get("cell") or {})
    try:
        return Cell(method=str(c["method"]), category=str(c["category"]), seed=c.get("seed"), preset=c.get("preset"),
                    label=str(c.get("label", "")), options=tuple((str(k), v) for k, v in c.get("options", [])),
                    run_label=str(c.get("run_label", "")))
    except (KeyError, TypeError, ValueError) as e:
        raise ConfigError(f"a cell record without a readable 'cell' field ({e}); the archive or work folder "
                          "holds a damaged record: remove it so that the cell is computed again") from e


def _write(dst: Path, data: bytes) -> None:
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create the folder {dst.parent} ({e.strerror}); choose a writable archive or "
                          "work folder") from e
    atomic_write_bytes(dst, data)


def _copy(src: Path, dst: Path) -> None:
    try:
        data = src.read_bytes()
    except OSError as e:
        raise OutputError(f"could not read {src} ({e.strerror}); check that the folder is readable") from e
    _write(dst, data)


#: The file of an archive's dataset folder that holds every cell's per-sample metrics (``cells/`` beside the records).
PACKED = "per_sample.parquet"

#: How the packed file stores a cell's float64 metrics: as float32 (about seven significant digits; the tables print
#: one or two decimals of degrees, centimetres and percent, and the bootstrap resamples the same values), and a
#: column that is another one times a unit factor (``t_cm`` = 100 ``t``, ``C_cm_j0`` = 100 ``C_j0``, within 1e-9)
#: as that rule only. A layout without ``"precision"`` (an archive packed before) holds float64 as it was.
PRECISION = "float32"

#: The unit columns a packed file derives instead of storing: the part of a column's name that, taken out, names
#: the column it is a multiple of, and the factor (:func:`scapo.eval.metrics`' centimetres from metres).
_DERIVED_UNITS = {"_cm": 100.0}


def _unit_base(column: str) -> tuple[str, float] | None:
    """``("t_p0", 100.0)`` for ``"t_cm_p0"``: the column ``column`` is a multiple of and the factor, or None."""
    for part, factor in _DERIVED_UNITS.items():
        if part in column:
            return column.replace(part, "", 1), factor
    return None


def _compact(df):
    """``(stored, derived)``: the cell table ``df`` as the packed file stores it (float64 columns as float32, the
    derived unit columns dropped) and the derived columns' rules ``{column: [base column, factor]}``."""
    import numpy as np

    derived = {}
    for c in df.columns:
        rule = _unit_base(str(c))
        if rule is None or rule[0] not in df.columns or df[c].dtype != np.float64 or df[rule[0]].dtype != np.float64:
            continue
        a, b = df[c].to_numpy(), rule[1] * df[rule[0]].to_numpy()
        if np.array_equal(np.isnan(a), np.isnan(b)) and np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
            derived[str(c)] = [rule[0], rule[1]]
    out = df.drop(columns=list(derived))
    floats = [c for c in out.columns if out[c].dtype == np.float64]
    return out.astype({c: np.float32 for c in floats}), derived


def _expand(stored, layout: dict):
    """A cell's own table (its columns, in order, and dtypes) from its ``stored`` rows and ``layout``."""
    stored = stored.copy()
    for c, (base, factor) in (layout.get("derived") or {}).items():
        stored[c] = stored[base].astype("float64") * float(factor)
    return stored[layout["columns"]].astype(layout["dtypes"]).reset_index(drop=True)


def as_archived(df):
    """The per-sample table ``df`` as it comes back from a packed archive (:data:`PRECISION`): what a table
    made again from the archive reads, and what a cell scored again is compared with (:func:`rescore_cell`)."""
    stored, derived = _compact(df.reset_index(drop=True))
    return _expand(stored, {"columns": list(map(str, df.columns)), "dtypes": {str(c): str(t) for c, t in
                                                                          df.dtypes.items()}, "derived": derived})


def same_as_archived(back, df) -> bool:
    """Whether ``back`` (from the archive) is the cell table ``df`` as the archive keeps it: the same columns,
    dtypes and rows, integers and NaNs exactly, floats within float32 rounding (relative 1e-6)."""
    import numpy as np

    df = df.reset_index(drop=True)
    if back is None or list(back.columns) != list(df.columns) or list(back.dtypes) != list(df.dtypes) \
            or len(back) != len(df):
        return False
    for c in df.columns:
        a, b = back[c].to_numpy(), df[c].to_numpy()
        if np.issubdtype(b.dtype, np.floating):
            if not (np.array_equal(np.isnan(a), np.isnan(b)) and np.allclose(a, b, rtol=1e-6, atol=0, equal_nan=True)):
                return False
        elif not np.array_equal(a, b):
            return False
    return True


def archived_per_sample(cells: Path, stem: str):
    """The archived per-sample metrics (a ``pandas.DataFrame``, the cell's own columns and dtypes) of the cell
    ``stem`` (``<key>.<protocol>``) in the archive folder ``cells``: from the packed file (its floats as the file keeps
    them, :data:`PRECISION`), else from the cell's own parquet file (an archive written before the packed file); None
    where neither has it.

    Raises:
        ConfigError: the file holding it cannot be read (names it: remove the cell's files so that it is computed
            again)."""
    import pandas as pd

    packed, own = Path(cells) / PACKED, Path(cells) / f"{stem}.parquet"
    try:
        if own.is_file():
            return pd.read_parquet(own)
        return _from_packed(packed, stem) if packed.is_file() else None
    except (OSError, ValueError, KeyError, TypeError) as e:
        path = own if own.is_file() else packed
        raise ConfigError(f"the archived per-sample metrics {path} are unreadable ({e}); remove the cell's files from "
                          "the archive so that it is computed again") from e


def _layouts(packed: Path) -> dict:
    import pyarrow.parquet as pq

    return json.loads((pq.read_schema(packed).metadata or {}).get(b"scapo_cells", b"{}"))


def _from_packed(packed: Path, stem: str):
    """Cell ``stem``'s table from the packed file ``packed`` (its own columns, in order, and dtypes), or None."""
    import pyarrow.parquet as pq

    layout = _layouts(packed).get(stem)
    if layout is None:
        return None
    df = pq.read_table(packed, filters=[("_cell", "=", stem)]).to_pandas()
    return _expand(df, layout)


def _pack(cells: Path, frames: dict) -> None:
    """Put the per-sample metrics ``frames`` (stem -> DataFrame) into ``cells``' packed file, replacing those stems'
    rows (written atomically; the other cells' rows kept, those of an earlier float64 layout stored again as
    :data:`PRECISION`)."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    packed = Path(cells) / PACKED
    frames = dict(frames)
    if packed.is_file():
        for stem in _layouts(packed):
            if stem not in frames:
                frames[stem] = _from_packed(packed, stem)
    layouts, parts = {}, []
    for stem, df in sorted(frames.items()):
        stored, derived = _compact(df.reset_index(drop=True))
        layouts[stem] = {"columns": list(map(str, df.columns)),
                         "dtypes": {str(c): str(t) for c, t in df.dtypes.items()},
                         "derived": derived, "precision": PRECISION}
        parts.append(stored.assign(_cell=stem))
    table = pa.Table.from_pandas(pd.concat(parts, ignore_index=True, sort=False), preserve_index=False)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           b"scapo_cells": json.dumps(layouts, sort_keys=True).encode()})
    floats = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf, compression="zstd", compression_level=19, use_byte_stream_split=floats or False)
    _write(packed, buf.getvalue().to_pybytes())


def pack_archive(archive: Path) -> int:
    """Pack every dataset folder of ``archive`` whose cells keep their per-sample metrics in a file each (an archive
    written before :data:`PACKED`) or in a packed file of an earlier layout (float64): their tables go into the packed
    file as :data:`PRECISION`, checked to come back the same (:func:`same_as_archived`), and the per-cell files are
    deleted. Returns the number of cells packed.

    Raises:
        ConfigError: a cell's metrics do not come back the same from the packed file (nothing is deleted)."""
    import pandas as pd

    n = 0
    for cells in sorted(p for p in Path(archive).rglob("cells") if p.is_dir()):
        own = sorted(f for f in cells.glob("*.parquet") if f.name != PACKED)
        packed = cells / PACKED
        earlier = {s: _from_packed(packed, s) for s, lay in _layouts(packed).items()
                   if lay.get("precision") != PRECISION} if packed.is_file() else {}
        if not own and not earlier:
            continue
        frames = {**earlier, **{f.name[:-len(".parquet")]: pd.read_parquet(f) for f in own}}
        _pack(cells, frames)
        for stem, df in frames.items():  # read back from the packed file alone before anything is deleted
            if not same_as_archived(_from_packed(packed, stem), df):
                raise ConfigError(f"{packed}: the metrics of {stem} do not come back the same; nothing deleted")
        for f in own:
            f.unlink()
        n += len(frames)
    return n


def archive_cell(data: Path, cell: Cell, protocol: str, archive: Path, predictions: bool = False) -> bool:
    """Copy one done cell's small files from its dataset folder ``data`` into ``archive/<data.name>/``.

    Args:
        data: the dataset folder of a bench work folder (``<work>/<category>_i<I>_v<V>_s<seed>``).
        cell: the cell (its record must exist: the bench calls this after :func:`~scapo.bench.cells.compute_cell`).
        protocol: the protocol the record was scored under (``scapo``, ``eap``, ``op-align``).
        archive: the archive's root folder (created when missing).
        predictions: also keep the cell's predictions (xz-compressed); by default only their sha256 (in the record).

    Returns:
        True when anything was written (a cell new to the archive, or one whose record changed), else False.

    Raises:
        OutputError: the archive cannot be written (nothing archived before is lost: every file is written
            atomically, the record last).
    """
    src = cell_paths(data, cell, protocol)
    dst = cell_paths(Path(archive) / Path(data).name, cell, protocol)
    if not src.record.is_file():
        return False
    record = src.record.read_bytes()
    if dst.record.is_file() and dst.record.read_bytes() == record:
        return False
    xz = dst.predictions.with_name(dst.predictions.name + ".xz")
    if predictions and src.predictions.is_file():
        _write(xz, lzma.compress(src.predictions.read_bytes(), preset=6))
    if cell.trained:
        for name in RUN_FILES:
            if (src.run / name).is_file():
                _copy(src.run / name, dst.run / name)
    import pandas as pd

    try:
        _pack(dst.per_sample.parent, {dst.per_sample.name[:-len(".parquet")]: pd.read_parquet(src.per_sample)})
    except (OSError, ValueError) as e:
        raise OutputError(f"could not archive {src.per_sample} ({e})") from e
    if dst.per_sample.is_file():  # an older archive's own file of this cell: the packed rows replace it
        dst.per_sample.unlink()
    _write(dst.record, record)
    return True


def restore_cells(data: Path, archive: Path, dataset_hash: str) -> list[str]:
    """Copy the archived cells of ``data``'s dataset (``archive/<data.name>/``) into ``data`` when their records
    name ``dataset_hash``; files already in ``data`` are kept as they are (a cell whose record is there is skipped).

    Args:
        data: a generated dataset folder of a bench work folder.
        archive: the archive's root folder (missing: nothing to restore).
        dataset_hash: the hash of ``data``'s dataset (:attr:`scapo.data.Split.dataset_hash` of its test split).

    Returns:
        The restored cells' record names (``<key>.<protocol>.json``); the bench then finds them done when their
        records are valid (same evaluator, current presets and inference settings) and computes the others.

    Raises:
        OutputError: ``data`` cannot be written. ConfigError: an archived record is damaged (names it).
    """
    root = Path(archive) / Path(data).name
    restored: list[str] = []
    for rec_path in sorted((root / "cells").glob("*.json")):
        try:
            rec = json.loads(rec_path.read_text())
        except (OSError, ValueError) as e:
            raise ConfigError(f"the archived cell record {rec_path} is unreadable ({e}); remove it so that "
                              "the cell is computed again") from e
        if rec.get("dataset_hash") != dataset_hash:
            continue  # another dataset under the same name: computed again
        key, sep, protocol = rec_path.name[:-len(".json")].rpartition(".")
        cell = _cell_of(rec)
        if not sep or cell.key != key:
            raise ConfigError(f"the archived record {rec_path} is named for cell {key!r} but holds cell "
                              f"{cell.key!r}; remove it so that the cell is computed again")
        src, dst = cell_paths(root, cell, protocol), cell_paths(Path(data), cell, protocol)
        if dst.record.exists():
            continue
        _restore_predictions(src, dst)
        if cell.trained and not (dst.run / "checkpoint.pt").exists():
            for name in RUN_FILES:  # a partial run of the work folder keeps its own files
                if (src.run / name).is_file() and not (dst.run / name).exists():
                    _copy(src.run / name, dst.run / name)
        if not dst.per_sample.exists():
            df = archived_per_sample(src.per_sample.parent, src.per_sample.name[:-len(".parquet")])
            if df is not None:
                _write(dst.per_sample, df.to_parquet(index=False))
        _copy(rec_path, dst.record)
        restored.append(rec_path.name)
    return restored


def _restore_predictions(src: CellPaths, dst: CellPaths) -> None:
    xz = src.predictions.with_name(src.predictions.name + ".xz")
    if dst.predictions.exists() or not xz.is_file():
        return
    _write(dst.predictions, _decompressed(xz))


def _decompressed(xz: Path) -> bytes:
    """The bytes of archived predictions ``xz``; ConfigError (what to do) when they cannot be read."""
    try:
        return lzma.decompress(xz.read_bytes())
    except (OSError, lzma.LZMAError) as e:
        raise ConfigError(f"the archived predictions {xz} cannot be decompressed ({e}); remove the cell's "
                          "files from the archive so that it is computed again") from e


# ---------------------------------------------------------------------------------------------- dataset bytes
#: The archived dataset's subfolder of ``<archive>/<dataset folder name>/``.
DATASET = "dataset"
#: The shard fields an archived dataset keeps whole: the double-precision ground truth, computed by numpy's
#: vector kernels, whose last bit may differ between CPU kinds (:data:`scapo.data.storage.ARRAY_FIELDS`).
DOUBLE_FIELDS = ("part_pose", "joint_axis", "joint_pivot", "joint_state", "joint_limit", "T_cam_obj", "K",
                 "bbox_diag")
#: How far a regenerated double-precision value may be from the archived one (relative, and absolute in metres /
#: radians / pixels): rounding moves the last bits (1e-16 relative); a change of the generator moves far more.
RECONCILE_RTOL = 1e-9
RECONCILE_ATOL = 1e-12


def _digest(a: np.ndarray) -> str:
    """sha256 of an array's dtype, shape and bytes."""
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _card(data: Path) -> dict:
    return read_json(Path(data) / "card.json", "dataset card", DatasetError,
                     "generate the dataset first (scapo generate, or the bench generates it)")


def _shard_arrays(data: Path, name: str, sha256: str) -> dict[str, np.ndarray]:
    from scapo.data.storage import read_shard

    return read_shard(Path(data) / "shards" / f"{name}.npz", sha256)


def archived_dataset_hashes(archive: Path, name: str) -> dict[str, int]:
    """The dataset hashes that the archived cell records of dataset folder ``name`` name, with their counts.

    Raises:
        ConfigError: a record is unreadable (names it).
    """
    counts: dict[str, int] = {}
    for rec_path in sorted((Path(archive) / name / "cells").glob("*.json")):
        try:
            h = str(json.loads(rec_path.read_text()).get("dataset_hash"))
        except (OSError, ValueError, AttributeError) as e:
            raise ConfigError(f"the archived cell record {rec_path} is unreadable ({e}); remove it so that the cell "
                              "is computed again") from e
        counts[h] = counts.get(h, 0) + 1
    return counts


def archive_dataset(data: Path, archive: Path) -> str:
    """Pin the bytes of the generated dataset ``data`` in ``archive/<data.name>/dataset/`` (see the module
    docstring), unless a dataset is pinned there already.

    Args:
        data: a generated dataset folder (``card.json`` and its shards).
        archive: the archive's root folder.

    Returns:
        ``"archived"`` (written now), ``"same"`` (this dataset is pinned already), ``"other"`` (another dataset is
        pinned under this name: the archive keeps it; :func:`reconcile_dataset` may make ``data`` that one) or
        ``"unpinned cells"`` (nothing is pinned, but the archived cells under this name were computed on another
        dataset, none on this one: pinning this one would orphan them, so nothing is written; a machine that
        generates their dataset pins it).

    Raises:
        DatasetError: ``data`` has no readable card, or a shard does not match its card. OutputError: the archive
        cannot be written (the card is written last, so an interrupted call leaves no pinned dataset).
    """
    card = _card(data)
    dst = Path(archive) / Path(data).name / DATASET
    if (dst / "card.json").is_file():
        pinned = read_json(dst / "card.json", "archived dataset card", ConfigError,
                           f"remove {dst} so that the dataset is pinned again")
        return "same" if pinned.get("dataset_hash") == card["dataset_hash"] else "other"
    cells = set(archived_dataset_hashes(archive, Path(data).name))
    if cells and card["dataset_hash"] not in cells:
        return "unpinned cells"
    fields: dict[str, dict] = {}
    double: dict[str, np.ndarray] = {}
    for name in sorted(card["shards"]):
        arrays = _shard_arrays(data, name, card["shards"][name]["sha256"])
        fields[name] = {"order": list(arrays), "digests": {k: _digest(v) for k, v in arrays.items()}}
        for k in DOUBLE_FIELDS:
            double[f"{name}/{k}"] = arrays[k]
    buf = io.BytesIO()
    np.savez(buf, **double)
    _write(dst / "double.npz.xz", lzma.compress(buf.getvalue(), preset=9))
    _write(dst / "fields.json", json.dumps(fields, sort_keys=True).encode())
    _write(dst / "card.json", json.dumps(card, indent=1, sort_keys=True).encode())
    return "archived"


def archive_conflict(data: Path, archive: Path) -> str:
    """Why cells computed on the generated dataset ``data`` would not belong in ``archive/<data.name>/``, or ``""``
    when they would (its dataset is the pinned one, or nothing is pinned or archived under that name).

    A dataset other than the pinned one (one that :func:`reconcile_dataset` could not make the pinned bytes), or,
    with nothing pinned, a dataset other than the one every archived cell names, would put cells of two datasets
    under one name, and a table takes the cells of one. The tables' runner computes no cell of such a dataset.

    Raises:
        DatasetError: ``data`` has no readable card. ConfigError: an archived record or card is unreadable.
    """
    have = _card(data)["dataset_hash"]
    root = Path(archive) / Path(data).name
    if (root / DATASET / "card.json").is_file():
        pinned = read_json(root / DATASET / "card.json", "archived dataset card", ConfigError,
                           f"remove {root / DATASET} so that the dataset is pinned again")["dataset_hash"]
        return "" if pinned == have else (f"this machine generated dataset {have[:12]} and could not make it the "
                                          f"pinned {pinned[:12]}")
    cells = archived_dataset_hashes(archive, Path(data).name)
    if cells and have not in cells:
        return (f"the archived cells name dataset {', '.join(h[:12] for h in cells)}, which is not pinned, and "
                f"this machine generated {have[:12]}; a machine that generates theirs pins it (--data-only), or "
                "this machine's is adopted if the cells show it is theirs "
                "(bench/diagnostics/cross_cpu_check.py --adopt)")
    return ""


def _npcs_again(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """A shard's ``npcs`` ``(B, N, 3)`` float32 computed again, view by view, from its points, labels, part poses
    and box diagonals (:func:`scapo.sim.render.npcs_of`, the generator's own function)."""
    from scapo.sim.render import npcs_of

    pts, lab, pose, diag = arrays["points"], arrays["part_label"], arrays["part_pose"], arrays["bbox_diag"]
    if not (len(pts) == len(lab) == len(pose) == len(diag)):
        raise ValueError("its arrays hold different numbers of views")
    return np.stack([npcs_of(pts[i], lab[i], pose[i], float(diag[i])) for i in range(len(pts))])


#: float32 fields that the generator derives from double-precision ground truth, with the function that derives
#: them: rounding moves such a value by one float32 ulp where the double it is rounded from crosses a float32
#: boundary (measured: one value in each of two of washer's shards, Table 1's dataset), so a regenerated dataset's
#: field is computed again from the archived ground truth and must then have the archived digest.
DERIVED = {"npcs": _npcs_again}
#: How far a regenerated derived field may be from the one computed again from the archived ground truth (relative:
#: a few float32 ulps); more means this machine's generator computes it otherwise, and nothing is reconciled.
DERIVED_RTOL = 1e-6


def reconcile_dataset(data: Path, archive: Path, rtol: float = RECONCILE_RTOL,
                      atol: float = RECONCILE_ATOL) -> dict:
    """Make the generated dataset ``data`` byte-identical to the one pinned in ``archive/<data.name>/dataset/``
    when the two differ only by the rounding of double-precision ground truth (see the module docstring).

    Args:
        data: a generated dataset folder (its generation finished: ``card.json`` exists).
        archive: the archive's root folder.
        rtol, atol: how far a double-precision value may be from the archived one.

    Returns:
        A report: ``status`` is ``"none"`` (nothing pinned under this name), ``"same"`` (``data`` is the pinned
        dataset), ``"reconciled"`` (shards re-written: ``shards`` of them, ``max_abs_diff`` per field,
        ``recomputed``: per derived field, the shards in which it was computed again; the same
        report is written to ``data/reconciled.json``) or ``"different"`` (``why``: the first difference that is
        not rounding; ``data`` is left as it was, and the archived cells of that dataset are not restored).

    Raises:
        DatasetError: ``data`` or the archive's dataset is damaged (names the file), or the re-written dataset does
        not have the pinned hash. OutputError: ``data`` is in use by another process or cannot be written.
    """
    from scapo.data.config import GenerateConfig
    from scapo.data.generate import config_sha256, generate, record_shard

    src = Path(archive) / Path(data).name / DATASET
    if not (src / "card.json").is_file():
        return {"status": "none"}
    hint = f"remove {src} so that the dataset is pinned again from a generated one"
    pinned = read_json(src / "card.json", "archived dataset card", DatasetError, hint)
    fields = read_json(src / "fields.json", "archived dataset fields", DatasetError, hint)
    card = _card(data)
    if card.get("dataset_hash") == pinned.get("dataset_hash"):
        return {"status": "same", "dataset_hash": card["dataset_hash"]}

    def different(why: str) -> dict:
        return {"status": "different", "why": why, "dataset_hash": card["dataset_hash"],
                "archived": pinned.get("dataset_hash")}

    if card.get("config") != pinned.get("config"):
        return different("the datasets' configs differ")
    if set(card.get("shards", {})) != set(pinned.get("shards", {})) or set(fields) != set(pinned["shards"]):
        return different("the datasets' shards differ")
    try:
        with np.load(io.BytesIO(lzma.decompress((src / "double.npz.xz").read_bytes())), allow_pickle=False) as z:
            double = {k: z[k] for k in z.files}
    except (OSError, lzma.LZMAError, ValueError, EOFError) as e:
        raise DatasetError(f"the archived dataset values {src / 'double.npz.xz'} cannot be read ({e}); {hint}") from e
    rewrite: dict[str, bytes] = {}
    diffs: dict[str, float] = {}
    recomputed: dict[str, int] = {}
    for name in sorted(pinned["shards"]):
        want_sha = pinned["shards"][name]["sha256"]
        have_sha = card["shards"][name]["sha256"]
        if have_sha == want_sha:
            continue
        arrays = _shard_arrays(data, name, have_sha)
        try:
            order, digests = list(fields[name]["order"]), dict(fields[name]["digests"])
        except (KeyError, TypeError, ValueError) as e:
            raise DatasetError(f"the archived dataset fields {src / 'fields.json'} lack shard {name}'s order or "
                               f"digests ({e}); {hint}") from e
        if list(arrays) != order or set(digests) != set(order):
            return different(f"shard {name} holds other arrays ({', '.join(arrays)})")
        derived = []
        for k in order:
            if _digest(arrays[k]) == digests[k]:
                continue
            ref = double.get(f"{name}/{k}")
            if ref is None and k in DERIVED:
                derived.append(k)  # computed again below, from the archived ground truth
                continue
            if ref is None:
                return different(f"shard {name}'s {k} differs, and it is not double-precision ground truth")
            if _digest(ref) != digests[k]:
                raise DatasetError(f"the archived values of shard {name}'s {k} ({src / 'double.npz.xz'}) do not "
                                   f"match their digest in fields.json; {hint}")
            a = arrays[k]
            if a.shape != ref.shape or a.dtype != ref.dtype:
                return different(f"shard {name}'s {k} has another shape or type than the archived one")
            if not np.allclose(a, ref, rtol=rtol, atol=atol, equal_nan=True):
                d = float(np.nanmax(np.abs(a - ref)))
                return different(f"shard {name}'s {k} differs by up to {d:.3g} (more than rounding)")
            diffs[k] = max(diffs.get(k, 0.0), float(np.nanmax(np.abs(a - ref))) if a.size else 0.0)
            arrays[k] = ref
        for k in derived:
            try:
                again = DERIVED[k](arrays)
            except (KeyError, IndexError, ValueError) as e:
                return different(f"shard {name}'s {k} differs and cannot be computed again from its ground truth "
                                 f"({e})")
            if again.shape != arrays[k].shape or not np.allclose(arrays[k], again, rtol=DERIVED_RTOL, atol=0):
                return different(f"shard {name}'s {k} differs from the one computed again from its ground truth "
                                 "by more than float32 rounding")
            if _digest(again) != digests[k]:
                return different(f"shard {name}'s {k} differs, and computed again from the archived ground truth "
                                 "it is not the archived one either")
            diffs[k] = max(diffs.get(k, 0.0), float(np.abs(arrays[k].astype(np.float64) - again).max()))
            recomputed[k] = recomputed.get(k, 0) + 1
            arrays[k] = again
        buf = io.BytesIO()
        np.savez(buf, **{k: arrays[k] for k in order})  # as scapo.data.storage.shard_bytes writes a shard
        raw = buf.getvalue()
        if hashlib.sha256(raw).hexdigest() != want_sha:
            return different(f"shard {name} re-written with the archived values is not the archived shard")
        rewrite[name] = raw
    cfg = GenerateConfig.from_dict(card["config"])
    with FolderLock(data, "reconcile"):
        for name, raw in rewrite.items():
            atomic_write_bytes(Path(data) / "shards" / f"{name}.npz", raw)
            record_shard(Path(data), name, pinned["shards"][name]["sha256"], config_sha256(cfg),
                         reconciled_from=str(src))
    generate(cfg, data, progress=False)  # renders nothing (every shard verifies): writes the manifest and card
    got = _card(data)["dataset_hash"]
    if got != pinned["dataset_hash"]:
        raise DatasetError(f"{data}: after reconciling with {src}, its hash is {got[:12]} and not the archived "
                           f"{pinned['dataset_hash'][:12]}; delete {data} and generate it again")
    report = {"status": "reconciled", "dataset_hash": got, "generated_hash": card["dataset_hash"],
              "archive": str(src), "shards": len(rewrite), "max_abs_diff": dict(sorted(diffs.items())),
              "recomputed": dict(sorted(recomputed.items())),
              "rtol": rtol, "atol": atol, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    write_json(Path(data) / "reconciled.json", report)
    return report


# ---------------------------------------------------------------------------------------------- adoption
#: How far a per-sample error of an archived cell scored again on a regenerated dataset, and a float of an untrained
#: method's predictions computed again on it, may be from the archived one (absolute, in the metric's unit:
#: degrees, centimetres, metres). Rounding of double-precision ground truth moves them by 1e-12 (measured on issue
#: 31's 73 archived cells, ``results/diagnostics/cross_cpu`` (at 9a79e15)); a float32 input one ulp off moves them by
#: 1e-8.
ADOPT_ATOL = 1e-9
#: The evidence file of :func:`adopt_dataset`, in ``<archive>/<dataset folder name>/dataset/``.
ADOPTED = "adopted.json"


def _archived_predictions(root: Path, rec: dict, rec_path: Path):
    """The archived predictions of record ``rec`` (decompressed, their sha256 checked), or None when not kept."""
    from scapo.eval import Predictions

    xz = root / (str(rec.get("predictions") or "") + ".xz")
    if not rec.get("predictions") or not xz.is_file():
        return None
    raw = _decompressed(xz)
    if hashlib.sha256(raw).hexdigest() != rec.get("predictions_sha256"):
        raise ConfigError(f"the archived predictions {xz} are not the ones {rec_path.name} scored (sha256 differs); "
                          "remove the cell's files from the archive so that it is computed again")
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "predictions.npz").write_bytes(raw)
        return Predictions.load(Path(tmp) / "predictions.npz")


def rescore_cell(root: Path, rec_path: Path, data: Path) -> dict | None:
    """Score an archived cell's predictions again, under its record's protocol, on the generated dataset ``data``
    (its hash unchecked) and compare the per-sample metrics with the archived ones.

    Args:
        root: ``<archive>/<dataset folder name>``. rec_path: one of its ``cells/<key>.<protocol>.json``.
        data: a generated dataset folder (float64 metrics in degrees / centimetres / metres, as the evaluator's).

    Returns:
        None when the cell's predictions are not archived; else ``cell``, ``protocol``, ``archived_dataset``,
        ``samples``, ``same_samples`` (the same (instance, view) rows in the same order), ``S_identical``,
        ``nan_pattern_same``, ``max_abs_diff`` (over every numeric per-sample column), ``worst_column``,
        ``summary_S`` and ``summary_R`` (archived, here) and, for :func:`adopt_dataset`, ``result`` (the
        :class:`~scapo.eval.EvalResult`) and ``predictions`` (the archived :class:`~scapo.eval.Predictions`).

    Raises:
        ConfigError: the archived record, per-sample metrics or predictions are damaged (names the file).
        DatasetError / PredictionError: as :func:`scapo.eval.evaluate`.
    """
    import pandas as pd

    from scapo.eval import evaluate

    rec = read_json(rec_path, "archived cell record", ConfigError, "remove it so that the cell is computed again")
    key, _, protocol = rec_path.name[:-len(".json")].rpartition(".")
    preds = _archived_predictions(root, rec, rec_path)
    if preds is None:
        return None
    res = evaluate(data, preds, protocol=protocol, check_hash=False)
    old = archived_per_sample(rec_path.parent, rec_path.name[:-len(".json")])
    if old is None:
        raise ConfigError(f"no archived per-sample metrics of {rec_path.name[:-len('.json')]} in {rec_path.parent}; "
                          "remove the cell's files from the archive so that it is computed again")
    new = res.per_sample.reset_index(drop=True)
    packed = rec_path.parent / PACKED
    stem = rec_path.name[:-len(".json")]
    if packed.is_file() and (_layouts(packed).get(stem) or {}).get("precision") == PRECISION:
        new = as_archived(new)  # compared as the archive keeps it (float32)
    ids = [c for c in ("instance_id", "view_id") if c in old.columns and c in new.columns]
    same_rows = len(old) == len(new) and all(np.array_equal(old[c].to_numpy(), new[c].to_numpy()) for c in ids)
    cols = [c for c in old.columns if c in new.columns and pd.api.types.is_numeric_dtype(old[c])]
    row = {"cell": key, "protocol": protocol, "archived_dataset": str(rec.get("dataset_hash")),
           "samples": len(new), "same_samples": bool(same_rows), "S_identical": False, "nan_pattern_same": False,
           "max_abs_diff": float("inf"), "worst_column": "",
           "summary_S": (rec.get("summary", {}).get("S"), res.summary.get("S")),
           "summary_R": (rec.get("summary", {}).get("R"), res.summary.get("R")),
           "result": res, "predictions": preds}
    if not same_rows or "S" not in cols:
        return row
    a, b = old[cols].to_numpy(dtype=np.float64), new[cols].to_numpy(dtype=np.float64)
    diff = np.where(np.isnan(a) & np.isnan(b), 0.0, np.abs(a - b))
    diff = np.where(np.isnan(diff), np.inf, diff)
    worst = int(np.argmax(diff.max(axis=0))) if diff.size else 0
    row.update(S_identical=bool(np.array_equal(old["S"].to_numpy(), new["S"].to_numpy())),
               nan_pattern_same=bool((np.isnan(a) == np.isnan(b)).all()),
               max_abs_diff=float(diff.max()) if diff.size else 0.0, worst_column=cols[worst] if cols else "")
    return row


def _json_bytes(obj) -> bytes:
    """``obj`` as :func:`scapo.files.write_json` writes it (records and run identities)."""
    return (json.dumps(obj, indent=1, sort_keys=True, default=str) + "\n").encode()


def _replace_hash(obj, old: str, new: str):
    """``obj`` (JSON values) with every string equal to ``old`` replaced by ``new``."""
    if isinstance(obj, dict):
        return {k: _replace_hash(v, old, new) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_replace_hash(v, old, new) for v in obj]
    return new if obj == old else obj


#: Untrained methods whose predictions are a deterministic function of a dataset's inputs (:func:`adopt_dataset`
#: computes their archived cells again to compare inputs).
UNTRAINED_DETERMINISTIC = ("icp",)


def _recompute_untrained(rec: dict, preds, data: Path, atol: float, progress: bool) -> dict:
    """Compute an archived untrained cell (its method and options, from its record) again on ``data`` and compare
    its predictions with the archived ``preds``: integer fields exactly, float fields within ``atol``. The report
    says, per field, how many entries and samples differ (integers) or the largest difference (floats)."""
    from scapo.eval.predictions import _FIELDS
    from scapo.methods import run_method

    cell = _cell_of(rec)
    with tempfile.TemporaryDirectory() as tmp:
        again = run_method(cell.method, data, Path(tmp) / "predictions.npz", progress=progress, **dict(cell.options))
    out = {"cell": cell.key, "method": cell.method, "identical": True, "max_abs_diff": 0.0, "field": "",
           "fields": {}, "within_atol": False}
    rows = np.ones(len(preds), dtype=bool) if len(preds) == len(again) else None
    for k in ("instance_id", "view_id", "split", *_FIELDS):
        a, b = np.asarray(getattr(preds, k)), np.asarray(getattr(again, k))
        if a.dtype.kind == "U":  # split names: the width of the string type is the writer's
            a, b = a.astype(str).astype(object), b.astype(str).astype(object)
        if a.shape != b.shape or a.dtype != b.dtype:
            return {**out, "identical": False, "max_abs_diff": float("inf"), "field": f"{k} (shape or type)"}
        if not np.issubdtype(a.dtype, np.floating):
            bad = (a != b).reshape(len(a), -1)
            if bad.any():  # how many entries, in how many samples
                out["fields"][k] = {"entries": int(bad.sum()), "samples": int(bad.any(1).sum())}
                out.update(identical=False, max_abs_diff=float("inf"), field=out["field"] or k)
                rows &= ~bad.any(1)
            continue
        d = np.abs(a.astype(np.float64) - b).reshape(len(a), -1).max(1) if a.size else np.zeros(len(a))
        out["fields"][k] = {"max_abs_diff": float(d.max()) if d.size else 0.0,
                            "samples_over_atol": int((d > atol).sum())}
        if out["fields"][k]["max_abs_diff"] > out["max_abs_diff"]:
            out.update(max_abs_diff=out["fields"][k]["max_abs_diff"], field=k)
        out["identical"] = out["identical"] and not d.any()
    if rows is not None and out["max_abs_diff"] == float("inf"):  # the floats of the samples whose integers agree
        out["float_diff_where_integers_agree"] = max(
            (float(np.abs(np.asarray(getattr(preds, k), np.float64)[rows] - getattr(again, k)[rows]).max())
             for k in _FIELDS if np.issubdtype(np.asarray(getattr(preds, k)).dtype, np.floating) and rows.any()),
            default=0.0)
    out["within_atol"] = out["max_abs_diff"] <= atol
    return out


def adopt_dataset(data: Path, archive: Path, atol: float = ADOPT_ATOL, progress: bool = False) -> dict:
    """Re-label the archived cells of ``archive/<data.name>/``, computed on a dataset that is not pinned, with the
    hash of the generated dataset ``data`` and pin it, when the cells show that it is their dataset regenerated on
    another CPU kind (see the module docstring for the checks).

    Args:
        data: a generated dataset folder of the same folder name (config) as the archived cells'.
        archive: the archive's root folder.
        atol: :data:`ADOPT_ATOL`.
        progress: show the untrained methods' progress bars.

    Returns:
        A report: ``status`` is ``"none"`` (no archived cell), ``"pinned"`` (a dataset is pinned:
        :func:`reconcile_dataset` decides), ``"same"`` (the cells name ``data``'s dataset already), ``"adopted"``
        (with ``from``, ``dataset_hash``, ``cells``, ``max_abs_diff``, ``untrained``, ``cell_evidence``; written to
        ``dataset/adopted.json`` too) or ``"different"`` (``why``; nothing written).

    Raises:
        ConfigError: an archived file is damaged (names it). DatasetError: ``data`` is not a generated dataset.
        OutputError: the archive cannot be written. Every check runs before the first write; the predictions, runs
        and per-sample metrics are written before the records that name them, the pinned card last (an interrupted
        call is reported by the next one, which asks for the folder's files back from git).
    """
    from scapo.provenance import provenance

    data, root = Path(data), Path(archive) / Path(data).name
    card = _card(data)
    have = str(card["dataset_hash"])
    if (root / DATASET / "card.json").is_file():
        return {"status": "pinned"}
    hashes = archived_dataset_hashes(archive, data.name)
    if not hashes:
        return {"status": "none"}

    def different(why: str) -> dict:
        return {"status": "different", "why": why, "dataset_hash": have, "archived": sorted(hashes)}

    records = [(p, read_json(p, "archived cell record", ConfigError, "remove it so that the cell is computed again"))
               for p in sorted((root / "cells").glob("*.json"))]
    if (root / DATASET / ADOPTED).is_file() or any("adopted" in rec for _, rec in records):
        return different(f"an adoption of {root} was interrupted; restore its files (git checkout -- {root}) and "
                         "adopt again")
    if set(hashes) == {have}:
        return {"status": "same", "dataset_hash": have}
    if len(hashes) > 1:
        return different(f"the archived cells name {len(hashes)} datasets ({', '.join(h[:12] for h in hashes)})")
    old = next(iter(hashes))
    structure = {k: card[k] for k in ("category", "part_names", "joint_type", "joint_parts")}
    rows, untrained, runs = [], [], {}
    for rec_path, rec in records:
        row = rescore_cell(root, rec_path, data)
        if row is None:
            return different(f"{rec_path.name}'s predictions are not archived, so it cannot be scored again")
        if not (row["same_samples"] and row["S_identical"] and row["nan_pattern_same"]
                and row["max_abs_diff"] <= atol):
            return different(f"{rec_path.name} scored on this dataset differs from its archived scores (samples "
                             f"same: {row['same_samples']}, S identical: {row['S_identical']}, NaNs same: "
                             f"{row['nan_pattern_same']}, largest difference {row['max_abs_diff']:.3g} in "
                             f"{row['worst_column'] or '-'})")
        cell = _cell_of(rec)
        if cell.trained:
            run = cell_paths(root, cell, row["protocol"]).run
            ident = read_json(run / "run.json", "archived run identity", ConfigError,
                              "remove the cell's files from the archive so that it is computed again")
            if ident.get("dataset_hash") != old or {k: ident.get(k) for k in structure} != structure:
                return different(f"{run.name}/run.json names another dataset or object structure")
            runs[run] = ident
        elif cell.method in UNTRAINED_DETERMINISTIC:
            check = _recompute_untrained(rec, row["predictions"], data, atol, progress)
            if not check["within_atol"]:
                where = "; ".join(f"{k}: {v['entries']} entries in {v['samples']} samples" if "entries" in v else
                                  f"{k}: {v['samples_over_atol']} samples beyond {atol:g}"
                                  for k, v in check["fields"].items() if v.get("entries") or v.get("samples_over_atol"))
                return {**different(f"{cell.method} computed again on this dataset's inputs differs from the archived "
                                    f"{rec_path.name} ({where or check['field']}), so nothing shows that its inputs "
                                    "are the cells'"), "untrained": [check]}
            untrained.append(check)
        rows.append((rec_path, rec, row))
    if not untrained:
        return different("no archived cell of a deterministic untrained method (ICP) to compute again, so nothing "
                         "shows that this dataset's inputs are the cells'")
    prov = provenance()
    writes: list[tuple[Path, bytes]] = []
    finals: list[tuple[Path, bytes]] = []
    metrics: dict = {}  # the adopted cells' per-sample metrics, packed
    evidence = []
    for rec_path, rec, row in rows:
        preds = row["predictions"]
        preds.dataset_hash = have
        preds.info = _replace_hash(preds.info, old, have)
        with tempfile.TemporaryDirectory() as tmp:
            raw = preds.save(Path(tmp) / "predictions.npz").read_bytes()
        sha = hashlib.sha256(raw).hexdigest()
        writes.append((root / (rec["predictions"] + ".xz"), lzma.compress(raw, preset=6)))
        metrics.setdefault(rec_path.parent, {})[rec_path.name[:-len(".json")]] = \
            row["result"].per_sample.reset_index(drop=True)
        evidence.append({k: row[k] for k in ("cell", "protocol", "samples", "S_identical", "nan_pattern_same",
                                            "max_abs_diff", "worst_column", "summary_S", "summary_R")}
                        | {"record_sha256": hashlib.sha256(rec_path.read_bytes()).hexdigest(),
                           "predictions_sha256": rec["predictions_sha256"], "adopted_predictions_sha256": sha})
        new = _replace_hash(rec, old, have)
        new.update(predictions_sha256=sha, summary=row["result"].summary,
                   info=_replace_hash(json.loads(json.dumps(row["result"].info, default=str)), old, have),
                   adopted={"from": old, "evidence": f"{DATASET}/{ADOPTED}", "max_abs_diff": row["max_abs_diff"],
                            "commit": prov["commit"], "time": prov["time"]})
        finals.append((rec_path, _json_bytes(new)))
    writes += [(run / "run.json", _json_bytes(_replace_hash(ident, old, have))) for run, ident in runs.items()]
    report = {"status": "adopted", "from": old, "dataset_hash": have, "cells": len(evidence),
              "max_abs_diff": max(e["max_abs_diff"] for e in evidence), "untrained": untrained, "atol": atol,
              "provenance": prov, "cell_evidence": evidence}
    for path, raw in writes:
        _write(path, raw)
    for cells, frames in metrics.items():
        _pack(cells, frames)
        for stem in frames:  # an older archive's own files of these cells: the packed rows replace them
            (cells / f"{stem}.parquet").unlink(missing_ok=True)
    for path, raw in finals:
        _write(path, raw)
    _write(root / DATASET / ADOPTED, raw := _json_bytes(report))
    pinned = archive_dataset(data, archive)
    if pinned != "archived":
        raise ConfigError(f"{root}: the cells were adopted but pinning the dataset answered {pinned!r}; restore the "
                          f"folder's files (git checkout -- {root}) and adopt again")
    return json.loads(raw)


__all__ = ["ADOPTED", "ADOPT_ATOL", "DATASET", "DOUBLE_FIELDS", "RECONCILE_ATOL", "RECONCILE_RTOL", "RUN_FILES",
           "UNTRAINED_DETERMINISTIC", "adopt_dataset", "archive_cell", "archive_conflict", "archive_dataset",
           "archived_dataset_hashes", "archived_per_sample", "as_archived", "pack_archive", "PACKED", "PRECISION",
           "same_as_archived", "reconcile_dataset",
           "rescore_cell", "restore_cells"]
