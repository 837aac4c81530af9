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
"""

from __future__ import annotations

import json
import lzma
from pathlib import Path

from scapo.bench.cells import Cell, CellPaths, cell_paths
from scapo.errors import ConfigError, OutputError
from scapo.files import atomic_write_bytes

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


__all__ = ["RUN_FILES", "archive_cell", "restore_cells"]
