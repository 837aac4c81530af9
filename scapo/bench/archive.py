"""A cells archive: the small files of every finished bench cell, kept outside the work folder so that a work folder
lost with its machine costs only the datasets' generation, never a trained cell.

A bench work folder holds large files (datasets, checkpoints) that cannot be committed, and a machine whose
processes and disks end with its session loses them; a table regenerated over many sessions (issue 31) then
recomputes every cell. The archive keeps, per finished cell, what makes its record valid again
(:func:`scapo.bench.cells._read_record`) beside a regenerated dataset::

    <archive>/<dataset folder name>/
        cells/<key>.<protocol>.json       the cell's record (scores, provenance, dataset hash, predictions' sha256)
        cells/<key>.<protocol>.parquet    its per-sample metrics
        predictions_<key>.npz.xz          its predictions, xz-compressed (restored byte for byte: the sha256 holds)
        run_<run key>/run.json            the trained run's identity (preset fields, dataset, seed) ...
        run_<run key>/timing.json         ... and its training wall time and steps (no checkpoint)

:func:`archive_cell` adds a done cell (the bench calls it after every cell when ``--archive DIR`` is given);
:func:`restore_cells` copies the archived cells of a dataset back into a work folder whose dataset has the same
hash (a dataset is generated deterministically from its config; one of another hash gets nothing restored, and
its cells are computed again). Restoring never overwrites a file of the work folder, and a record is written last,
so an interrupted restore leaves no cell that looks done without its predictions. Nothing in the archive is run:
records and run files are JSON, predictions are loaded by :meth:`scapo.eval.Predictions.load` with its checks.

The archive also pins each dataset's bytes (:func:`archive_dataset`, :func:`reconcile_dataset`)::

    <archive>/<dataset folder name>/dataset/
        card.json        the card of the dataset the cells were computed on (its hash, every shard's sha256)
        fields.json      per shard, the order of its arrays and each array's digest (dtype, shape, bytes)
        double.npz.xz    per shard, its double-precision ground truth (part poses, joint axes, pivots, states,
                         limits, camera pose, intrinsics, box diagonal), xz-compressed

A dataset is generated deterministically from its config on one kind of CPU, but not bit for bit across kinds:
numpy's and the renderer's vector kernels round the last bit of some double-precision values differently (measured
on issue 31's datasets: ICP's poses and segmentation on the two machines' laptop datasets were bit-identical, its
joint axes 1.6e-15 apart, and the dataset hashes differed). A cell belongs to the bytes it was computed on, so
:func:`reconcile_dataset` makes a regenerated dataset byte-identical to the archived one when it differs only so:
every array that is not double-precision ground truth must be bit-identical, every double-precision array within
``rtol`` / ``atol`` of the archived one (which then replaces it), and every shard so re-written must have the
archived sha256; otherwise nothing is changed and the cells of the archived dataset are computed again.
"""

from __future__ import annotations

import hashlib
import io
import json
import lzma
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


def archive_cell(data: Path, cell: Cell, protocol: str, archive: Path) -> bool:
    """Copy one done cell's small files from its dataset folder ``data`` into ``archive/<data.name>/``.

    Args:
        data: the dataset folder of a bench work folder (``<work>/<category>_i<I>_v<V>_s<seed>``).
        cell: the cell (its record must exist: the bench calls this after :func:`~scapo.bench.cells.compute_cell`).
        protocol: the protocol the record was scored under (``scapo``, ``eap``, ``op-align``).
        archive: the archive's root folder (created when missing).

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
    if src.predictions.is_file():
        _write(xz, lzma.compress(src.predictions.read_bytes(), preset=6))
    if cell.trained:
        for name in RUN_FILES:
            if (src.run / name).is_file():
                _copy(src.run / name, dst.run / name)
    _copy(src.per_sample, dst.per_sample)
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
        if src.per_sample.is_file() and not dst.per_sample.exists():
            _copy(src.per_sample, dst.per_sample)
        _copy(rec_path, dst.record)
        restored.append(rec_path.name)
    return restored


def _restore_predictions(src: CellPaths, dst: CellPaths) -> None:
    xz = src.predictions.with_name(src.predictions.name + ".xz")
    if dst.predictions.exists() or not xz.is_file():
        return
    try:
        raw = lzma.decompress(xz.read_bytes())
    except (OSError, lzma.LZMAError) as e:
        raise ConfigError(f"the archived predictions {xz} cannot be decompressed ({e}); remove the cell's "
                          "files from the archive so that it is computed again") from e
    _write(dst.predictions, raw)


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
    under one name, and a table takes the cells of one. Issue 31's runner computes no cell of such a dataset.

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
                f"this machine generated {have[:12]}; a machine that generates theirs pins it (--data-only)")
    return ""


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
        dataset), ``"reconciled"`` (shards re-written: ``shards`` of them, ``max_abs_diff`` per field; the same
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
        for k in order:
            if _digest(arrays[k]) == digests[k]:
                continue
            ref = double.get(f"{name}/{k}")
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
              "rtol": rtol, "atol": atol, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    write_json(Path(data) / "reconciled.json", report)
    return report


__all__ = ["DATASET", "DOUBLE_FIELDS", "RECONCILE_ATOL", "RECONCILE_RTOL", "RUN_FILES", "archive_cell",
           "archive_conflict", "archive_dataset", "archived_dataset_hashes", "reconcile_dataset", "restore_cells"]
