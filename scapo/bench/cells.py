"""Cells of a benchmark table: one method x category x training seed (x ablation), computed once.

A cell lives in its dataset's folder of the bench work folder::

    <work>/<category>_i<I>_v<V>_s<data seed>/
        run_<key>/                      training run (trained methods; resumable per epoch)
        predictions_<key>.npz           predictions of the test, val (and, when needed, train) splits
        cells/<key>.<protocol>.json     the cell's record: evaluation summary, wall times, provenance
        cells/<key>.<protocol>.parquet  its per-sample metrics (test split)

with ``key`` = the method's label for a fitted method (``icp``) and ``<label>_<preset>_s<seed>`` for a
trained one (``scapo_cpu_s0``; an ablation's ``/`` is written ``+``: ``scapo-no-shape_var_cpu+no-shape_var_s0``).

A record is valid while its dataset hash, its predictions file (sha256), the evaluator's source
(:func:`evaluator_fingerprint`) and, for a method with inference settings outside its run (SCAPO's
refinement; ``MethodEntry.inference``), those settings are unchanged, and, for a trained method, its
run is the one its preset would train today (``MethodEntry.run_is_current``); a valid record is never
recomputed, so a finished bench reruns in seconds and writes identical tables. Each step resumes on
its own: a finished run is not retrained, existing predictions of the same dataset, run and
inference settings are not recomputed, and only the (cheap) evaluation is redone when the evaluator
changed; the record then keeps the commit that trained and predicted the cell (``computed_commit``)
beside the evaluation's own provenance. Training, prediction and evaluation wall times are
recorded per cell (training: summed over every session that trained the run, from its ``timing.json``).

A run whose preset's training fields changed since it was trained is stale: the cell is retrained,
after its old run, predictions and record are moved (never deleted) to
``<dataset>/stale/<key>-<UTC time>/``. On request (``recompute_dirty``) a cell whose record names a
``-dirty`` (or unknown) commit, so that the code that computed it cannot be recovered, is moved aside the
same way to ``<dataset>/dirty/<key>-<UTC time>/`` and computed again from scratch.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import pandas as pd

from scapo.data import load
from scapo.data.storage import sha256_file
from scapo.engine.ledger import check_budget
from scapo.errors import ConfigError
from scapo.eval import EvalResult, Predictions, evaluate
from scapo.files import atomic_write_bytes, write_json
from scapo.methods import METHODS, run_method, train_method
from scapo.provenance import provenance


@dataclass(frozen=True)
class Cell:
    """One cell of a benchmark table.

    Attributes:
        method: registry name (``scapo list``). category: dataset category.
        seed: training seed of a trained method; None for a fitted one (ICP).
        preset: the training preset actually used (a method's preset, or a modified one such as the SCAPO
            ablation ``cpu/no-shape_var``); None for a fitted method.
        label: the predictions' method label (the table row): the method name, or e.g.
            ``scapo-no-shape_var`` for an ablation, ``scapo+refine`` for the refined prediction of a run.
        options: prediction options as sorted ``(name, value)`` pairs (e.g. the method's ``one_pass`` options).
        run_label: the label whose trained run the cell predicts from (default its own): the ``+refine`` row shares
            the run of its method's one-pass row.
    """

    method: str
    category: str
    seed: int | None = None
    preset: str | None = None
    label: str = ""
    options: tuple[tuple[str, object], ...] = ()
    run_label: str = ""

    def __post_init__(self):
        if not self.label:
            object.__setattr__(self, "label", self.method)
        if not self.run_label:
            object.__setattr__(self, "run_label", self.label)
        object.__setattr__(self, "options", tuple(sorted((str(k), v) for k, v in self.options)))
        if (self.seed is None) != (self.preset is None):
            raise ConfigError(f"cell {self.method}/{self.category}: a trained cell needs both a seed and a preset")

    @property
    def trained(self) -> bool:
        return self.seed is not None

    @property
    def key(self) -> str:
        """File-name key of the cell within its dataset folder (see the module docstring)."""
        if not self.trained:
            return self.label
        return f"{self.label}_{self.preset.replace('/', '+')}_s{self.seed}"

    @property
    def run_key(self) -> str:
        """File-name key of the trained run the cell predicts from (its own key unless ``run_label`` differs)."""
        return self.key if self.run_label == self.label else f"{self.run_label}_{self.preset.replace('/', '+')}" \
            f"_s{self.seed}"


def method_preset(method: str, preset: str) -> str:
    """The preset ``method`` trains with when a table asks for ``preset``: ``preset`` itself, the same for every
    category (the paper used one setting for all; a per-category preset, e.g. SCAPO's ``cpu-laptop``, is asked for
    by name in a labelled row, after every trained method has been offered the same val trials). A modified preset
    (``<base>/<parts>``, an ablation or a schedule) is checked on its base.

    Raises:
        UnknownNameError: unknown method. ConfigError: a trained method without that preset.
    """
    entry = METHODS.get(method)
    base = preset.partition("/")[0]
    if base not in entry.presets:
        raise ConfigError(f"method {method!r} has no preset {base!r}; its presets: {', '.join(entry.presets)}")
    return preset


def _hash_evaluator_source() -> str:
    import scapo.eval

    root = Path(scapo.eval.__file__).parent
    h = hashlib.sha256()
    for p in sorted(root.glob("*.py")):
        if p.name == "tables.py":  # presentation only; the scores do not depend on it
            continue
        h.update(p.name.encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


# Taken once, as this module is imported (scapo.eval is imported above it): a long bench records the evaluator it
# runs, not the files on disk when a cell ends, which a checkout changed under it would no longer match.
_EVALUATOR_FINGERPRINT = _hash_evaluator_source()


def evaluator_fingerprint() -> str:
    """sha256 (16 hex digits) of the evaluator's source (``scapo/eval/*.py``, reference tables
    excluded) as this process loaded it: a change of metrics, matching, alignment or protocols
    invalidates every cached score."""
    return _EVALUATOR_FINGERPRINT


def computed_commit(rec: dict) -> str:
    """The commit whose code trained and predicted a cell: kept from the first record when only the
    evaluation was redone since (``computed_commit``), else the record's own commit."""
    return str(rec.get("computed_commit") or rec.get("provenance", {}).get("commit", "unknown"))


@dataclass
class CellPaths:
    run: Path
    predictions: Path
    record: Path
    per_sample: Path


def cell_paths(data: Path, cell: Cell, protocol: str) -> CellPaths:
    data = Path(data)
    return CellPaths(run=data / f"run_{cell.run_key}", predictions=data / f"predictions_{cell.key}.npz",
                     record=data / "cells" / f"{cell.key}.{protocol}.json",
                     per_sample=data / "cells" / f"{cell.key}.{protocol}.parquet")


def _read_record(paths: CellPaths, dataset_hash: str) -> dict | None:
    """The cell's record when it is still valid (same dataset and evaluator, per-sample metrics present, and its
    predictions, where present, the ones it scored: a cell restored from an archive kept without predictions has
    none), else None."""
    try:
        rec = json.loads(paths.record.read_text())
    except (OSError, ValueError):
        return None
    if (rec.get("dataset_hash") != dataset_hash or rec.get("evaluator") != evaluator_fingerprint()
            or not paths.per_sample.is_file()
            or (paths.predictions.is_file() and rec.get("predictions_sha256") != sha256_file(paths.predictions))):
        return None  # a record restored from an archive without its predictions stays valid while its scores are
    cell = rec.get("cell", {})
    if cell.get("seed") is not None and not _run_current(paths.run, cell.get("method", ""), cell.get("preset"),
                                                        cell.get("seed")):
        return None
    entry = METHODS.get(cell.get("method", "")) if cell.get("method") in METHODS else None
    if entry is not None and entry.inference is not None and cell.get("seed") is not None:
        options = {str(k): v for k, v in cell.get("options", [])}
        stored = rec.get("info", {}).get("inference")
        if isinstance(stored, dict):  # a record of before "off" was stage2_starts' one spelling
            from scapo.nn.template_fit import current_refine_names

            stored = current_refine_names(stored)
        if stored != json.loads(json.dumps(entry.inference(paths.run, options))):
            return None
    return rec


def _run_current(run: Path, method: str, preset: str | None, seed: int | None) -> bool:
    """The run folder holds the run that ``method``'s ``preset`` (at ``seed``) would train today; True
    for a method without the check. The dataset is the run folder's parent (the cell layout)."""
    entry = METHODS.get(method) if method in METHODS else None
    if entry is None or entry.run_is_current is None or preset is None:
        return True
    return bool(entry.run_is_current(run, run.parent, preset, seed))


def _stale_run(paths: CellPaths, cell: Cell) -> bool:
    """A started run (``run.json``) that its preset would no longer train (its fields changed since)."""
    return (cell.trained and (paths.run / "run.json").is_file()
            and not _run_current(paths.run, cell.method, cell.preset, cell.seed))


def set_aside_stale(paths: CellPaths, cell: Cell) -> Path | None:
    """Move a stale cell's run, predictions and records to ``<dataset>/stale/<key>-<UTC time>/`` (kept,
    never deleted) so the cell is recomputed; returns that folder, or None when the run is current."""
    if not _stale_run(paths, cell):
        return None
    return _set_aside(paths, cell, "stale")


def _set_aside(paths: CellPaths, cell: Cell, why: str) -> Path:
    """Move the cell's run, predictions and records into ``<dataset>/<why>/<key>-<UTC time>/``."""
    dest = paths.run.parent / why / f"{cell.key}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}"
    dest.mkdir(parents=True, exist_ok=False)
    own_run = cell.run_label == cell.label  # a run shared with another row stays for that row (set aside by it)
    for p in ((paths.run,) if own_run else ()) + (paths.predictions, paths.record, paths.per_sample):
        if p.exists():
            p.rename(dest / p.name)
    return dest


def dirty_sha(commit: str) -> bool:
    """A commit as provenance records it names uncommitted code (``<sha>-dirty``), code whose state git could not
    verify (``<sha>-unverified``) or none (``unknown``)."""
    return commit.endswith(("-dirty", "-unverified")) or commit == "unknown"


def dirty_commit(rec: dict) -> bool:
    """The cell was trained, predicted or evaluated from a checkout with uncommitted changes
    (``<sha>-dirty``) or outside git (``unknown``): the code behind it cannot be recovered from the history."""
    return any(dirty_sha(c) for c in (computed_commit(rec), str(rec.get("provenance", {}).get("commit", "unknown"))))


def _result_of(rec: dict, paths: CellPaths) -> EvalResult:
    per_sample = pd.read_parquet(paths.per_sample)
    return EvalResult(method=rec["label"], category=rec["category"], split="test", per_sample=per_sample,
                      summary=rec["summary"], info=rec["info"])


def _run_finished(run: Path) -> bool:
    return (run / "timing.json").is_file()


def cell_status(data: Path, cell: Cell, protocol: str, dataset_hash: str | None,
                recompute_dirty: bool = False) -> str:
    """What is left of a cell: ``done``, ``evaluate`` (predictions of this dataset and run exist, made under the
    method's current inference settings: what :func:`compute_cell` would only score), ``predict`` (run trained),
    ``resume training`` (a partial run), ``retrain (stale)`` (its preset's training fields changed
    since the run was trained), ``recompute (dirty)`` (done at a ``-dirty`` commit, with
    ``recompute_dirty``), ``re-evaluate (dirty)`` (only evaluated at one, with ``recompute_dirty``) or
    ``todo`` (nothing yet; also when the dataset is not built)."""
    paths = cell_paths(data, cell, protocol)
    if dataset_hash is None:
        return "todo"
    rec = _read_record(paths, dataset_hash)
    if rec is not None:  # a valid record implies a current run
        if recompute_dirty and dirty_commit(rec):
            return "recompute (dirty)" if dirty_sha(computed_commit(rec)) else "re-evaluate (dirty)"
        return "done"
    if _stale_run(paths, cell):
        return "retrain (stale)"
    if paths.predictions.is_file() and _predictions_fit(paths.predictions, dataset_hash, cell, paths.run):
        return "evaluate"
    if cell.trained and _run_finished(paths.run):
        return "predict"
    if cell.trained and (paths.run / "checkpoint.pt").is_file():
        return "resume training"
    return "todo"


def _predictions_fit(path: Path, dataset_hash: str, cell: Cell, run: Path) -> bool:
    """Existing predictions belong to this dataset and (trained methods) to this run, made under the method's
    current inference settings. The run is recognised by its folder's name (``run_<key>`` beside the predictions in
    the dataset folder), not its absolute path, so that a work folder moved or copied elsewhere keeps its
    predictions (the dataset hash already ties them to this dataset)."""
    try:
        p = Predictions.load(path)
    except Exception:  # noqa: BLE001 - a damaged or foreign file is recomputed, never trusted
        return False
    if p.dataset_hash != dataset_hash or p.method != cell.label:
        return False
    if not cell.trained:
        return True
    inference = METHODS.get(cell.method).inference
    stored = p.info.get("inference")
    if isinstance(stored, dict):  # predictions of before "off" was stage2_starts' one spelling
        from scapo.nn.template_fit import current_refine_names

        stored = current_refine_names(stored)
    if inference is not None and stored != inference(run, dict(cell.options)):
        return False  # made under other inference settings (e.g. a preset's refinement changed since)
    return Path(str(p.info.get("run", ""))).name == Path(run).name


def compute_cell(data: Path, cell: Cell, protocol: str, progress: bool = True,
                 device: str | None = None, recompute_dirty: bool = False,
                 evaluate_only: bool = False, plan: dict | None = None) -> tuple[EvalResult, dict, bool]:
    """Compute (or load) one cell: train, predict, evaluate on the test split of ``data``. The record holds the
    trained run's compute ledger (``ledger``; ``wall["charged_s"]``, :mod:`scapo.engine.ledger`) and the wall and
    CPU milliseconds per test cloud of the prediction (``wall["infer_ms_per_cloud"]``, ``infer_cpu_ms_per_cloud``).

    ``plan`` (:func:`scapo.bench.experiments.budget_cells`): the budget the trained run's ledger is held to; a run
    over :data:`scapo.engine.ledger.OVER_BUDGET` times it is refused (ConfigError naming the phase; the run is kept,
    no record is written).

    ``evaluate_only``: load or (re-)evaluate a cell whose predictions exist, never train or predict
    (``--finished-only``; a bench may be computing other cells of the same folder meanwhile).

    ``recompute_dirty``: a done cell whose record names a ``-dirty`` or unknown commit is moved aside
    (``<dataset>/dirty/``, kept) and computed again from scratch (training included); one only evaluated
    from such a checkout (trained and predicted at a clean commit) is evaluated again, keeping its
    predictions and their commit.

    Returns:
        (the test-split :class:`EvalResult`, the cell's record, whether anything was computed).

    Raises:
        As :func:`~scapo.methods.train_method`, :func:`~scapo.methods.run_method` and
        :func:`~scapo.eval.evaluate` (every input is checked there); OutputError when the record
        cannot be written.
    """
    data = Path(data)
    paths = cell_paths(data, cell, protocol)
    dataset_hash = load(data, "test").dataset_hash
    try:  # an earlier record of this cell, valid or not (e.g. scored by an older evaluator)
        earlier = json.loads(paths.record.read_text())
    except (OSError, ValueError):
        earlier = None
    rec = _read_record(paths, dataset_hash)
    rescore = False
    if rec is not None and recompute_dirty and dirty_commit(rec):
        if not dirty_sha(computed_commit(rec)):  # trained and predicted from committed code: only the scoring again
            print(f"scapo: {cell.key}: evaluated at commit {rec['provenance'].get('commit')}; evaluating its "
                  f"predictions (computed at {computed_commit(rec)[:12]}) again")
            rec, rescore = None, True  # the record was valid: its predictions are the ones it scored
        else:
            moved = _set_aside(paths, cell, "dirty")
            print(f"scapo: {cell.key}: computed at commit {computed_commit(rec)}; moved it to {moved} and "
                  "computing it again")
            rec = earlier = None
    if rec is not None:
        return _result_of(rec, paths), rec, False
    moved = set_aside_stale(paths, cell)
    if moved is not None:
        earlier = None
        print(f"scapo: {cell.key}: the run was trained with an older {cell.preset!r} preset; moved it to {moved} "
              "and training again")
    wall: dict = {}
    fit = paths.predictions.is_file() and (rescore or _predictions_fit(paths.predictions, dataset_hash, cell,
                                                                        paths.run))
    if evaluate_only and not fit:
        raise ConfigError(f"cell {cell.category}/{cell.key} has no predictions yet; run the bench without "
                          "--finished-only to compute it")
    if cell.trained:
        if not (evaluate_only or rescore):
            train_method(cell.method, data, paths.run, cell.preset, progress=progress, device=device, seed=cell.seed)
        timing = json.loads((paths.run / "timing.json").read_text())
        wall.update(train_s=float(timing["seconds"]), train_device=timing.get("device"))
        if timing.get("steps") is not None:
            wall["train_steps"] = int(timing["steps"])
        ledger = timing.get("ledger")
        if ledger is not None:
            wall["charged_s"] = float(ledger["charged_s"])
        if plan is not None and not (evaluate_only or rescore):
            if ledger is None:
                raise ConfigError(f"{paths.run} was trained before the compute ledger existed (its timing.json has "
                                  "none), so its charged compute is unknown; move it away and run the bench again")
            check_budget(ledger, plan["budget_s"], plan["phases"], what=f"cell {cell.category}/{cell.key}")
    t0 = time.perf_counter()
    if fit:
        preds = Predictions.load(paths.predictions)
        preds_sha = sha256_file(paths.predictions)
        # only re-evaluated (the same predictions, hence the same run): the code that computed them and their
        # measured time are the earlier record's, which this evaluation must not replace
        reevaluated = (earlier is not None and earlier.get("predictions_sha256") == preds_sha
                       and earlier.get("dataset_hash") == dataset_hash)
        if reevaluated and "predict_s" in earlier.get("wall", {}):
            wall["predict_s"] = float(earlier["wall"]["predict_s"])  # as timed when they were made
        else:  # predictions written before the bench timed them: the method's own timing of the splits
            wall["predict_s"] = float(preds.info.get("predict_seconds_total", preds.info.get("fit_seconds", 0.0)
                                                 + preds.info.get("predict_seconds_test", 0.0)))
    else:
        opts = {"run": paths.run, "label": cell.label, **dict(cell.options)} if cell.trained else dict(cell.options)
        if device is not None and cell.trained:
            opts["device"] = device
        preds = run_method(cell.method, data, paths.predictions, progress=progress, **opts)
        wall["predict_s"] = round(time.perf_counter() - t0, 3)
        preds_sha, reevaluated = sha256_file(paths.predictions), False
    for k in ("ms_per_cloud_test", "cpu_ms_per_cloud_test"):  # as the method timed its test split
        if k in preds.info:
            wall[f"infer_{k[: -len('_test')]}"] = float(preds.info[k])
    t1 = time.perf_counter()
    res = evaluate(data, preds, protocol=protocol)
    wall["evaluate_s"] = round(time.perf_counter() - t1, 3)
    prov = provenance(torch_device=wall.get("train_device") or None)
    rec = {"cell": asdict(cell), "key": cell.key, "label": cell.label, "category": cell.category,
           "protocol": protocol, "dataset": str(data), "dataset_hash": dataset_hash,
           "predictions": paths.predictions.name, "predictions_sha256": preds_sha,
           "run": paths.run.name if cell.trained else None, "evaluator": evaluator_fingerprint(),
           "computed_commit": computed_commit(earlier) if reevaluated else prov["commit"],
           "summary": res.summary, "info": json.loads(json.dumps(res.info, default=str)), "wall": wall,
           "ledger": timing.get("ledger") if cell.trained else None,
           "provenance": prov}
    paths.record.parent.mkdir(parents=True, exist_ok=True)
    buf = res.per_sample.to_parquet(index=False)
    atomic_write_bytes(paths.per_sample, buf)
    write_json(paths.record, rec)
    rec = json.loads(paths.record.read_text())  # as a rerun will read it (same key order, same floats)
    return _result_of(rec, paths), rec, True
