"""The canonical-frame diagnosis ladder: ``scapo bench ladder`` (:func:`run_ladder`).

Each rung removes one difficulty of the paper's task, so the first rung where a method's canonical frame breaks
names the difficulty that breaks it:

========== ================================================================================================
rung       data (one dataset per rung and category, :data:`RUNGS`)
========== ================================================================================================
aligned    complete clouds of every instance and joint state in the object's own frame (``--viewpoints paper
           --euler 0,0``: no rotation): the frame is given, the parts are not. Opt-in (``--rungs aligned``): it
           asks whether a method's part split forms once the frame problem is removed
one        complete clouds (points on the whole posed mesh, ``scapo generate --complete``) of one shape
           (``--one-shape``) at its rest state (``--state rest``) under uniform SO(3)
complete   complete clouds of every instance and joint state under uniform SO(3)
paper      single rendered views in the paper's regime (``--viewpoints paper``)
sphere     single rendered views from the whole sphere (``--viewpoints sphere``)
========== ================================================================================================

Every rung has the same instances, views per instance and splits (only the difficulty changes), and every
trained method gets the same training compute on every rung: ``budget_minutes`` of one CPU core, turned into
epochs (or iterations) per method from its clouds/s measured on the ladder's own data through the engine
(:func:`scapo.bench.perf.bench_train_data` and :func:`scapo.bench.perf.training_budget`, as the tables' equal budget is
made). The scores are on the **val** split (a diagnosis chooses what to fix; test stays for the tables):
frame consistency (:func:`scapo.eval.frames.frame_consistency`), S, D, mean and median part rotation error R, strict and
symmetry-aware, and the evaluator's training-split alignment inlier ratio.

A cell (rung x method x seed) is resumable: its record ``<work>/<category>/<rung>/<method>_s<seed>.json`` is written
last, and a finished cell is never recomputed. With ``device`` (``scapo bench ladder --device cuda``, e.g. with the
``paper`` presets on a GPU: ``--preset paper --device cuda``) the budget is minutes of that device, its speeds are
measured there (:func:`speed_file`) and its cells live in ``<work>/<category>/<rung>/<preset>_<device>/``: the
datasets are shared, the CPU ladder's cells are not touched.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scapo.engine.ledger import check_budget
from scapo.errors import BudgetError, ConfigError
from scapo.eval.frames import CONSISTENCY_DEG, CONSISTENCY_VERSION, split_consistency
from scapo.files import check_output_dir, write_json

#: The rungs, easiest first: keywords of :func:`scapo.data.make_config` (besides the shared sizes).
RUNGS = {
    "aligned": {"complete": True, "viewpoints": "paper", "euler_deg": ((0.0, 0.0),) * 3},
    "one": {"complete": True, "one_shape": True, "state": "rest", "viewpoints": "sphere"},
    "complete": {"complete": True, "viewpoints": "sphere"},
    "paper": {"viewpoints": "paper"},
    "sphere": {"viewpoints": "sphere"},
}
RUNG_LABELS = {
    "aligned": "complete clouds, all instances and states, no rotation (the frame given)",
    "one": "complete clouds, one shape, rest state, uniform SO(3)",
    "complete": "complete clouds, all instances and states, uniform SO(3)",
    "paper": "single views, the paper's viewpoints",
    "sphere": "single views, the whole sphere",
}
#: The rungs run when none are named: the four difficulties of the canonical-frame diagnosis (``aligned`` is asked
#: for by name).
DEFAULT_RUNGS = ("one", "complete", "paper", "sphere")
#: The methods of the ladder: the trained ones (ICP, fitted without training, may be added with --methods).
LADDER_METHODS = ("scapo", "op-align", "eap", "npcs")
#: Prediction options of the ladder's cells: one-pass SCAPO (no test-time refinement), as Table 1's one-pass rows.
CELL_OPTIONS = {"scapo": {"refine_steps": 0}}
#: A frame "breaks" at the first rung whose symmetry-aware object-frame consistency is below this (the issue's target
#: for the tables is 0.9).
BREAK = 0.9
def rung_dir(work: Path, category: str, rung: str, instances: int, views: int, train_views: int, seed: int) -> Path:
    """The dataset folder of one rung: ``<work>/data/<category>_<rung>_i<I>_v<V>_t<T>_s<seed>``."""
    return Path(work) / "data" / f"{category}_{rung}_i{instances}_v{views}_t{train_views}_s{seed}"


def _finished_dataset(folder: Path, cfg) -> bool:
    """Whether ``folder`` holds a finished dataset (its card, written last) of exactly ``cfg``."""
    try:
        card = json.loads((Path(folder) / "card.json").read_text())
    except (OSError, ValueError):
        return False
    return card.get("config") == json.loads(cfg.to_json())


def rung_config(category: str, rung: str, instances: int, views: int, train_views: int, seed: int):
    """The :class:`~scapo.data.config.GenerateConfig` of one rung (the bench's splits: 20 % test, 10 % val)."""
    from scapo.data import make_config

    if rung not in RUNGS:
        raise ConfigError(f"unknown rung {rung!r}; known: {', '.join(RUNGS)}")
    return make_config(category, instances, views, seed, train_views=train_views, test_fraction=0.2,
                       val_fraction=0.1, cropped="reject", **RUNGS[rung])


def speed_file(work: Path, method: str, preset: str = "cpu", device: str | None = None, sets: dict | None = None,
               data: Path | None = None) -> Path:
    """Where the ladder keeps ``method``'s measured training speed: ``<work>/speed_<method>.json`` for the ``cpu``
    preset on the CPU (the tables' budget), ``speed_<method>_<preset>_<device>.json`` otherwise; a variant's fields
    ``sets`` add ``_v<hash>`` (a variant's one-time work and steps can cost more than its base's); the dataset it is
    measured on, ``data``, adds ``_<its folder name>`` (the ladders of two categories may share a work folder)."""
    tag = f"_{Path(data).name}" if data is not None else ""
    if sets:
        import hashlib

        tag = "_v" + hashlib.sha256(json.dumps(sorted((str(k), str(v)) for k, v in sets.items())).encode()
                                    ).hexdigest()[:8] + tag
    if preset == "cpu" and device in (None, "cpu"):
        return work / f"speed_{method}{tag}.json"
    return work / f"speed_{method}_{preset.replace('/', '+')}_{(device or 'cpu').replace(':', '')}{tag}.json"


def cells_dir(work: Path, category: str, rung: str, preset: str = "cpu", device: str | None = None) -> Path:
    """A rung's cells (records, predictions, runs): ``<work>/<category>/<rung>`` for the ``cpu`` preset on the CPU,
    ``<work>/<category>/<rung>/<preset>_<device>`` otherwise, so that a GPU ladder shares the datasets only."""
    base = work / category / rung
    if preset == "cpu" and device in (None, "cpu"):
        return base
    return base / f"{preset.replace('/', '+')}_{(device or 'cpu').replace(':', '')}"


#: Steps per epoch of a speed run (two epochs per stage). A step's CPU time varies by +-10 % from one epoch of 100
#: steps to the next (OP-Align-style: 53-64 CPU s per 100 steps over eight epochs), and 10 steps per epoch measured
#: 0.51 s per step where its cells then cost 0.57-0.59: the speed run measures whole epochs of the ``cpu`` presets.
SPEED_STEPS = 100

#: A speed run whose steps took more than this many wall seconds per CPU second shared its cores with other work
#: (a test run beside the chains of cells): its CPU time per step is inflated too (measured: OP-Align-style's steps
#: 25.7 clouds/s with a test run beside two chains, 31.5 without), so every cell planned from it would stop short
#: of its budget. It is set aside and the ladder stops, naming what to do. Two chains on two cores measure 1.0-1.1.
MAX_WALL_PER_CPU = 1.25
#: A speed run whose steps took fewer CPU seconds than this (the ``test`` presets' few tiny steps) is not held to
#: :data:`MAX_WALL_PER_CPU`: its budget is a test's, and a fraction of a second of steps cannot tell a busy machine
#: from scheduling noise (the suite's own two workers measured 2.03 for a test preset's steps). Every ``cpu`` and
#: ``paper`` preset's speed run (two epochs of 100 steps) takes more than 60.
MIN_GUARDED_CPU_S = 10.0


def _training_presets(methods: Sequence, data: Path, budget_minutes: float, preset: str, work: Path,
                      device: str | None = None) -> dict:
    """Per trained method, ``(preset, values, plan)``: its ``preset`` with the epochs (iterations) that fill
    ``budget_minutes`` of one core (of ``device``, e.g. ``cuda``, when given) on ``data``'s training split less its
    one-time work, the replaced fields, and the plan :func:`scapo.engine.ledger.check_budget` holds the cell's
    ledger to (:func:`budget_plan`), from charged speeds measured once (:func:`speed_file`, reused where this machine
    can plan from it: :func:`measured_speed`). An entry of ``methods`` may
    be ``(method, preset name, sets)`` (a ladder variant, :func:`variant_preset`: that preset with the fields
    ``sets`` replaced, its own speed measured); its result is keyed by that tuple, with ``sets`` as sorted items."""
    from scapo.bench.perf import budget_schedule, training_budget
    from scapo.config import override
    from scapo.data import load
    from scapo.methods import METHODS

    keys = [(k[0], k[1], dict(k[2])) if isinstance(k, tuple) else (k, preset, {}) for k in methods]
    trained = [(m, p, sets) for m, p, sets in keys if METHODS.get(m).trained]
    clouds = len(load(data, "train"))
    out = {}
    for m, p, sets in trained:  # one file per method, preset, fields and dataset, so that ladders can share the folder
        path = speed_file(work, m, p, device, sets, data)
        old_path = speed_file(work, m, p, device, sets)  # named without the dataset (before it was in the name)
        if not path.is_file() and old_path.is_file() and _speed_rows(old_path, m, data, check=False) is not None:
            old_path.rename(path)  # measured on this very dataset: kept under its new name
        rows = measured_speed(path, work / f"speed_runs_{path.stem[6:]}", m, p, data, device, sets)
        r = training_budget(rows, budget_minutes, clouds)[0]
        base = override(METHODS.get(m).preset(p), sets, f"{m} preset") if sets else METHODS.get(m).preset(p)
        values = budget_schedule(r, base, budget_minutes)
        key = m if (p, sets) == (preset, {}) else (m, p, tuple(sorted(sets.items())))
        out[key] = (override(base, values, f"{m} preset"), values, budget_plan(r, values, budget_minutes, clouds))
    return out


def measured_speed(path: Path, runs: Path, method: str, preset: str, data: Path, device: str | None = None,
                   sets: dict | None = None, command: str = "scapo bench ladder") -> list[dict]:
    """``method``'s charged training speed on ``data`` (:func:`scapo.bench.perf.bench_train_data` rows), from the
    speed file ``path`` when it holds one this machine can plan from, else measured (two epochs of
    :data:`SPEED_STEPS` steps per stage, the run in ``runs``) and written there. A file is measured again when it was
    measured before the compute ledger (kept as ``*.pre-ledger.json``: wall-clock rates, one-time work uncharged) or,
    on CPU, on another kind of CPU or one not recorded (kept as ``*.<UTC time>.other-cpu.json``: a core-second of
    another kind buys other steps). Used by the ladder (:func:`_training_presets`) and the tables' budget
    (:func:`scapo.bench.experiments.budget_cells`); ``command`` names the caller in what it prints.

    Raises:
        ConfigError: too few training clouds for two steps; a measurement whose steps took more than
            :data:`MAX_WALL_PER_CPU` wall seconds per CPU second (a busy machine: its CPU time per step is inflated
            too, so every cell planned from it would stop short of its budget; kept as ``*.<UTC time>.busy.json``);
            a file that is not a speed file of ``method`` on ``data`` (:func:`_speed_rows`)."""
    from scapo.bench.perf import bench_train_data
    from scapo.data import load as load_split
    from scapo.methods import METHODS
    from scapo.provenance import cpu_kind

    sets = dict(sets or {})
    if path.is_file() and not all("unit" in r for r in _speed_rows(path, method, data)):
        path.rename(path.with_suffix(".pre-ledger.json"))  # kept: wall-clock rates, one-time work uncharged
        old = runs / f"{method}_{preset.replace('/', '-')}"
        if old.exists():
            old.rename(old.with_name(old.name + ".pre-ledger"))
    if path.is_file() and (device or "cpu") == "cpu" and {
            r.get("cpu_kind") for r in _speed_rows(path, method, data)} != {cpu_kind()}:
        # measured on another kind of CPU (or before the kind was recorded): its core-seconds buy other steps
        kept = path.with_suffix(f".{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}.other-cpu.json")
        print(f"{command}: {path.name} was measured on another kind of CPU "
              f"({', '.join(sorted(str(r.get('cpu_kind', 'not recorded')) for r in _speed_rows(path, method, data)))}; "
              f"this is {cpu_kind()}): kept as {kept.name}, measured again", flush=True)
        path.rename(kept)
        old = runs / f"{method}_{preset.replace('/', '-')}"
        if old.exists():
            old.rename(old.with_name(old.name + kept.suffixes[0]))
    if not path.is_file():
        what = preset + "".join(f", {k}={v}" for k, v in sets.items())
        print(f"{command}: measuring the training speed of {method} ({what}) on {data.name}", flush=True)
        batch = METHODS.get(method).preset(preset).batch_size
        clouds = len(load_split(data, "train"))
        if clouds < 2 * batch:  # the speed run trains two steps at least
            raise ConfigError(f"{data.name}: {clouds} training clouds, fewer than the two batches of {batch} that "
                              f"measuring {method}'s training speed needs: give more --instances or --train-views")
        steps = max(2, min(SPEED_STEPS, clouds // batch))
        rows = bench_train_data(data, [method], preset=preset, steps=steps, work=runs, device=device, sets=sets)
        busy = max((float(r.get("wall_per_cpu", 1.0)) for r in rows
                    if float(r.get("steps_cpu_s", MIN_GUARDED_CPU_S)) >= MIN_GUARDED_CPU_S), default=1.0)
        if busy > MAX_WALL_PER_CPU:
            kept = path.with_suffix(f".{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}.busy.json")
            write_json(kept, rows)
            raise ConfigError(f"the training speed of {method} was measured on a busy machine (its steps took "
                              f"{busy:.2f} wall seconds per CPU second, more than {MAX_WALL_PER_CPU}: other work "
                              f"shared the cores, which slows each step's CPU time too), so its cells would be "
                              f"planned short of their budget; kept as {kept.name}. Run {command} again with "
                              "nothing else busy (one chain per core)")
        write_json(path, rows)
    return _speed_rows(path, method, data)


def _speed_rows(path: Path, method: str, data: Path, check: bool = True) -> list[dict] | None:
    """``method``'s rows of the speed file ``path`` (:func:`scapo.bench.perf.bench_train_data`), checked: a list of
    objects with the method's row, a positive finite batch size and stage-1 rate, measured on ``data`` (its folder name
    and training-split size). Without ``check``, None where the file is not that (it is then measured again).

    Raises:
        ConfigError: (with ``check``) the file is damaged or was measured on another dataset (names it)."""
    from scapo.data import load

    try:
        rows = json.loads(Path(path).read_text())
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise ValueError("not a list of rows")
        mine = [r for r in rows if r.get("method") == method]
        if not mine:
            raise ValueError(f"no row of {method}")
        for r in mine:
            for k in ("batch_size", "stage1_clouds_per_s"):
                v = r.get(k)
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                    raise ValueError(f"field {k!r} is {v!r}")
        where = {(Path(str(r.get("data", ""))).name, r.get("train_clouds")) for r in mine}
        if where != {(Path(data).name, len(load(data, "train")))}:
            raise LookupError(f"it was measured on {sorted(map(str, where))}, this ladder's training data is "
                              f"{Path(data).name} ({len(load(data, 'train'))} clouds)")
    except (OSError, ValueError, LookupError) as e:
        if not check:
            return None
        what = "belongs to another dataset" if isinstance(e, LookupError) else "is damaged"
        raise ConfigError(f"the speed file {path} {what} ({e}); delete it (the speed is measured again) or give "
                          "another --work") from None
    return mine


def budget_plan(row: dict, values: dict, budget_minutes: float, train_clouds: int) -> dict:
    """What a cell's ledger is held to: ``{"budget_s", "unit", "phases": {phase: planned charged seconds}}``, the
    one-time phases as measured in the speed run (``row``, :func:`scapo.bench.perf.bench_train_data`) and the steps
    and epochs of the schedule ``values`` (:func:`scapo.bench.perf.budget_schedule`) at the measured rates."""
    batch = int(row["batch_size"])
    per_epoch = max(train_clouds // batch, 1)
    if row.get("max_steps_per_epoch"):
        per_epoch = min(per_epoch, int(row["max_steps_per_epoch"]))
    phases = {k: float(v) for k, v in (row.get("one_time_s") or {}).items()}
    if "iterations" in values:
        phases["stage1/steps"] = values["iterations"] * batch / row["stage1_clouds_per_s"]
    else:
        if "stage1_epochs" in values:  # the engine's stages in the order of scapo.registry.schedule_fields
            epochs = {1: values["stage1_epochs"], 2: values["stage2_epochs"]}
        elif "stage0_epochs" in values:
            epochs = {1: values["stage0_epochs"], 2: values["epochs"]}
        else:
            epochs = {1: values.get("epochs", 0)}
        for k, e in epochs.items():
            if f"stage{k}_clouds_per_s" in row and e:
                phases[f"stage{k}/steps"] = e * per_epoch * batch / row[f"stage{k}_clouds_per_s"]
                phases[f"stage{k}/epochs"] = e * float(row.get(f"stage{k}_epoch_s", 0.0))
    return {"budget_s": 60.0 * budget_minutes, "unit": row.get("unit", "core-seconds"),
            "phases": {k: round(v, 1) for k, v in phases.items()}}


def variant_preset(sets: dict, preset: str) -> tuple[str, dict]:
    """A variant's base preset and the fields it replaces: ``preset=NAME`` among a variant's assignments trains
    ``NAME`` instead of the ladder's ``preset`` (e.g. a per-category preset as a labelled row, ``--variant
    scapo:cpu-laptop:preset=cpu-laptop``); the other assignments replace fields of that preset. Every variant's
    speed and one-time work are measured on their own (:func:`speed_file`) and fill the same budget."""
    rest = {k: v for k, v in sets.items() if k != "preset"}
    return str(sets.get("preset", preset)), rest


def parse_variant(text: str, flag: str = "--variant",
                  example: str = "scapo:consensus:losses.consensus=1") -> tuple[str, str, dict[str, str]]:
    """``"scapo:consensus:losses.consensus=1,losses.align=0"`` -> ``("scapo", "consensus", {...})``: a trained
    method's preset with fields replaced (the ``--set`` keys of ``scapo train``), a row of its own named
    ``METHOD:LABEL``, at the same budget as the method's default row. ``flag`` and ``example`` name the option in
    the messages (``bench table1 --option-row`` parses its rows the same way).

    Raises:
        ConfigError: not of the form ``METHOD:LABEL:KEY=VALUE[,KEY=VALUE...]``, or a label that is not a plain name."""
    from scapo.config import parse_assignments

    method, _, rest = str(text).partition(":")
    label, _, sets = rest.partition(":")
    if not method or not label or not sets or not all(c.isalnum() or c in "_-." for c in label):
        raise ConfigError(f"{flag} {text!r}: write METHOD:LABEL:KEY=VALUE[,KEY=VALUE...] with LABEL a plain name "
                          f"(letters, digits, '_', '-', '.'), e.g. {example}")
    return method, label, parse_assignments(sets.split(","), flag)


def resampling_stability(method, points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """How much a method's object frame moves when the same view is sampled again: the angle (degrees) between the
    ``T_cam_obj`` rotations it predicts from two disjoint random subsets of ``n`` points of each cloud (two
    overlapping ones when a cloud has fewer than ``2 n`` points). An equivariant network gives the same frame for a
    rotated copy of one cloud; this measures whether it also gives it for another sample of one surface, which a
    category-level frame needs before any other difficulty.

    Args:
        method: a loaded trained method (:func:`scapo.methods.load`). points: ``(B, N, 3)`` float32 camera-frame
            clouds (metres). n: points per subset (the method's training density).

    Returns:
        ``(B,)`` float64 angles in degrees.
    """
    rng = np.random.default_rng(seed)
    B, N, _ = points.shape
    n = min(n, N)
    a_idx, b_idx = [], []
    for _ in range(B):
        perm = rng.permutation(N)
        a_idx.append(perm[:n])
        b_idx.append(perm[n:2 * n] if 2 * n <= N else rng.permutation(N)[:n])
    pa = np.take_along_axis(points, np.stack(a_idx)[..., None], 1)
    pb = np.take_along_axis(points, np.stack(b_idx)[..., None], 1)
    Ra = np.asarray(method.predict_points(pa)["T_cam_obj"], dtype=np.float64)[:, :3, :3]
    Rb = np.asarray(method.predict_points(pb)["T_cam_obj"], dtype=np.float64)[:, :3, :3]
    cos = (np.einsum("bij,bij->b", Ra, Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _stability(run: Path, data: Path, method: str, preset, limit: int = 64, device: str | None = None) -> float:
    """Median :func:`resampling_stability` of a run on the first ``limit`` val clouds at its training density, with
    the cell's prediction options (:data:`CELL_OPTIONS`: one-pass)."""
    from scapo.data import load
    from scapo.methods import load_run

    pts = load(data, "val").arrays(["points"])["points"][:limit]
    n = int(getattr(preset, "train_points", getattr(preset, "points", 256)))
    return float(np.median(resampling_stability(load_run(run, device=device, **CELL_OPTIONS.get(method, {})), pts,
                                                n)))


#: The fields of a cell record that its table reads, with their types (a record without one of them is damaged).
RECORD_FIELDS = {"method": str, "seed": int, "dataset_hash": str, "S": (int, float), "frame_consistency": (int, float)}


def read_record(path: Path) -> dict:
    """A ladder or compute-curve cell's record, checked on read.

    Raises:
        ConfigError: the file is not JSON, not an object, lacks a field of :data:`RECORD_FIELDS` or holds one of
            another type or a non-finite score (names the file and what to do: move it away, the cell is computed
            again)."""
    path = Path(path)
    try:
        rec = json.loads(path.read_text())
        if not isinstance(rec, dict):
            raise ValueError(f"a JSON {type(rec).__name__}, not an object")
        for k, t in RECORD_FIELDS.items():
            if k not in rec:
                raise ValueError(f"no field {k!r}")
            if not isinstance(rec[k], t) or isinstance(rec[k], bool) or (
                    isinstance(rec[k], float) and not math.isfinite(rec[k])):
                raise ValueError(f"field {k!r} is {rec[k]!r}")
    except (OSError, ValueError) as e:
        raise ConfigError(f"the cell record {path} is damaged ({e}); move it away (with its predictions and run) and "
                          "run again: the cell is computed again") from None
    return rec


def check_table_rows(path: Path, made: set, fields: Sequence[str], command: str) -> None:
    """Refuse to replace the table ``path`` (a ladder's or compute curve's ``.json``, written before into the same
    ``--out``) by one without some of its rows: ``made`` is the set of ``fields`` tuples this run writes. A narrower
    rerun once rewrote the table without the rows it was not asked for.

    Raises:
        ConfigError: rows of the table this run does not make (up to five named), and what to do."""
    if not Path(path).is_file():
        return
    try:
        rows = json.loads(Path(path).read_text())["records"]
        have = {tuple(r[f] for f in fields) for r in rows}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"{path} is not a table of {command} ({type(e).__name__}: {e}); give another --out or move "
                          "it away") from None
    lost = sorted(have - made, key=str)
    if lost:
        more = ", ..." if len(lost) > 5 else ""
        raise ConfigError(f"{path} holds {len(lost)} row(s) this run does not make ({', '.join(map(str, lost[:5]))}"
                          f"{more}; as {', '.join(fields)}), which rewriting it would lose: ask for them too (their "
                          "finished cells are reused), or give another --out")


def check_one_commit(records: Sequence[dict], allow: bool = False) -> None:
    """Refuse a table whose cells were computed by several commits' code (``provenance.commit`` of each record), or
    whose trained cells were charged on several kinds of CPU (``provenance.cpu_kind``,
    :func:`scapo.provenance.cpu_kind`; a record without it counts as a kind of its own): a table's cells come from one
    clean commit, a cell made by other code would otherwise be reused silently, and a core-second of one kind of CPU
    need not buy the steps one of another buys (machines sold under one name differ in family, model and vector
    units), so the equal budget is held only among cells of one kind.

    Raises:
        ConfigError: (without ``allow``, ``--allow-mixed-commits``) the commits or the kinds, and some cells of each."""
    def where(r: dict) -> str:
        return f"{r.get('rung', str(r.get('budget_min', '?')) + ' min')}/{r.get('method')}_s{r.get('seed')}"

    def listing(by: dict, width: int = 80) -> str:
        return "; ".join(f"{k[:width]}: {', '.join(v[:3])}{', ...' if len(v) > 3 else ''}"
                         for k, v in sorted(by.items()))

    by: dict[str, list[str]] = {}
    kinds: dict[str, list[str]] = {}
    for r in records:
        prov = r.get("provenance") or {}
        by.setdefault(str(prov.get("commit", "unknown")), []).append(where(r))
        if r.get("charged_min") is not None or r.get("ledger"):
            kinds.setdefault(str(prov.get("cpu_kind", "kind not recorded")), []).append(where(r))
    if len(by) > 1 and not allow:
        raise ConfigError(f"the cells come from {len(by)} commits ({listing(by, 12)}); a table's cells come from one "
                          "commit: compute the others again at one commit (move their records, predictions and runs "
                          "away), or give --allow-mixed-commits to write it anyway")
    if not allow:
        check_one_kind(kinds)


def check_one_kind(kinds: dict[str, list[str]]) -> None:
    """Refuse trained cells charged in core-seconds of several kinds of CPU (``kinds``: ``provenance.cpu_kind`` ->
    the cells charged there, by name): a core-second of one kind buys other steps than one of another, so a table's
    budget is equal only on one kind. Used by the ladder (:func:`check_one_commit`) and the paper's tables
    (:func:`scapo.bench.experiments.check_commits`).

    Raises:
        ConfigError: more than one kind, naming each and some of its cells."""
    if len(kinds) > 1:
        listing = "; ".join(f"{k[:80]}: {', '.join(v[:3])}{', ...' if len(v) > 3 else ''}"
                            for k, v in sorted(kinds.items()))
        raise ConfigError(f"the trained cells were charged on {len(kinds)} kinds of CPU ({listing}); a core-second "
                          "of one kind buys other steps than one of another, so a table's budget is equal only on one "
                          "kind: compute the others again on one kind (move their records, predictions and runs "
                          "away), or give --allow-mixed-commits to write it anyway")


def dataset_hash(data: Path) -> str:
    """The hash of the dataset ``data`` (its val split's, as the cells' records hold it)."""
    from scapo.data import load

    return load(data, "val").dataset_hash


def check_reuse(rec: dict, path: Path, data_hash: str, values: dict | None = None, budget_s: float | None = None
                ) -> None:
    """Refuse to reuse the finished cell ``rec`` (its record at ``path``) for a run of other conditions: another
    dataset, another schedule (``values``: the preset fields the budget set, with a variant's fields), another budget
    (``budget_s``, charged seconds), or charged on another kind of CPU (a record with a ledger in core-seconds whose
    ``provenance.cpu_kind`` is not this machine's: its budget bought other steps, :func:`check_one_commit`). A cell is
    found by its rung, method and seed; this is what keeps a table from being built of cells made under other
    conditions.

    Raises:
        ConfigError: what differs, and what to do (another ``--work``, or the cell moved away)."""
    why = []
    if rec.get("dataset_hash") != data_hash:
        why.append(f"dataset {str(rec.get('dataset_hash'))[:12]} (asked: {data_hash[:12]})")
    if values is not None and rec.get("budget_values") is not None and \
            json.loads(json.dumps(rec["budget_values"])) != json.loads(json.dumps(values, default=str)):
        why.append(f"schedule {rec['budget_values']} (asked: {values})")
    planned = (rec.get("plan") or {}).get("budget_s")
    if budget_s is not None and planned is not None and abs(float(planned) - float(budget_s)) > 1e-6:
        why.append(f"a budget of {float(planned) / 60:g} minutes (asked: {float(budget_s) / 60:g})")
    if (rec.get("ledger") or {}).get("unit") == "core-seconds":  # charged in core-seconds of its kind of CPU
        from scapo.provenance import cpu_kind

        kind = str((rec.get("provenance") or {}).get("cpu_kind", "a kind of CPU not recorded"))
        if kind != cpu_kind():
            why.append(f"core-seconds of {kind} (this machine: {cpu_kind()})")
    if why:
        raise ConfigError(f"the finished cell {path} was made with {'; '.join(why)}; it is not reused for this run: "
                          "give another --work, or move the cell (its record, predictions and run) away to compute "
                          "it again")


def _upgrade(rec_path: Path, data: Path, method: str, preset) -> dict:
    """A cell's record, with the symmetry-aware consistency and the resampling stability added when it was written
    before they existed, and the consistency scored again when it predates :data:`CONSISTENCY_VERSION` on a category
    that declares a symmetry (from the cell's own predictions and run; ``consistency_commit`` names the code)."""
    from scapo.eval import Predictions
    from scapo.methods import METHODS
    from scapo.provenance import git_commit

    rec = read_record(rec_path)
    stale = (rec.get("consistency_version", 1) < CONSISTENCY_VERSION
             and bool(json.loads((Path(data) / "card.json").read_text()).get("symmetry")))
    if "frame_consistency_sym" in rec and "resampling_deg" in rec and not stale:
        return rec
    stem = rec_path.name[: -len(".json")]
    preds = Predictions.load(rec_path.parent / f"{stem}_predictions.npz")
    rec["frame_consistency"], rec["frame_consistency_sym"] = (round(x, 4) for x in split_consistency(data, preds))
    if "resampling_deg" not in rec:
        rec["resampling_deg"] = (_stability(rec_path.parent / f"{stem}_run", data, method, preset)
                                 if METHODS.get(method).trained else None)
    rec["consistency_version"] = CONSISTENCY_VERSION
    rec["consistency_commit"] = git_commit()
    write_json(rec_path, rec)
    return rec


def _cell(data: Path, work: Path, category: str, rung: str, method: str, seed: int, preset, values: dict,
          protocol: str, label: str | None = None, preset_name: str = "cpu", device: str | None = None,
          plan: dict | None = None) -> dict:
    """Train (trained methods), predict and score one cell on the val split; returns (and writes) its record, with
    the run's compute ledger (``ledger``: charged seconds by phase, :mod:`scapo.engine.ledger`), its charged minutes
    and the inference milliseconds per val cloud (wall and CPU).

    Raises:
        BudgetError: a trained cell whose ledger exceeds its ``plan``'s budget by more than
            :data:`scapo.engine.ledger.OVER_BUDGET` (:func:`~scapo.engine.ledger.check_budget`; its run is kept, no
            record is written)."""
    from scapo.eval import evaluate
    from scapo.methods import METHODS, run_method, train_method
    from scapo.provenance import provenance

    name = method if label is None else f"{method}:{label}"
    key = name.replace(":", "--")
    cells = cells_dir(work, category, rung, preset_name, device)  # a cell's record, predictions and run
    rec_path = cells / f"{key}_s{seed}.json"
    if rec_path.is_file():
        check_reuse(read_record(rec_path), rec_path, dataset_hash(data), values if METHODS.get(method).trained
                    else None, plan["budget_s"] if plan else None)
        return _upgrade(rec_path, data, method, preset)
    run = cells / f"{key}_s{seed}_run"
    wall = {}
    t0 = time.perf_counter()
    threads = ledger = None
    if METHODS.get(method).trained:
        import torch

        threads = torch.get_num_threads()
        train_method(method, data, run, preset, progress=False, seed=seed, device=device)
        timing = json.loads((run / "timing.json").read_text())
        wall["train_s"] = float(timing["seconds"])
        wall["train_steps"] = timing.get("steps")
        ledger = timing.get("ledger")
        if plan is not None:
            if ledger is None:
                raise ConfigError(f"{run} was trained before the compute ledger existed (its timing.json has none), "
                                  "so its charged compute is unknown; move it away and run the ladder again")
            check_budget(ledger, plan["budget_s"], plan["phases"], what=f"cell {category}/{rung}/{key}_s{seed}")
    t1 = time.perf_counter()
    opts = {"run": run, **CELL_OPTIONS.get(method, {})} if METHODS.get(method).trained else {}
    if device is not None and METHODS.get(method).trained:
        opts["device"] = device
    preds_path = cells / f"{key}_s{seed}_predictions.npz"
    preds = run_method(method, data, preds_path, progress=False, **opts)
    wall["predict_s"] = round(time.perf_counter() - t1, 1)
    stability = _stability(run, data, method, preset, device=device) if METHODS.get(method).trained else None
    res = evaluate(data, preds, split="val")
    s = res.summary
    consistency, consistency_sym = s["frame_consistency"], s["frame_consistency_sym"]
    rec = {
        "rung": rung, "rung_label": RUNG_LABELS[rung], "method": name, "seed": seed, "split": "val",
        "protocol": protocol, "dataset": data.name, "dataset_hash": res.info["dataset_hash"],
        "preset": getattr(preset, "name", preset), "budget_values": values,
        "frame_consistency": round(consistency, 4), "frame_consistency_sym": round(consistency_sym, 4),
        "consistency_version": CONSISTENCY_VERSION, "alignment_inlier_ratio": res.info.get("alignment_inlier_ratio"),
        "resampling_deg": stability,
        "S": s.get("S"), "D": s.get("D"), "D_median": s.get("D_median"), "C": s.get("C"),
        "R": s.get("R"), "R_median": s.get("R_median"), "R_sym": s.get("R_sym"), "R_sym_median": s.get("R_sym_median"),
        "R_over90": s.get("R_over90"), "R_sym_over90": s.get("R_sym_over90"),
        "ledger": ledger, "plan": plan,
        "charged_min": None if ledger is None else round(ledger["charged_s"] / 60, 4),
        "infer_ms_per_cloud": preds.info.get("ms_per_cloud_val"),
        "infer_cpu_ms_per_cloud": preds.info.get("cpu_ms_per_cloud_val"),
        "wall": {**wall, "cell_s": round(time.perf_counter() - t0, 1)}, "torch_threads": threads,
        "provenance": provenance(torch_device=device), "device": device or "cpu",
    }
    rec = json.loads(json.dumps(rec, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    write_json(rec_path, rec)
    return rec


def _unit(meta: dict) -> str:
    """The budget's unit: core-minutes (one torch thread of a CPU core) or minutes of the torch device."""
    dev = str(meta.get("device") or "cpu")
    return "core-minutes" if dev == "cpu" else f"minutes of the {dev} device"


def _fmt(v, nd: int = 1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, list):
        return " / ".join(_fmt(x, 2) for x in v)
    return f"{v:.{nd}f}"


def write_ladder(records: Sequence[dict], out: Path, name: str, meta: dict) -> list[Path]:
    """``<out>/<name>.{md,json,csv}``: one row per rung x method x seed (the records), with provenance."""
    import pandas as pd

    from scapo.report import markdown_table

    out = check_output_dir(out, "ladder output folder")
    cols = ["rung", "method", "seed", "frame_consistency", "frame_consistency_sym", "alignment_inlier_ratio",
            "resampling_deg", "S", "D", "D_median", "C", "R",
            "R_median", "R_sym", "R_sym_median", "R_sym_over90"]
    flat = []
    for r in records:
        row = {k: r.get(k) for k in cols}
        row["alignment_inlier_ratio"] = (None if r.get("alignment_inlier_ratio") is None
                                         else float(np.mean(r["alignment_inlier_ratio"])))
        row["train_steps"] = r["wall"].get("train_steps")
        row["charged_min"] = r.get("charged_min")
        row["infer_ms_per_cloud"] = r.get("infer_ms_per_cloud")
        row["train_wall_min"] = None if r["wall"].get("train_s") is None else r["wall"]["train_s"] / 60
        row["commit"] = r["provenance"].get("commit")
        row["dataset_hash"] = r["dataset_hash"]
        flat.append(row)
    header = ["rung", "method", "seed", "frame cons.", "frame cons. sym", "align. inliers (train)", "resampling deg",
              "S %", "D", "D med", "C", "R",
              "R med", "R sym", "R sym med", "R sym > 90 %", "steps", "charged min", "infer ms"]
    body = [[r["rung"], r["method"], r["seed"], _fmt(r["frame_consistency"], 2),
             _fmt(r.get("frame_consistency_sym"), 2), _fmt(r["alignment_inlier_ratio"], 2), _fmt(r["resampling_deg"]),
             _fmt(r["S"]), _fmt(r["D"]), _fmt(r["D_median"]), _fmt(r["C"], 3), _fmt(r["R"]), _fmt(r["R_median"]),
             _fmt(r["R_sym"]), _fmt(r["R_sym_median"]), _fmt(r["R_sym_over90"]),
             "-" if r["train_steps"] is None else str(r["train_steps"]), _fmt(r["charged_min"]),
             _fmt(r["infer_ms_per_cloud"])] for r in flat]
    commits = sorted({r["commit"] for r in flat})
    # per method: the symmetry-aware object-frame consistency rung by rung (mean over its seeds), and the first rung
    # whose mean is below BREAK
    names = list(dict.fromkeys(r["method"] for r in flat))
    summary = []
    for m in names:
        vals, cells = [], []
        for k in meta["rungs"]:
            v = [r["frame_consistency_sym"] for r in flat if r["method"] == m and r["rung"] == k
                 and r.get("frame_consistency_sym") is not None]
            vals.append(float(np.mean(v)) if v else None)
            cells.append(f"{_fmt(vals[-1], 2)} ({len(v)})" if v else "-")
        broken = next((k for k, v in zip(meta["rungs"], vals) if v is not None and v < BREAK), None)
        summary.append([m, *cells, broken or f"none (all >= {BREAK:g})"])
    md = [f"# Canonical-frame ladder: {meta['category']} ({meta['split']} split)", "",
          "Rungs: " + "; ".join(f"**{k}**: {RUNG_LABELS[k]}" for k in meta["rungs"]) + ".", "",
          f"Equal training compute: {meta['budget_minutes']} {_unit(meta)} per trained cell (epochs from the "
          f"measured clouds/s, `speed_<method>*.json`, less each method's one-time work; charged min: the run's "
          "compute ledger, every core-second spent before it can predict, `scapo.engine.ledger`; infer ms: wall "
          "milliseconds per val cloud). One-pass predictions. Frame consistency: share of val "
          "samples whose object-frame "
          f"offset is within {CONSISTENCY_DEG:g} deg of the common one (1 = one canonical frame), strict and against "
          "the category's declared symmetric ground truths (sym; e.g. a laptop's base/lid exchange); the alignment "
          "inlier ratio is the evaluator's, on the training split, per part (another quantity than the frame "
          "consistency); resampling deg: median angle between the object frames predicted from two disjoint random "
          "subsets (training density) of one val view.", "",
          markdown_table(header, body), "",
          "Where the frame breaks: the symmetry-aware object-frame consistency per rung, mean over the training seeds "
          f"(their number in brackets), and the first rung below {BREAK:g}.", "",
          markdown_table(["method", *meta["rungs"], "first rung below"], summary), "",
          f"Provenance: commits {', '.join(commits)}; {meta['instances']} instances, {meta['views']} views per "
          "val/test "
          f"instance, {meta['train_views']} per training instance, data seed {meta['data_seed']}, preset "
          f"{meta['preset']!r}, protocol {meta['protocol']!r}; written by `{meta['command']}`."
          + (f" {len(meta['missing'])} cells of these rungs, methods and seeds are not computed (listed in the JSON's "
             "`meta.missing`)." if meta.get("missing") else ""), ""]
    paths = [out / f"{name}.md", out / f"{name}.json", out / f"{name}.csv"]
    from scapo.files import atomic_write_text

    atomic_write_text(paths[0], "\n".join(md))
    write_json(paths[1], {"meta": meta, "records": list(records)})
    atomic_write_text(paths[2], pd.DataFrame(flat).to_csv(index=False))
    return paths


def _write_finished(work: Path, category: str, rungs, methods, parsed, seeds, out: Path, meta: dict) -> list[Path]:
    """The table of the finished cells only (``--finished-only``): nothing is trained or predicted (a record written
    before the symmetry-aware consistency and the resampling column existed gets them, :func:`_upgrade`)."""
    from scapo.config import override
    from scapo.methods import METHODS

    records, missing = [], []
    sets = {(m, label): v for m, label, v in parsed}
    names = [(m, None) for m in methods] + [(m, label) for m, label, _ in parsed]
    for r in rungs:
        for m, label in names:
            key = (m if label is None else f"{m}:{label}").replace(":", "--")
            for s in seeds:
                path = cells_dir(work, category, r, meta["preset"], meta.get("device")) / f"{key}_s{s}.json"
                if path.is_file():
                    preset = None
                    if METHODS.get(m).trained:
                        preset = METHODS.get(m).preset(meta["preset"])
                        if label is not None:
                            base, rest = variant_preset(sets[(m, label)], meta["preset"])
                            preset = override(METHODS.get(m).preset(base), rest, f"{m} preset")
                    data = rung_dir(work, category, r, meta["instances"], meta["views"], meta["train_views"],
                                    meta["data_seed"])
                    check_reuse(read_record(path), path, dataset_hash(data),
                                budget_s=60.0 * meta["budget_minutes"] if METHODS.get(m).trained else None)
                    records.append(_upgrade(path, data, m, preset))
                else:
                    missing.append(f"{r}/{key}_s{s}")
    if not records:
        raise ConfigError(f"no finished ladder cell of {category} in {work}; run the ladder without --finished-only")
    meta["missing"] = missing
    check_one_commit(records, meta.get("allow_mixed_commits", False))
    return write_ladder(records, out, f"ladder_{category}", meta)


def run_ladder(category: str = "laptop", methods: Sequence[str] = LADDER_METHODS, rungs: Sequence[str] = DEFAULT_RUNGS,
               seeds: Sequence[int] = (0,), work: str | Path = "bench_work/ladder",
               out: str | Path = "results/canonical_ladder",
               budget_minutes: float = 5.0, instances: int = 60, views: int = 8, train_views: int = 16,
               data_seed: int = 1, preset: str = "cpu", protocol: str = "scapo", workers: int = 1,
               command: str = "scapo bench ladder", dry_run: bool = False, data_only: bool = False,
               variants: Sequence[str] = (), finished_only: bool = False, device: str | None = None,
               allow_mixed_commits: bool = False) -> list[Path]:
    """Run (or resume) the ladder for ``category``: generate each rung's dataset, train every method with the same
    budget, predict one-pass, score on val, write ``<out>/ladder_<category>.{md,json,csv}``.

    Args:
        methods: registered method names (trained ones get ``budget_minutes``). rungs: names of :data:`RUNGS`.
        seeds: training seeds. instances, views, train_views, data_seed: the datasets' sizes (equal on every rung).
        dry_run: list the cells, compute nothing. data_only: generate the rungs' datasets and stop.
        variants: :func:`parse_variant` texts: extra rows of a method's preset with fields replaced.
        finished_only: compute nothing; write the table of the cells whose records exist (the others are listed in
            its ``missing``).

    Raises:
        ConfigError: an empty or unknown list, a budget <= 0, sizes too small for a val split.
        UnknownNameError: an unknown method. BudgetError: cells that charged more than 110 % of their budget (the
        other cells are computed and their table written first). Otherwise as generation, training and evaluation.
    """
    from scapo.data import generate
    from scapo.methods import METHODS

    methods, rungs, seeds = list(methods), list(rungs), list(seeds)
    if not methods or not rungs or not seeds:
        raise ConfigError("give at least one method, one rung and one seed")
    for m in methods:
        METHODS.get(m)
    bad = [r for r in rungs if r not in RUNGS]
    if bad:
        raise ConfigError(f"unknown rung(s) {', '.join(bad)}; known: {', '.join(RUNGS)}")
    if not (math.isfinite(budget_minutes) and 0 < budget_minutes <= 7 * 24 * 60):
        raise ConfigError(f"--budget-minutes must be a positive number of core-minutes, at most 10080 (a week of one "
                          f"core), got {budget_minutes}")
    if instances < 10:
        raise ConfigError(f"--instances must be >= 10 (a val and a test split of their own), got {instances}")
    if any(s < 0 for s in seeds):
        raise ConfigError(f"training seeds must be >= 0, got {seeds}")
    for what, values in (("--methods", methods), ("--rungs", rungs), ("--seeds", seeds)):
        if len(set(values)) != len(values):  # one cell counted twice would pass for two
            raise ConfigError(f"{what}: a value is given twice: {list(values)}; give each once")

    def meta_of() -> dict:
        return {"category": category, "rungs": rungs, "methods": methods, "seeds": seeds, "split": "val",
                "budget_minutes": budget_minutes, "instances": instances, "views": views, "train_views": train_views,
                "data_seed": data_seed, "preset": preset, "protocol": protocol, "command": command,
                "variants": list(variants), "device": device or "cpu", "allow_mixed_commits": allow_mixed_commits}

    parsed = [parse_variant(v) for v in variants]
    from scapo.config import override

    for m, label, sets in parsed:
        if not METHODS.get(m).trained:
            raise ConfigError(f"--variant {m}:{label}: {m!r} is not trained; a variant replaces fields of its preset")
        if m not in methods:  # a variant row is read against its method's own row
            raise ConfigError(f"--variant {m}:{label}: {m!r} is not among --methods ({', '.join(methods)}); a variant "
                              f"is compared with its method's row: add {m} to --methods")
        base, rest = variant_preset(sets, preset)
        override(METHODS.get(m).preset(base), rest, f"{m} preset (--variant {label})")  # bad keys before any work
    if len({(m, label) for m, label, _ in parsed}) != len(parsed):
        raise ConfigError("--variant: two variants with one METHOD:LABEL")
    work = check_output_dir(work, "ladder work folder")
    check_output_dir(out, "ladder output folder")
    if not dry_run and not data_only:
        names = list(methods) + [f"{m}:{label}" for m, label, _ in parsed]
        check_table_rows(Path(out) / f"ladder_{category}.json", {(r, n, s) for r in rungs for n in names
                                                                  for s in seeds}, ("rung", "method", "seed"),
                         "scapo bench ladder")
    cfgs = {r: rung_config(category, r, instances, views, train_views, data_seed) for r in rungs}
    print(f"scapo bench ladder: {category}, rungs {', '.join(rungs)}; methods {', '.join(methods)}; seeds "
          f"{seeds}; {budget_minutes} {_unit({'device': device})} per trained cell", flush=True)
    if dry_run:
        for r in rungs:
            for m in methods:
                for s in seeds:
                    folder = rung_dir(work, category, r, instances, views, train_views, data_seed)
                    print(f"  {r:9s} {m:9s} seed {s}: {folder}")
        return []
    if finished_only:
        return _write_finished(work, category, rungs, methods, parsed, seeds, Path(out), meta_of())
    for r in rungs:
        folder = rung_dir(work, category, r, instances, views, train_views, data_seed)
        if not _finished_dataset(folder, cfgs[r]):  # a finished one is not touched (other chains may be reading it)
            generate(cfgs[r], folder, workers=workers, progress=False)
    if data_only:
        return []
    ref = rung_dir(work, category, "paper" if "paper" in rungs else rungs[0], instances, views, train_views, data_seed)
    meta = meta_of()
    variant_keys = {label: (m, *variant_preset(v, preset)) for m, label, v in parsed}
    presets = _training_presets(list(methods) + [(m, p, tuple(sorted(rest.items())))
                                                 for m, p, rest in variant_keys.values()],
                                ref, budget_minutes, preset, work, device)
    records, refused = [], []
    for r in rungs:
        data = rung_dir(work, category, r, instances, views, train_views, data_seed)
        for m in methods:
            for s in seeds:
                pc, values, plan = presets.get(m, (None, {}, None))
                t0 = time.perf_counter()
                try:
                    rec = _cell(data, work, category, r, m, s, pc, values, protocol, preset_name=preset,
                                device=device, plan=plan)
                except BudgetError as e:  # the other cells go on; the run is kept
                    print(f"  {r:9s} {m:9s} seed {s}: refused: {e}", flush=True)
                    refused.append(str(e))
                    continue
                print(f"  {r:9s} {m:9s} seed {s}: frame consistency {_fmt(rec['frame_consistency'], 2)}, S "
                      f"{_fmt(rec['S'])}, D {_fmt(rec['D'])}, R median {_fmt(rec['R_median'])}, R sym median "
                      f"{_fmt(rec['R_sym_median'])} ({time.perf_counter() - t0:.0f} s)", flush=True)
                records.append(rec)
        for m, label, sets in parsed:
            from scapo.config import override

            _, base, rest = variant_keys[label]
            pv, values, plan = presets[(m, base, tuple(sorted(rest.items())))]
            for s in seeds:
                t0 = time.perf_counter()
                try:
                    rec = _cell(data, work, category, r, m, s, pv, {**sets, **values}, protocol, label=label,
                                preset_name=preset, device=device, plan=plan)
                except BudgetError as e:
                    print(f"  {r:9s} {m}:{label} seed {s}: refused: {e}", flush=True)
                    refused.append(str(e))
                    continue
                print(f"  {r:9s} {m}:{label} seed {s}: frame consistency {_fmt(rec['frame_consistency'], 2)}, S "
                      f"{_fmt(rec['S'])}, D {_fmt(rec['D'])}, R median {_fmt(rec['R_median'])}, R sym median "
                      f"{_fmt(rec['R_sym_median'])} ({time.perf_counter() - t0:.0f} s)", flush=True)
                records.append(rec)
    if not records:
        raise BudgetError("every cell was refused over its budget:\n" + "\n".join(refused))
    check_one_commit(records, allow_mixed_commits)
    paths = write_ladder(records, Path(out), f"ladder_{category}", meta)
    if refused:  # the table of the others is written; the refusals end the command with an error
        raise BudgetError(f"{len(refused)} cell(s) refused over their budget (the table lists the others):\n"
                          + "\n".join(refused))
    return paths
