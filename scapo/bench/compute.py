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

Outputs: ``<out>/accuracy_vs_compute.{md,csv,json,png}``.
"""

from __future__ import annotations

import math
import time
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
    """The cells' folder of one budget: ``<work>/compute/b<budget>`` (``b5``, ``b15``, ``b2.5``)."""
    return Path(work) / "compute" / f"b{budget:g}"


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
    S, median symmetry-aware R and symmetry-aware frame consistency against the budget (log axis). ``meta["note"]``,
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
          f"seed {meta['data_seed']}), preset {meta['preset']!r}, protocol {meta['protocol']!r}; machine "
          f"{meta.get('machine', '-')}; written by `{meta['command']}`."
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
                      finished_only: bool = False) -> list[Path]:
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
            no finished cell with ``finished_only``. OutputError: an unwritable work or output folder.
            Otherwise as generation, training and evaluation.
    """
    from scapo.data import generate
    from scapo.provenance import device_description

    methods, budgets, seeds = list(methods), [float(b) for b in budgets], list(seeds)
    _check(methods, budgets, seeds, rung)
    if instances < 10:
        raise ConfigError(f"--instances must be >= 10 (a val and a test split of their own), got {instances}")
    work = check_output_dir(work, "compute curve work folder")
    if not data_only:
        check_output_dir(out, "compute curve output folder")
    cfg = rung_config(category, rung, instances, views, train_views, data_seed)
    data = rung_dir(work, category, rung, instances, views, train_views, data_seed)
    name = ("accuracy_vs_compute" if (category, rung) == ("laptop", "paper")
            else f"accuracy_vs_compute_{category}_{rung}")
    meta = {"name": name, "category": category, "rung": rung, "methods": methods, "budgets": budgets, "seeds": seeds,
            "split": "val", "dataset": data.name, "instances": instances, "views": views, "train_views": train_views,
            "data_seed": data_seed, "preset": preset, "protocol": protocol, "command": command,
            "machine": device_description("cpu")}
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
        presets = {b: _training_presets(methods, data, b, preset, work) for b in budgets}
        if data_only:
            return []
        for b, m, s in cells:
            pc, values = presets[b][m]
            t0 = time.perf_counter()
            rec = _cell(data, budget_dir(work, b), category, rung, m, s, pc, values, protocol)
            print(f"  {b:6g} min  {m:9s} seed {s}: frame consistency sym {_fmt(rec['frame_consistency_sym'], 2)}, "
                  f"S {_fmt(rec['S'])}, R sym median {_fmt(rec['R_sym_median'])}, steps "
                  f"{rec['wall'].get('train_steps')} ({time.perf_counter() - t0:.0f} s)", flush=True)
    return _write_finished(work, data, meta, cells, Path(out), preset)


def _write_finished(work: Path, data: Path, meta: dict, cells, out: Path, preset: str) -> list[Path]:
    """The table of every finished cell among ``cells`` (the others are listed in ``meta['missing']``)."""
    from scapo.methods import METHODS

    records, missing = [], []
    for b, m, s in cells:
        path = budget_dir(work, b) / meta["category"] / meta["rung"] / f"{m}_s{s}.json"
        if path.is_file():
            rec = _upgrade(path, data, m, METHODS.get(m).preset(preset))
            records.append({**rec, "budget_min": b})
        else:
            missing.append(f"{m} {b:g} min seed {s}")
    if not records:
        raise ConfigError(f"no finished cell of the compute curve in {work / 'compute'}; run it without "
                          "--finished-only")
    meta = {**meta, "missing": missing, "cell_options": CELL_OPTIONS}
    return write_curve(records, out, meta)
