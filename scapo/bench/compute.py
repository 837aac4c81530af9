"""Accuracy against training compute: ``scapo bench compute`` (:func:`run_compute_curve`).

For each trained method, one cell per training budget (default 5, 15, 45 and 120 core-minutes) on one rung of the
canonical-frame ladder (:mod:`scapo.bench.ladder`; default the paper's single-view regime): the budget becomes epochs
(iterations) from the method's clouds/s measured once on that data (the ladder's ``speed_<method>.json``, shared
with it), each cell trains from scratch with its own schedule (the cosine learning-rate schedule spans the whole
budget, so a 5-minute cell is not a snapshot of a 120-minute one), predicts one-pass and is scored on **val** with
the ladder's columns: frame consistency strict and symmetry-aware, S, D, mean and median part rotation error R
(strict and symmetry-aware).

The tables' equal per-cell budget is chosen from these curves (the issue asks for at most 45 core-minutes per
training run).

Cells: ``<work>/compute/b<budget>/<category>/<rung>/<method>_s<seed>.{json,_predictions.npz,_run}``; the datasets
and speed files are the ladder's (``<work>/data/``, ``<work>/speed_<method>.json``). A cell's record is written
last and never recomputed; an unfinished cell's training resumes from its run folder's checkpoint, so a
120-minute cell may span sessions. Several processes may share one work folder if they take different methods
(``--methods``) after ``--data-only`` has rendered the dataset and measured every method's speed alone; each writes
the table of every finished cell at its end (``--finished-only`` writes it alone).

``from_table`` (``scapo bench compute --from-table``): the curve of the table's own cells. The work folder is a
``scapo bench table1 --budget-minutes`` work folder (:func:`scapo.bench.experiments.budget_cells`), whose dataset
(``<work>/<category>_i<I>_v<V>_t<T>_s<seed>[_paper]``), measured speeds (``<work>/speeds/``) and budget rule are used:
each method trains with the preset the table gives it and the epochs that fill the budget less its one-time work
(:mod:`scapo.engine.ledger`), so a curve cell is the table's cell at another budget. A cell
whose run the table has already trained (same preset, schedule and seed, ``<dataset>/run_<key>``, finished) starts
from a copy of that run (the engine checks its identity) and is only predicted and scored on val. Cells:
``<work>/compute/b<budget>/<category>/<rung>/``.

Outputs: ``<out>/accuracy_vs_compute.{md,csv,json,png}``.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from scapo.bench.ladder import (
    CELL_OPTIONS,
    LADDER_METHODS,
    RUNGS,
    _cell,
    _finished_dataset,
    _fmt,
    _training_presets,
    _upgrade,
    cells_dir,
    check_one_commit,
    check_reuse,
    check_table_rows,
    dataset_hash,
    read_record,
    rung_config,
    rung_dir,
)
from scapo.errors import ConfigError
from scapo.files import atomic_write_text, check_output_dir, write_json

#: The issue's budgets (core-minutes of training per cell, one torch thread).
COMPUTE_BUDGETS = (5.0, 15.0, 45.0, 120.0)
#: The largest budget a cell may be given (core-minutes): a week of one core.
MAX_BUDGET = 7 * 24 * 60.0
#: The scores drawn against compute (record key, axis label).
CURVE_PANELS = (("S", "S (%)"), ("R_sym_median", "median R sym (deg)"),
                ("frame_consistency_sym", "frame consistency sym"))


def budget_dir(work: Path, budget: float) -> Path:
    """The cells' folder of one budget: ``<work>/compute/b<budget>`` (``b5``, ``b15``, ``b2.5``; the exact value where
    the short form would name another budget too: ``b0.05000001``)."""
    short = f"{budget:g}"
    return Path(work) / "compute" / f"b{short if float(short) == float(budget) else repr(float(budget))}"


def _check(methods, budgets, seeds, rung):
    from scapo.methods import METHODS

    if not methods or not budgets or not seeds:
        raise ConfigError("give at least one method, one budget and one seed")
    for m in methods:
        if not METHODS.get(m).trained:
            raise ConfigError(f"{m!r} is not trained: an accuracy-against-compute curve is for trained methods; give "
                              f"some of {', '.join(LADDER_METHODS)}")
    bad = [b for b in budgets if not (isinstance(b, (int, float)) and math.isfinite(b) and 0 < b <= MAX_BUDGET)]
    if bad:
        raise ConfigError(f"--budgets must be positive numbers of core-minutes, at most {MAX_BUDGET:g} (a week of "
                          f"one core), got {bad}")
    for what, values in (("--budgets", budgets), ("--methods", methods), ("--seeds", seeds)):
        if len(set(values)) != len(values):  # one cell counted twice would pass for two
            raise ConfigError(f"{what}: a value is given twice: {list(values)}; give each once")
    if rung not in RUNGS:
        raise ConfigError(f"unknown rung {rung!r}; known: {', '.join(RUNGS)}")
    if any(s < 0 for s in seeds):
        raise ConfigError(f"training seeds must be >= 0, got {list(seeds)}")


def write_curve(records: Sequence[dict], out: Path, meta: dict, name: str = "accuracy_vs_compute") -> list[Path]:
    """``<out>/<name>.{md,json,csv,png}``: one row per method x budget x seed (the cells' records) and a figure of
    S, median symmetry-aware R and symmetry-aware frame consistency against the budget (log axis). The provenance
    line names the machines the cells were computed on (each record's ``provenance.device``, with counts when they
    differ) apart from the one that wrote the files (``meta["machine"]``). ``meta["note"]``,
    when given, is a paragraph after the description and ``meta["predictions"]`` names the rows' predictions in the
    figure's title (default "one-pass")."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    from scapo.report import markdown_table

    out = check_output_dir(out, "compute curve output folder")
    flat = []
    for r in records:
        flat.append({"method": r["method"], "budget_min": r["budget_min"], "seed": r["seed"],
                     "train_steps": r["wall"].get("train_steps"),
                     "train_wall_min": None if r["wall"].get("train_s") is None else round(r["wall"]["train_s"] / 60,
                                                                                           2),
                     **{k: r.get(k) for k in ("frame_consistency", "frame_consistency_sym", "resampling_deg", "S", "D",
                                              "D_median", "C", "R", "R_median", "R_sym", "R_sym_median",
                                              "R_sym_over90")},
                     "commit": r["provenance"].get("commit"), "dataset_hash": r["dataset_hash"]})
    flat.sort(key=lambda r: (r["method"], r["budget_min"], r["seed"]))
    header = ["method", "core-min", "seed", "steps", "train wall min", "frame cons.", "frame cons. sym",
              "resampling deg", "S %", "D", "D med", "R", "R med", "R sym", "R sym med", "R sym > 90 %"]
    body = [[r["method"], f"{r['budget_min']:g}", r["seed"], "-" if r["train_steps"] is None else str(r["train_steps"]),
             _fmt(r["train_wall_min"]), _fmt(r["frame_consistency"], 2), _fmt(r["frame_consistency_sym"], 2),
             _fmt(r["resampling_deg"]), _fmt(r["S"]), _fmt(r["D"]), _fmt(r["D_median"]), _fmt(r["R"]),
             _fmt(r["R_median"]), _fmt(r["R_sym"]), _fmt(r["R_sym_median"]), _fmt(r["R_sym_over90"])] for r in flat]
    commits = sorted({r["commit"] for r in flat})
    # the cells' own machines (a curve may be finished on another one)
    devices = Counter(r.get("provenance", {}).get("device") or "-" for r in records)
    machines = "; ".join(f"{d} ({n} cell{'s' if n > 1 else ''})" if len(devices) > 1 else d
                         for d, n in sorted(devices.items()))
    rescored = sorted({r["consistency_commit"] for r in records if r.get("consistency_commit")})
    named = sorted({f"{r['method']} {r['budget_values']['preset'].split('/')[0]}" for r in records
                    if isinstance(r.get("budget_values"), dict) and "preset" in r["budget_values"]})
    presets = (f"presets {', '.join(named)} (the table's; each row's schedule in its budget_values)"
               if meta.get("from_table") and named else f"preset {meta['preset']!r}")
    md = [f"# Accuracy against training compute: {meta['category']}, rung {meta['rung']!r} ({meta['split']} split)",
          "",
          "Each cell trains from scratch for its budget (core-minutes of one torch thread, turned into epochs from "
          "the method's clouds/s measured once on this data), with its own learning-rate schedule over that budget; "
          "one-pass predictions scored on val. Columns as in `results/canonical_ladder/` (frame consistency: share "
          "of val samples whose object-frame offset is within 15 deg of the common one; sym: against the declared "
          "symmetric ground truths). Train wall min is the measured wall time of the training run (it may exceed "
          "the budget when other work shared the machine: the budget is fixed in steps, not in seconds).", "",
          *([meta["note"], ""] if meta.get("note") else []),
          markdown_table(header, body), "",
          f"![curves]({meta['name']}.png)", "",
          f"Provenance: commits {', '.join(commits) or '-'}; dataset `{meta['dataset']}` ({meta['instances']} "
          f"instances, {meta['views']} views per val/test instance, {meta['train_views']} per training instance, data "
          f"seed {meta['data_seed']}), {presets}, protocol {meta['protocol']!r}; cells computed on {machines}; "
          f"written on {meta.get('machine', '-')} by `{meta['command']}`."
          + (f" Frame consistency of earlier records scored again from their predictions at {', '.join(rescored)} "
             "(each record's consistency_commit)." if rescored else "")
          + (f" Not computed yet: {', '.join(meta['missing'])}." if meta.get("missing") else ""), ""]
    paths = [out / f"{meta['name']}.md", out / f"{meta['name']}.json", out / f"{meta['name']}.csv",
             out / f"{meta['name']}.png"]
    atomic_write_text(paths[0], "\n".join(md))
    write_json(paths[1], {"meta": meta, "records": list(records)})
    atomic_write_text(paths[2], pd.DataFrame(flat).to_csv(index=False))
    fig, axes = plt.subplots(1, len(CURVE_PANELS), figsize=(4.2 * len(CURVE_PANELS), 3.4))
    for ax, (key, label) in zip(axes, CURVE_PANELS):
        for m in dict.fromkeys(r["method"] for r in flat):
            pts = sorted((r["budget_min"], r[key]) for r in flat if r["method"] == m and r[key] is not None)
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=m)
        ax.set_xscale("log")
        ticks = sorted({r["budget_min"] for r in flat})
        ax.set_xticks(ticks, [f"{b:g}" for b in ticks])
        ax.minorticks_off()
        ax.set_xlabel("training compute (core-minutes)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{meta['category']}, rung {meta['rung']}, val, {meta.get('predictions', 'one-pass')}", fontsize=10)
    fig.tight_layout()
    tmp = paths[3].with_name(paths[3].name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(paths[3])
    return paths


def run_compute_curve(category: str = "laptop", methods: Sequence[str] = LADDER_METHODS,
                      budgets: Sequence[float] = COMPUTE_BUDGETS, seeds: Sequence[int] = (0,),
                      work: str | Path = "bench_work/ladder", out: str | Path = "results", rung: str = "paper",
                      instances: int = 60, views: int = 8, train_views: int = 16, data_seed: int = 1,
                      preset: str = "cpu", protocol: str = "scapo", workers: int = 1,
                      command: str = "scapo bench compute", dry_run: bool = False, data_only: bool = False,
                      finished_only: bool = False, from_table: bool = False,
                      allow_mixed_commits: bool = False) -> list[Path]:
    """Run (or resume) the accuracy-against-compute cells and write ``<out>/accuracy_vs_compute.{md,csv,json,png}``.

    Cells run budget by budget (smallest first), method by method, so an interrupted curve has its cheap points.

    Args:
        methods: trained methods. budgets: core-minutes per cell. seeds: training seeds (the issue: one).
        work: the ladder's work folder (datasets and speed files are shared with ``scapo bench ladder``).
        rung: the ladder rung whose dataset is used (:data:`scapo.bench.ladder.RUNGS`).
        dry_run: list the cells, compute nothing. finished_only: write the table of the finished cells.
        data_only: render the dataset and measure every method's training speed (one after another, so that no
            measurement shares the machine), then stop: run it before chains of methods run side by side.

    Raises:
        ConfigError: an untrained or unknown method, a budget <= 0 or repeated, an unknown rung, a negative seed,
            no finished cell with ``finished_only``; with ``from_table``, a rung other than ``paper``/``sphere`` or
            no finished table dataset of these settings in ``work``. OutputError: an unwritable work or output
            folder. Otherwise as generation, training and evaluation.
    """
    from scapo.data import generate
    from scapo.provenance import device_description

    methods, budgets, seeds = list(methods), [float(b) for b in budgets], list(seeds)
    _check(methods, budgets, seeds, rung)
    if instances < 10:
        raise ConfigError(f"--instances must be >= 10 (a val and a test split of their own), got {instances}")
    if from_table and rung not in ("paper", "sphere"):
        raise ConfigError(f"--from-table: the tables render single views (rung paper or sphere), not rung {rung!r}")
    work = check_output_dir(work, "compute curve work folder")
    if not data_only:
        check_output_dir(out, "compute curve output folder")
    cfg = rung_config(category, rung, instances, views, train_views, data_seed)
    data = (_table_dataset(work, category, rung, instances, views, train_views, data_seed, cfg) if from_table
            else rung_dir(work, category, rung, instances, views, train_views, data_seed))
    name = ("accuracy_vs_compute" if (category, rung) == ("laptop", "paper")
            else f"accuracy_vs_compute_{category}_{rung}")
    if not dry_run and not data_only:
        check_table_rows(Path(out) / f"{name}.json", {(m, b, s) for m in methods for b in budgets for s in seeds},
                         ("method", "budget_min", "seed"), "scapo bench compute")
    meta = {"name": name, "category": category, "rung": rung, "methods": methods, "budgets": budgets, "seeds": seeds,
            "split": "val", "dataset": data.name, "instances": instances, "views": views, "train_views": train_views,
            "data_seed": data_seed, "preset": preset, "protocol": protocol, "command": command,
            "machine": device_description("cpu"), "from_table": bool(from_table),
            "allow_mixed_commits": bool(allow_mixed_commits)}
    if from_table:
        meta["note"] = ("The table's cells at other budgets (`--from-table`): each method trains with the preset "
                        "`scapo bench table1` gives it (the rows' `budget_values` name it with its schedule) and the "
                        "epochs that fill the budget less its one-time work (SCAPO's pseudo-labels between its "
                        "stages, EAP-style's joint estimation) from the table's measured charged speeds, as in the "
                        "table; a cell at the table's own budget and seed is the table's run, predicted and scored "
                        "on val.")

    cells = [(b, m, s) for b in sorted(budgets) for m in methods for s in seeds]
    print(f"scapo bench compute: {category}, rung {rung}; methods {', '.join(methods)}; budgets "
          f"{', '.join(f'{b:g}' for b in sorted(budgets))} core-minutes; seeds {seeds}", flush=True)
    if dry_run:
        for b, m, s in cells:
            print(f"  {b:6g} min  {m:9s} seed {s}: {budget_dir(work, b) / category / rung / f'{m}_s{s}.json'}")
        return []
    if not finished_only:
        if not _finished_dataset(data, cfg):
            generate(cfg, data, workers=workers, progress=False)
        if from_table:
            presets = {b: _table_presets(methods, category, b, preset, work, instances, views, train_views, data_seed,
                                         rung) for b in budgets}
        else:
            presets = {b: _training_presets(methods, data, b, preset, work) for b in budgets}
        if data_only:
            return []
        for b, m, s in cells:
            pc, values, plan = presets[b][m]
            t0 = time.perf_counter()
            if from_table:
                _reuse_table_run(data, budget_dir(work, b), category, rung, m, s, values["preset"])
            rec = _cell(data, budget_dir(work, b), category, rung, m, s, pc, values, protocol, plan=plan)
            print(f"  {b:6g} min  {m:9s} seed {s}: frame consistency sym {_fmt(rec['frame_consistency_sym'], 2)}, "
                  f"S {_fmt(rec['S'])}, R sym median {_fmt(rec['R_sym_median'])}, steps "
                  f"{rec['wall'].get('train_steps')} ({time.perf_counter() - t0:.0f} s)", flush=True)
    return _write_finished(work, data, meta, cells, Path(out), preset)


def _table_kwargs(rung: str, train_views: int) -> dict:
    """The ``data_kwargs`` of ``scapo bench table1`` for the dataset of ``rung`` (its viewpoints, training views)."""
    return {"viewpoints": rung, "train_views": train_views}


def _table_dataset(work: Path, category: str, rung: str, instances: int, views: int, train_views: int, data_seed: int,
                   cfg) -> Path:
    """The finished dataset of a ``scapo bench table1`` work folder that is exactly the rung's ``cfg`` (a single-view
    rung, ``paper`` or ``sphere``: :func:`run_compute_curve` refuses the others first).

    Raises:
        ConfigError: no such finished dataset."""
    from scapo.bench.experiments import dataset_dir

    data = dataset_dir(work, category, instances, views, data_seed, _table_kwargs(rung, train_views))
    if not _finished_dataset(data, cfg):
        raise ConfigError(f"--from-table: {data} is not a finished dataset of {category}, rung {rung}, {instances} "
                          f"instances, {views} views ({train_views} per training instance), data seed {data_seed}; "
                          f"give the table's --work and its --instances/--views/--train-views/--seed, or render it "
                          f"with 'scapo bench table1 --data-only --viewpoints {rung} --categories {category}'")
    return data


def _table_presets(methods: Sequence[str], category: str, budget: float, preset: str, work: Path, instances: int,
                   views: int, train_views: int, data_seed: int, rung: str) -> dict:
    """Per method, the preset object and ``{"preset": name}`` that ``scapo bench table1 --budget-minutes budget``
    trains it with on ``category`` (its preset and the schedule part that fills the budget, from the
    table's measured speeds in ``<work>/speeds/``, measured there first when missing)."""
    from scapo.bench.cells import Cell, method_preset
    from scapo.bench.experiments import budget_cells
    from scapo.methods import METHODS

    cells = [Cell(m, category, seed=0, preset=method_preset(m, preset)) for m in methods]
    budgeted, _, plans = budget_cells(cells, budget, work, instances, views, data_seed,
                                      _table_kwargs(rung, train_views))
    return {c.method: (METHODS.get(c.method).preset(c.preset), {"preset": c.preset}, plans.get((category, c.key)))
            for c in budgeted}


def _reuse_table_run(data: Path, work: Path, category: str, rung: str, method: str, seed: int, preset: str) -> None:
    """Copy the table's finished run of ``method`` at ``preset`` and ``seed`` (``<data>/run_<key>``) to the cell's
    run folder when the cell has neither a record nor a run yet: the cell is then only predicted and scored."""
    import shutil

    from scapo.bench.cells import Cell

    cells = cells_dir(work, category, rung)
    run = cells / f"{method}_s{seed}_run"
    table_run = data / f"run_{Cell(method, category, seed=seed, preset=preset).run_key}"
    if (cells / f"{method}_s{seed}.json").is_file() or run.exists() or not (table_run / "timing.json").is_file():
        return
    print(f"  reusing the table's finished run {table_run.name}", flush=True)
    tmp = run.with_name(run.name + ".copying")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(table_run, tmp)
    tmp.rename(run)


def _write_finished(work: Path, data: Path, meta: dict, cells, out: Path, preset: str) -> list[Path]:
    """The table of every finished cell among ``cells`` (the others are listed in ``meta['missing']``)."""
    from scapo.methods import METHODS

    records, missing = [], []
    for b, m, s in cells:
        path = budget_dir(work, b) / meta["category"] / meta["rung"] / f"{m}_s{s}.json"
        if path.is_file():
            check_reuse(read_record(path), path, dataset_hash(data), budget_s=60.0 * b)
            rec = _upgrade(path, data, m, METHODS.get(m).preset(preset))
            records.append({**rec, "budget_min": b})
        else:
            missing.append(f"{m} {b:g} min seed {s}")
    if not records:
        raise ConfigError(f"no finished cell of the compute curve in {work / 'compute'}; run it without "
                          "--finished-only")
    meta = {**meta, "missing": missing, "cell_options": CELL_OPTIONS}
    check_one_commit(records, meta.get("allow_mixed_commits", False))
    return write_curve(records, out, meta)
