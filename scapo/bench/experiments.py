"""The paper's tables regenerated with our methods: ``scapo bench table1|table2|table3`` (:func:`run_table` with
a :class:`TableSpec` of :data:`TABLES` and :class:`BenchOptions`).

Both are lists of :class:`~scapo.bench.cells.Cell` computed one by one (:func:`~scapo.bench.cells.compute_cell`:
resumable per cell, a finished cell is never recomputed), then written as tables and figures from the
cells' records alone, so a rerun of a finished bench recomputes nothing and writes identical files.

- Table 1 (:func:`run_table1`): every method x category x training seed, in the paper's Table 1
  layout with the robust statistics below it (:func:`scapo.eval.tables.write_table1`), per category a
  figure of test views (ground truth and each method's segmentation and joint axes) and one figure of
  the error distributions (R and D per method and category).
- Table 3 (:func:`run_table3`): SCAPO with each regulariser of the paper's ablation switched off
  (presets ``<preset>/no-<term>``, :func:`scapo.models.presets.get_preset`) beside the full model,
  whose cells are Table 1's SCAPO cells when both benches share the work folder.

The tables' provenance is a function of the cells (their commits, devices, presets, dataset hashes
and wall times), not of the moment the tables were written.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from scapo.bench.archive import (
    archive_cell,
    archive_conflict,
    archive_dataset,
    reconcile_dataset,
    restore_cells,
)
from scapo.bench.cells import (
    Cell,
    cell_paths,
    cell_status,
    compute_cell,
    computed_commit,
    dirty_commit,
    dirty_sha,
    method_preset,
)
from scapo.data import generate, load, make_config
from scapo.data.config import viewpoints_of
from scapo.errors import BudgetError, ConfigError, ScapoWarning
from scapo.files import check_output_dir
from scapo.methods import METHODS, describe
from scapo.provenance import git_commit
from scapo.registry import Registry

#: Categories of the paper's Table 1 (and of our Table 3), in its column order.
TABLE1_CATEGORIES = ("laptop", "safe", "eyeglasses", "oven", "washer")


def table_methods() -> list[str]:
    """Every registered method in the paper's row order: supervised methods first (most labels first),
    then the others in registration order, SCAPO (ours) last."""
    names = list(METHODS)
    return sorted(names, key=lambda m: (-sum(bool(v) for v in METHODS.get(m).supervision.values()), m == "scapo",
                                        names.index(m)))


def dataset_dir(work: Path, category: str, instances: int, views: int, seed: int,
                data_kwargs: Mapping | None = None) -> Path:
    """``<work>/<category>_i<instances>_v<views>[_t<train views>]_s<seed>[_paper][_parts]``: the training views appear
    when they differ from ``views``, ``_paper`` for the paper's viewpoints (``data_kwargs["viewpoints"]``), ``_parts``
    for every part rendered alone (``data_kwargs["parts_alone"]``); the whole sphere's and the upright datasets keep
    the names they had before the settings existed (the generator refuses a folder of another config)."""
    kw = data_kwargs or {}
    tv = int(kw.get("train_views") or 0)
    name = f"{category}_i{instances}_v{views}" + (f"_t{tv}" if tv and tv != views else "") + f"_s{seed}"
    return Path(work) / (name + ("_paper" if kw.get("viewpoints") == "paper" else "")
                         + ("_parts" if kw.get("parts_alone") else ""))


def parse_category_seeds(specs: Sequence[str]) -> dict[str, list[int]]:
    """``["safe=0", "laptop=0,1,2"]`` -> ``{"safe": [0], "laptop": [0, 1, 2]}``.

    Raises:
        ConfigError: a spec that is not ``CATEGORY=SEED[,SEED...]`` with seeds >= 0.
    """
    out: dict[str, list[int]] = {}
    for spec in specs:
        cat, eq, seeds = str(spec).partition("=")
        try:
            vals = [int(s) for s in seeds.split(",") if s.strip()]
        except ValueError:
            vals = []
        if not eq or not cat or not vals or min(vals) < 0:
            raise ConfigError(f"--category-seeds {spec!r} is not CATEGORY=SEED[,SEED...] (e.g. safe=0 or "
                              "laptop=0,1,2)")
        out[cat] = vals
    return out


def table1_cells(methods: Sequence[str], categories: Sequence[str], preset: str, seeds: Sequence[int],
                 category_seeds: dict[str, list[int]] | None = None, refine_rows: bool = True,
                 parts: Sequence[str] = (), option_rows: Sequence[str] = ()) -> list[Cell]:
    """Every cell of Table 1: per category, per method, per training seed of a trained method
    (``category_seeds[cat]`` overrides ``seeds`` for that category). Every row is a one-pass prediction: a method
    with a test-time refinement of its own (its entry's ``one_pass`` options) predicts without it, and with
    ``refine_rows`` every method with a whole-object model (``MethodEntry.refinable``) gets the method-independent
    refinement (:mod:`scapo.steps.refine`) of the same run's one-pass prediction as a row of its own, labelled
    ``<method>+refine`` (equal treatment: no row gets a test-time search another lacks). ``parts``: extra rows
    ``METHOD/PART`` (e.g. ``scapo/principal``): that trained method, one of ``methods``, trained with its preset
    ``<preset>/PART`` (a preset part the method's registry knows, e.g. :func:`scapo.models.presets.get_preset`'s
    ``principal``) on the same seeds, one-pass, labelled ``<method>-<PART>`` (an addition's own ablation row, at the
    same budget as every row). ``option_rows``: extra rows ``METHOD:LABEL:KEY=VALUE[,KEY=VALUE...]`` (e.g.
    ``scapo:base-frame:base_frame=principal``): the same trained runs as the method's one-pass row, predicted with
    those prediction options (``scapo predict --option`` keys) added, labelled ``<method>-<LABEL>`` (an inference
    addition's own ablation row: no training, the runs are shared).

    Raises:
        UnknownNameError: unknown method or preset part. ConfigError: a preset a trained method does not have, a
        category in ``category_seeds`` that is not in ``categories``, no seeds, a part or option row of a method that
        is not among ``methods``, not trained, or given twice, or an option row with an unknown or invalid option.
    """
    extra_rows = []
    for text in parts:
        m, slash, part = str(text).partition("/")
        if not slash or not m or not part or "/" in part:
            raise ConfigError(f"--part {text!r}: write METHOD/PART, e.g. scapo/principal")
        if m not in methods:
            raise ConfigError(f"--part {text}: {m!r} is not among the table's methods ({', '.join(methods)})")
        if not METHODS.get(m).trained:
            raise ConfigError(f"--part {text}: {m} is not trained; a part changes a training preset")
        if (m, part) in extra_rows:
            raise ConfigError(f"--part {text} is given twice; give each once")
        extra_rows.append((m, part))
    option_extra = []
    for text in option_rows:
        from scapo.bench.ladder import parse_variant
        from scapo.methods import validate_options

        m, label, values = parse_variant(text, "--option-row", "scapo:base-frame:base_frame=principal")
        if m not in methods:
            raise ConfigError(f"--option-row {text}: {m!r} is not among the table's methods ({', '.join(methods)})")
        if not METHODS.get(m).trained:
            raise ConfigError(f"--option-row {text}: {m} is not trained; an option row shares a trained method's runs")
        if any(mm == m and lab == label for mm, lab, _ in option_extra):
            raise ConfigError(f"--option-row {m}:{label} is given twice; give each once")
        validate_options(m, values)  # an unknown option or a bad value is refused before any work
        option_extra.append((m, label, tuple(values.items())))
    category_seeds = dict(category_seeds or {})
    extra = set(category_seeds) - set(categories)
    if extra:
        raise ConfigError(f"--category-seeds names {', '.join(sorted(extra))}, which is not among the categories "
                          f"({', '.join(categories)})")
    cells = []
    for cat in categories:
        cat_seeds = [int(s) for s in category_seeds.get(cat, seeds)]
        if not cat_seeds:
            raise ConfigError("no training seeds given (--seeds 0,1,2)")
        bad = [x for x in cat_seeds if not 0 <= x < 2 ** 32]
        if bad:  # checked with the cells, before any dataset is rendered (the dry run too)
            raise ConfigError(f"training seeds must be integers in [0, 2**32), got {bad} for {cat}")
        for m in methods:
            entry = METHODS.get(m)
            if not entry.trained:
                cells.append(Cell(m, cat))
                continue
            p = method_preset(m, preset)
            one = tuple(entry.one_pass.items())
            cells += [Cell(m, cat, s, p, options=one) for s in cat_seeds]
            if entry.refinable and refine_rows:  # the method-independent refinement, its own row
                cells += [Cell(m, cat, s, p, label=f"{m}+refine", run_label=m, options=one + (("refine", True),))
                          for s in cat_seeds]
            for part in (part for mm, part in extra_rows if mm == m):
                entry.preset(f"{p}/{part}")  # an unknown part is refused before any work
                cells += [Cell(m, cat, s, f"{p}/{part}", label=f"{m}-{part}", options=one) for s in cat_seeds]
            for label, values in ((lab, v) for mm, lab, v in option_extra if mm == m):
                opts = tuple({**dict(one), **dict(values)}.items())
                cells += [Cell(m, cat, s, p, label=f"{m}-{label}", run_label=m, options=opts) for s in cat_seeds]
    return cells


def table3_cells(categories: Sequence[str], preset: str, seeds: Sequence[int],
                 category_seeds: dict[str, list[int]] | None = None,
                 ablations: Sequence[str] | None = None, method: str = "scapo") -> list[Cell]:
    """The SCAPO ablation's cells: per category and seed, the full model and one run per ablated
    regulariser (the method entry's ``ablations``: :data:`scapo.models.presets.ABLATIONS` for SCAPO), labelled
    ``<method>-no-<term>``."""
    entry = METHODS.get(method)
    category_seeds = dict(category_seeds or {})
    cells = []
    for cat in categories:
        full = method_preset(method, preset)
        one = tuple(entry.one_pass.items())  # every row one-pass, as Table 1's (its "Full" rows are those cells)
        for s in category_seeds.get(cat, seeds):
            cells.append(Cell(method, cat, int(s), full, options=one))
            for term in (ablations or entry.ablations):
                entry.preset(f"{full}/no-{term}")  # an unknown term is refused before any work
                cells.append(Cell(method, cat, int(s), f"{full}/no-{term}", label=f"{method}-no-{term}", options=one))
    return cells


def _dataset_hash(data: Path) -> str | None:
    if not (data / "card.json").is_file():
        return None
    try:
        return load(data, "test").dataset_hash
    except Exception:  # noqa: BLE001 - a partial or damaged folder: the bench regenerates or reports it
        return None


def plan(cells: Sequence[Cell], work: Path, instances: int, views: int, data_seed: int, protocol: str,
         recompute_dirty: bool = False, archive: Path | None = None, data_kwargs: Mapping | None = None) -> list[dict]:
    """One row per cell: category, key, method, seed, preset, status (:func:`cell_status`; ``todo``
    also when its dataset is not generated yet; ``restore`` when a cell that is not done in the work folder is in
    the cells ``archive`` for this dataset, or for a dataset still to generate: the bench restores it then), the
    recorded wall seconds of a done cell, and the commit its record names (``-dirty``: computed from a checkout with
    uncommitted changes)."""
    import json

    rows, hashes = [], {}
    for c in cells:
        data = dataset_dir(work, c.category, instances, views, data_seed, data_kwargs)
        if data not in hashes:
            hashes[data] = _dataset_hash(data)
        status = cell_status(data, c, protocol, hashes[data], recompute_dirty)
        seconds, commit, dirty = math.nan, "", ""
        if status != "done" and archive is not None:
            kept = cell_paths(Path(archive) / data.name, c, protocol).record
            try:
                rec = json.loads(kept.read_text())
            except (OSError, ValueError):
                rec = None
            if rec is not None and hashes[data] in (None, rec.get("dataset_hash")):
                status, commit = "restore", computed_commit(rec)
                seconds = sum(v for k, v in rec.get("wall", {}).items() if k.endswith("_s"))
        if status in ("done", "recompute (dirty)", "re-evaluate (dirty)"):
            rec = json.loads(cell_paths(data, c, protocol).record.read_text())
            commit = computed_commit(rec)
            if dirty_commit(rec):
                dirty = "computed" if dirty_sha(commit) else "evaluated"
                if dirty == "evaluated":
                    commit = str(rec["provenance"]["commit"])  # evaluated from dirty code: the listing shows that one
            if status == "done":
                seconds = sum(v for k, v in rec["wall"].items() if k.endswith("_s"))
        rows.append({"category": c.category, "key": c.key, "method": c.method, "seed": c.seed, "preset": c.preset,
                     "status": status, "dataset": "generated" if hashes[data] else "to generate",
                     "seconds": seconds, "commit": commit, "dirty": dirty})
    return rows


def print_plan(rows: list[dict]) -> None:
    """The dry run's listing: one line per cell and a count per status."""
    for r in rows:
        secs = "" if math.isnan(r["seconds"]) else f"{r['seconds'] / 60:7.1f} min"
        dirty = r.get("dirty", "")
        again = "computes it again" if dirty == "computed" else "evaluates its predictions again"
        print(f"{r['category']:11s} {r['key']:44s} {r['status']:19s} {secs}"
              + ("" if r["dataset"] == "generated" else "  (dataset to generate)")
              + (f"  ({dirty} at {r['commit'][:12]}-dirty; --recompute-dirty {again})"
                 if dirty and r["status"] == "done" else ""))
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    done = sum(r["seconds"] for r in rows if not math.isnan(r["seconds"]))
    print(f"{len(rows)} cells: " + ", ".join(f"{n} {s}" for s, n in counts.items())
          + f"; recorded compute of the done and archived cells: {done / 3600:.2f} h")


#: The splits of every bench dataset: a fifth of the instances for test and a tenth for val, so that the default
#: 150 instances give 30 test instances per category (8 were too few for the bootstrap to separate methods).
BENCH_SPLITS = {"test_fraction": 0.2, "val_fraction": 0.1}
#: How Tables 1 and 3 rendered their datasets before the paper's viewpoints existed, and render them with
#: ``--viewpoints sphere``: clean sensor, the object's rotation drawn uniformly from SO(3) for every view (harder than
#: the paper: undersides and backs its data never shows), cropped views rejected.
SYNTHETIC_DATA = {"random_rotation": True, **BENCH_SPLITS}
#: Views per training instance of the paper's viewpoints in Tables 1 and 3 (val and test instances keep ``views``),
#: chosen on the val split (results/paper_regime/README.md); EAP renders about 100 per training instance.
PAPER_TRAIN_VIEWS = 64
#: The dataset settings (:func:`~scapo.data.config.make_config` keywords) of each ``--viewpoints`` setting of Tables
#: 1 and 3: ``paper`` (the default: EAP's views, which the SCAPO paper follows; :class:`~scapo.sim.render.ViewConfig`),
#: ``sphere`` (whole sphere, beyond the paper) and ``upright`` (the category's azimuth/elevation ranges, the rotation
#: diagnostic).
VIEWPOINT_DATA = {"paper": {"viewpoints": "paper", "train_views": PAPER_TRAIN_VIEWS, **BENCH_SPLITS},
                  "sphere": SYNTHETIC_DATA,
                  "upright": {**SYNTHETIC_DATA, "random_rotation": False}}
#: How the bench labels each setting wherever it prints one (table titles, provenance).
VIEWPOINT_LABELS = {"paper": "the paper's viewpoints (EAP's ranges per source dataset)",
                    "sphere": "whole sphere (uniform SO(3) object rotations; harder than the paper)",
                    "upright": "upright (the category's view ranges, as real scans are; for Tables 1 and 3 the "
                               "rotation diagnostic, not the paper's setting)"}
#: How Table 2 renders its datasets: the realistic sensor (scapo.sim.sensor), upright as real scans are, cropped
#: views rejected.
REAL_STYLE_DATA = {"sensor": "realistic", "cropped": "reject", **BENCH_SPLITS}
#: Per-category exceptions to the settings above (any other category uses them as they are, so the datasets
#: made before an exception existed keep their config hash). basket: its thin handles keep too few of the
#: 1024 points under the realistic sensor for some instances (instance 15 of data seed 1 failed all 50 views
#: at 5 %); 3 % renders every instance.
REAL_STYLE_CATEGORY_DATA = {"basket": {"min_part_fraction": 0.03}}


def data_settings(category: str, data_kwargs: dict | None = None, category_data: dict | None = None) -> dict:
    """The :func:`~scapo.data.config.make_config` keywords of a bench dataset: ``data_kwargs`` (default
    :data:`SYNTHETIC_DATA`) updated by ``category_data[category]`` when present."""
    return {**(data_kwargs or SYNTHETIC_DATA), **(category_data or {}).get(category, {})}


#: The protocols every archived cell is scored under when it is archived without its predictions (the tables'
#: ``--protocol`` rows then come from the archive alone): the SCAPO paper's, OP-Align's and EAP's rules.
ARCHIVED_PROTOCOLS = ("scapo", "op-align", "eap")


def _compute(cells: Sequence[Cell], work: Path, instances: int, views: int, data_seed: int, protocol: str,
             workers: int, cache_dir, progress: bool, device: str | None, finished_only: bool = False,
             data_kwargs: dict | None = None, recompute_dirty: bool = False, category_data: dict | None = None,
             archive: Path | None = None, data_only: bool = False, archive_predictions: bool = False,
             plans: dict | None = None):
    """Generate each dataset once (resumes), then compute every cell in order; with ``finished_only``
    nothing is computed and only the cells that are done are returned (the others in ``missing``). With
    ``archive`` (:mod:`scapo.bench.archive`), each generated dataset is first made the archived dataset's bytes
    where it differs from it only by rounding (:func:`~scapo.bench.archive.reconcile_dataset`), or pinned in the
    archive when none is (:func:`~scapo.bench.archive.archive_dataset`); the archived cells of each dataset are
    restored into the work folder once the dataset exists, and every done cell is archived (its predictions only with
    ``archive_predictions``; without them it is also scored and archived under each of :data:`ARCHIVED_PROTOCOLS`,
    so that tables under another protocol come from the archive alone). With ``data_only``
    the datasets are generated (reconciled, pinned, their cells restored) and no cell is computed or returned.
    ``plans`` (:func:`budget_cells`): each trained cell's budget, which its run's ledger is held to."""
    results, records, hashes, done, missing = [], [], {}, [], []

    def restore(data: Path, category: str) -> None:
        if archive is not None and hashes.get(category):
            restored = restore_cells(data, archive, hashes[category])
            if restored:
                print(f"restored {len(restored)} cell(s) of {data.name} from the archive {archive}", flush=True)

    def pin(data: Path) -> None:
        rep = reconcile_dataset(data, archive)
        if rep["status"] == "reconciled":
            derived = set(rep.get("recomputed", {}))
            moved = max((v for k, v in rep["max_abs_diff"].items() if k not in derived), default=0.0)
            again = "".join(f"; {k} computed again from the archived ground truth in {n} shard(s), moved by at most "
                            f"{rep['max_abs_diff'].get(k, 0.0):.2g}"
                            for k, n in sorted(rep.get("recomputed", {}).items()))
            print(f"{data.name}: generated as {rep['generated_hash'][:12]}, made the archived dataset "
                  f"{rep['dataset_hash'][:12]} ({rep['shards']} shard(s); double-precision values moved by at most "
                  f"{moved:.2g}{again})", flush=True)
        elif rep["status"] == "different":
            warnings.warn(f"{data.name} is not the archived dataset {rep['archived'][:12]} ({rep['why']}); its "
                          "archived cells are computed again", ScapoWarning, stacklevel=2)
        pinned = archive_dataset(data, archive)
        if pinned == "archived":
            print(f"{data.name}: dataset {load(data, 'test').dataset_hash[:12]} pinned in the archive {archive}",
                  flush=True)
        elif pinned == "unpinned cells":
            warnings.warn(f"{data.name}: {archive_conflict(data, archive)}; those cells are not restored here",
                          ScapoWarning, stacklevel=2)

    for c in cells:
        data = dataset_dir(work, c.category, instances, views, data_seed, data_kwargs)
        if finished_only:
            if c.category not in hashes:
                hashes[c.category] = _dataset_hash(data)
                restore(data, c.category)
            # done, or predicted and only to be scored again (the evaluator changed since): cheap, computes nothing
            if hashes[c.category] is None or cell_status(data, c, protocol, hashes[c.category]) not in (
                    "done", "evaluate"):
                missing.append(c)
                continue
        elif c.category not in hashes:
            generate(make_config(c.category, instances, views, data_seed,
                                 **data_settings(c.category, data_kwargs, category_data)), data,
                     workers=workers,
                     progress=progress, cache_dir=cache_dir)
            if archive is not None:
                pin(data)
            hashes[c.category] = load(data, "test").dataset_hash
            restore(data, c.category)
        if data_only:
            continue
        try:
            res, rec, computed = compute_cell(data, c, protocol, progress=progress, device=device,
                                              recompute_dirty=recompute_dirty, evaluate_only=finished_only,
                                              plan=(plans or {}).get((c.category, c.key)))
        except BudgetError as e:  # the other cells go on; the table lists this one as not done
            print(f"refused  {c.category:11s} {c.key:44s} {e}", flush=True)
            missing.append(c)
            continue
        if archive is not None:
            archive_cell(data, c, protocol, archive, predictions=archive_predictions)
            kept = cell_paths(Path(archive) / data.name, c, protocol)
            if not archive_predictions and not kept.predictions.with_name(kept.predictions.name + ".xz").is_file():
                # the predictions stay behind: their scores under the other protocols go to the archive now
                for other in ARCHIVED_PROTOCOLS:
                    if (other != protocol and cell_paths(data, c, other).predictions.is_file()
                            and not cell_paths(Path(archive) / data.name, c, other).record.is_file()):
                        compute_cell(data, c, other, progress=False, device=device, evaluate_only=True)
                        archive_cell(data, c, other, archive)
        s = res.summary
        print(f"{'computed' if computed else 'cached  '} {c.category:11s} {c.key:44s} "
              + " ".join(f"{k}={s[k]:.3f}" for k in ("S", "D", "C", "R", "R_median")), flush=True)
        results.append(res)
        records.append(rec)
        done.append(c)
    if finished_only and not done:
        raise ConfigError("no cell of this bench is done yet; run it without --finished-only first")
    if data_only:
        print(f"datasets ready: {', '.join(f'{k} {v[:12]}' for k, v in hashes.items())}", flush=True)
    return results, records, {k: v for k, v in hashes.items() if v}, done, missing


def training_run(cell: dict) -> str:
    """The trained run a provenance cell (``category``, ``cell``, optional ``run``) predicted from: its ``run``
    (the run folder's name, e.g. ``run_eap_cpu_s0``), or for a record written before the field existed the one-pass
    cell's run (a "+ refine" cell, ``eap+refine_cpu_s0``, predicts from ``run_eap_cpu_s0``)."""
    return str(cell.get("run") or "run_" + str(cell["cell"]).replace("+refine", ""))


def compute_seconds(cells, datasets: dict | None = None, seen: set | None = None) -> float:
    """Compute (s) held by provenance cells, each training counted once: a "+ refine" cell reuses the run its
    one-pass cell trained (its ``train_s`` is that run's), so only its prediction and evaluation add.

    ``cells``: dicts with ``category``, ``cell`` and optional ``run``, ``train_s``, ``predict_s``, ``evaluate_s``
    (seconds); ``datasets``: category -> dataset hash, so that cells of several tables on one dataset (Table 3's
    SCAPO cells are Table 1's) are one; ``seen``: a set shared between calls for such tables (updated in place).
    Returns seconds (float)."""
    seen = set() if seen is None else seen
    datasets = datasets or {}
    total = 0.0
    for c in cells:
        data = datasets.get(c["category"], c["category"])
        if ("cell", data, c["cell"]) not in seen:
            seen.add(("cell", data, c["cell"]))
            total += float(c.get("predict_s") or 0.0) + float(c.get("evaluate_s") or 0.0)
        if c.get("train_s") and ("run", data, training_run(c)) not in seen:
            seen.add(("run", data, training_run(c)))
            total += float(c["train_s"])
    return total


def _provenance(name: str, cells, records, hashes, instances, views, data_seed, protocol, preset,
                missing=(), random_rotation: bool = True, viewpoints: str | None = None, train_views: int = 0,
                parts_alone: bool = False) -> dict:
    """Provenance from the cells' records only (deterministic for a finished bench); ``missing``: cells
    of the bench left out because they are not done (``--finished-only``); ``random_rotation``: whether the
    datasets' objects were turned by a uniform SO(3) rotation (False: upright); ``parts_alone``: every part rendered
    alone (recorded only when set). A cell whose record was adopted by
    its dataset's regeneration on another CPU kind (:func:`scapo.bench.archive.adopt_dataset`) names the dataset it
    was computed on (``adopted_from``)."""
    per_cell = []
    for c, r in zip(cells, records):
        w = r["wall"]
        per_cell.append({"category": c.category, "cell": c.key, "method": c.method, "preset": c.preset, "seed": c.seed,
                         "commit": computed_commit(r), "device": r["provenance"]["device"],
                         **({"evaluated_at": r["provenance"]["commit"]}
                            if r["provenance"]["commit"] != computed_commit(r) else {}),
                         **({"adopted_from": str(r["adopted"].get("from", ""))[:16]}
                            if isinstance(r.get("adopted"), dict) else {}),
                         **({"run": r["run"]} if isinstance(r.get("run"), str) else {}),
                         **{k: w[k] for k in ("train_s", "train_steps", "charged_s", "predict_s", "evaluate_s",
                                              "infer_ms_per_cloud") if k in w}})
    seeds: dict[str, list[int]] = {}
    for c in cells:
        if c.seed is not None and c.seed not in seeds.setdefault(c.category, []):
            seeds[c.category].append(c.seed)
    total = compute_seconds(per_cell)  # a "+ refine" cell's training is its one-pass cell's run: counted once
    return {"bench": name, "preset": preset, "protocol": protocol,
            "data": {"instances": instances, "views": views, "seed": data_seed, "random_rotation": random_rotation,
                     **({"viewpoints": viewpoints, "viewpoints_label": VIEWPOINT_LABELS[viewpoints]}
                        if viewpoints else {}),
                     **({"train_views": train_views} if train_views and train_views != views else {}),
                     **({"parts_alone": True} if parts_alone else {})},
            "datasets": {k: v[:16] for k, v in hashes.items()}, "training_seeds": seeds,
            "commits": sorted({p["commit"] for p in per_cell} | {p["evaluated_at"] for p in per_cell
                                                                  if "evaluated_at" in p}),
            "devices": sorted({p["device"] for p in per_cell}),
            "compute_hours": round(total / 3600, 2), "cells": per_cell,
            **({"missing_cells": [f"{c.category}/{c.key}" for c in missing]} if missing else {})}


def _check(methods, categories, protocol, work, out_dir):
    from scapo.eval.protocols import get_protocol

    for cat in categories:
        make_config(cat, 1, 1, 0)  # an unknown category is refused before any work
    if not methods:
        raise ConfigError("no methods given (--methods icp,npcs,eap,op-align,scapo)")
    protocol = get_protocol(protocol).name
    if work is not None:
        check_output_dir(work, "bench work folder")
    if out_dir is not None:
        check_output_dir(out_dir, "table folder")
    return protocol


def _writer(write_table, name, out_dir, figures, work_dir, instances, views, data_seed, data_kwargs=None):
    """``write(results, done cells, provenance) -> paths`` of a table with its figures (Tables 1 and 2)."""
    def write(results, done, prov):
        paths = write_table(results, out_dir, prov, name=name, describe=describe)
        if figures:
            paths += _figures(done, results, work_dir, instances, views, data_seed, prov["protocol"], out_dir, name,
                              data_kwargs)
        return paths

    return write


def budget_cells(cells: Sequence[Cell], budget_minutes: float, work_dir: Path, instances: int, views: int,
                 data_seed: int, data_kwargs: Mapping | None = None, measure: bool = True,
                 archive: Path | None = None) -> tuple[list[Cell], dict, dict]:
    """The cells with the equal training budget (``scapo bench table1 --budget-minutes``): every trained cell's
    preset gets the schedule part (:func:`scapo.registry.schedule_part`, e.g. ``cpu/epochs-15-13``) whose epochs fill
    ``budget_minutes`` of one CPU core on its category's dataset less its one-time work (every charged core-second
    before the method can predict: set-up, stage starts, the work after the last epoch such as EAP-style's joint
    estimation; :mod:`scapo.engine.ledger`), from the method's charged clouds/s measured once on that dataset through
    the engine
    (:func:`scapo.bench.perf.bench_train_data` and
    :func:`scapo.bench.perf.training_budget`, as ``scapo bench ladder`` and ``scapo bench compute`` make theirs;
    ``<work>/speeds/<dataset>_<method>_<preset>.json``, measured with the torch threads this process has: run it
    as the cells will run, one thread per core). The datasets must exist (the bench generates them first). Measuring,
    a speed file is reused only where this machine can plan from it (:func:`scapo.bench.ladder.measured_speed`: a file
    of another kind of CPU, or from before the ledger, is kept aside and measured again; a measurement on a busy
    machine is refused). With ``archive`` (``--archive``), the speed files travel with the cells: a file the work
    folder lacks is restored from ``<archive>/speeds/`` first, and every speed file of the work folder is kept there
    after (a table resumed on a new machine plans from the speeds its cells were planned from, so their keys, which
    name the schedule, are found again; ``--finished-only`` names them from it).

    Returns:
        The cells (fitted ones unchanged), ``{category: {preset of the cell: schedule part}}`` for the table's
        provenance, and ``{(category, cell key): plan}`` (:func:`scapo.bench.ladder.budget_plan`: the budget and
        each phase's planned charged seconds) that :func:`~scapo.bench.cells.compute_cell` holds the trained run's
        ledger to.

    Raises:
        ConfigError: ``budget_minutes`` not in (0, 45 * 16]; with ``measure=False`` (``--finished-only``, ``--dry-run``)
        a speed not measured yet; measuring, as :func:`scapo.bench.ladder.measured_speed`.
    """
    import json
    import shutil

    from scapo.bench.ladder import budget_plan, measured_speed
    from scapo.bench.perf import budget_schedule, training_budget
    from scapo.config import override
    from scapo.registry import schedule_part

    if not (math.isfinite(budget_minutes) and 0 < budget_minutes <= 720):
        raise ConfigError(f"--budget-minutes must be a positive number of core-minutes per training run, at most 720, "
                          f"got {budget_minutes}")
    out, schedules, speeds, plans = [], {}, {}, {}
    for c in cells:
        if not c.trained:
            out.append(c)
            continue
        data = dataset_dir(work_dir, c.category, instances, views, data_seed, data_kwargs)
        path = Path(work_dir) / "speeds" / f"{data.name}_{c.method}_{c.preset.replace('/', '+')}.json"
        kept = None if archive is None else Path(archive) / "speeds" / path.name
        if not path.is_file() and kept is not None and kept.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(kept, path)  # the speed its archived cells were planned from
        if path not in speeds:  # one read per dataset and method (the seeds share it)
            if measure:
                rows = measured_speed(path, Path(work_dir) / "speeds" / "runs" / data.name, c.method, c.preset, data,
                                      command="scapo bench")
            elif path.is_file():
                rows = json.loads(path.read_text())
            else:
                raise ConfigError(f"--budget-minutes: the training speed of {c.method} ({c.preset}) on {data.name} "
                                  f"is not measured yet ({path}); run the bench without --finished-only / --dry-run")
            speeds[path] = training_budget(rows, budget_minutes, int(rows[0]["train_clouds"]))[0]
        base = METHODS.get(c.method).preset(c.preset)
        values = budget_schedule(speeds[path], base, budget_minutes)
        override(base, values, f"{c.method} preset")  # a schedule this preset takes
        part = schedule_part(values)
        schedules.setdefault(c.category, {})[f"{c.method} {c.preset}"] = part
        out.append(replace(c, preset=f"{c.preset}/{part}"))
        plans[(c.category, out[-1].key)] = budget_plan(speeds[path], values, budget_minutes,
                                                       int(speeds[path]["train_clouds"]))
    if archive is not None and measure and (Path(work_dir) / "speeds").is_dir():
        for f in sorted((Path(work_dir) / "speeds").glob("*.json")):  # with the files set aside (other kinds)
            dst = Path(archive) / "speeds" / f.name
            if not dst.is_file() or dst.read_bytes() != f.read_bytes():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(f, dst)
    return out, schedules, plans


def _bench(title, cells, methods, categories, write, instances, views, data_seed, work_dir, out_dir, preset, protocol,
           workers, cache_dir, dry_run, progress, device, finished_only, data_kwargs=None, recompute_dirty=False,
           category_data=None, allow_dirty=False, allow_mixed_commits=False, archive=None, data_only=False,
           archive_predictions=False, budget_minutes=None):
    """What both tables do: check names and outputs, list the cells (dry run) or compute them, and
    ``write(results, done cells, provenance) -> paths`` into ``out_dir`` (one clean commit for every cell unless
    allowed: :func:`check_commits`)."""
    if finished_only and recompute_dirty:
        raise ConfigError("--finished-only computes nothing and --recompute-dirty recomputes cells: use one of them")
    if data_only and (finished_only or recompute_dirty or dry_run):
        raise ConfigError("--data-only prepares the datasets and computes no cell: give it without --finished-only, "
                          "--recompute-dirty and --dry-run")
    protocol = _check(methods, categories, protocol, None if dry_run else work_dir,
                      None if dry_run else out_dir)
    if dry_run:  # the real run's folder checks, without creating anything
        for folder, what in ((work_dir, "--work"), (archive, "--archive"), (out_dir, "--out")):
            if folder is not None and any(p.exists() and not p.is_dir() for p in (Path(folder), *Path(folder).parents)):
                raise ConfigError(f"{what} {folder} is (or is inside) a file, not a folder; give a folder")
        if budget_minutes is not None:
            try:
                cells, _, _ = budget_cells(cells, budget_minutes, work_dir, instances, views, data_seed,
                                           data_kwargs, measure=False)
            except ConfigError as exc:
                print(f"(the budget's schedules are not known yet: {exc})")
        rows = plan(cells, work_dir, instances, views, data_seed, protocol, recompute_dirty, archive, data_kwargs)
        print_plan(rows)
        return rows
    if archive is not None:
        check_output_dir(archive, "cells archive")
    here = git_commit()
    if dirty_sha(here) and not allow_dirty:
        raise ConfigError(f"this checkout has uncommitted changes (commit {here}): cells computed or scored now could "
                          "not be traced to a commit; commit first (or run the bench from a worktree of a commit: git "
                          "worktree add), or pass --allow-dirty")
    schedules, plans = None, None
    if budget_minutes is not None:  # the datasets first: the schedules come from speeds measured on them
        if not finished_only:
            _compute(cells, work_dir, instances, views, data_seed, protocol, workers, cache_dir, progress, device,
                     False, data_kwargs, False, category_data, archive, True, archive_predictions)
        cells, schedules, plans = budget_cells(cells, budget_minutes, work_dir, instances, views, data_seed,
                                               data_kwargs, measure=not finished_only, archive=archive)
        if data_only:
            return []
    results, records, hashes, done, missing = _compute(cells, work_dir, instances, views, data_seed, protocol,
                                                       workers, cache_dir, progress, device, finished_only,
                                                       data_kwargs, recompute_dirty, category_data, archive,
                                                       data_only, archive_predictions, plans)
    if out_dir is not None and not data_only:
        check_commits(done, records, allow_dirty, allow_mixed_commits)
        kw = data_kwargs or SYNTHETIC_DATA
        prov = _provenance(title, done, records, hashes, instances, views, data_seed, protocol, preset, missing,
                           random_rotation=bool(kw.get("random_rotation", False)),
                           viewpoints=viewpoints_of(kw),
                           train_views=int(kw.get("train_views") or 0), parts_alone=bool(kw.get("parts_alone")))
        if schedules is not None:
            prov["training_budget"] = {"core_minutes_per_run": budget_minutes, "schedules": schedules,
                                       "speeds": f"{work_dir}/speeds/"}
        for p in write(results, done, prov):
            print(f"wrote {p}")
    return results


def check_commits(done: Sequence[Cell], records: Sequence[dict], allow_dirty: bool = False,
                  allow_mixed_commits: bool = False) -> dict[str, dict[str, list[str]]]:
    """The commits behind a table's cells: ``{"computed": {commit: cells}, "scored": {commit: cells}}``, the code that
    trained and predicted each cell (:func:`computed_commit`) and the code that scored it (the same, or a later one
    when only the evaluator changed since); a cell is named ``"<key>/<category>"``.

    Raises:
        ConfigError: a cell from a checkout with uncommitted changes (``-dirty`` or unknown) without
            ``allow_dirty``, or cells computed (or scored) at several commits, or trained cells charged in
            core-seconds of several kinds of CPU (``provenance.cpu_kind``: a core-second of one kind buys other steps
            than one of another, :func:`scapo.bench.ladder.check_one_commit`), without ``allow_mixed_commits``; the
            message names the cells of each commit or kind.
    """
    out: dict[str, dict[str, list[str]]] = {"computed": {}, "scored": {}}
    kinds: dict[str, list[str]] = {}
    for c, rec in zip(done, records):
        name = f"{c.key}/{c.category}"
        out["computed"].setdefault(computed_commit(rec), []).append(name)
        out["scored"].setdefault(str(rec.get("provenance", {}).get("commit", "unknown")), []).append(name)
        if (rec.get("ledger") or {}).get("unit") == "core-seconds":
            kinds.setdefault(str(rec.get("provenance", {}).get("cpu_kind", "kind not recorded")), []).append(name)

    def listing(group: dict[str, list[str]], shas) -> str:
        return "; ".join(f"{sha[:16]}: {', '.join(group[sha][:6])}"
                         + (f" and {len(group[sha]) - 6} more" if len(group[sha]) > 6 else "") for sha in shas)

    for what, group in out.items():
        dirty = [sha for sha in group if dirty_sha(sha)]
        if dirty and not allow_dirty:
            raise ConfigError(f"cells of this table were {what} from uncommitted code ({listing(group, dirty)}); "
                              "compute them again at a commit (--recompute-dirty) or pass --allow-dirty")
        if len(group) > 1 and not allow_mixed_commits:
            raise ConfigError(f"the cells of this table were {what} at {len(group)} commits ({listing(group, group)});"
                              " make every cell at one commit (run the bench from a worktree of it, after setting the "
                              "others' records aside) or pass --allow-mixed-commits (the provenance lists each cell's "
                              "commit)")
    if not allow_mixed_commits:
        from scapo.bench.ladder import check_one_kind

        check_one_kind(kinds)
    return out


def _figures(cells, results, work, instances, views, data_seed, protocol, out_dir, name,
             data_kwargs=None) -> list[Path]:
    """Per category: test views with ground truth and each method's output (its lowest training seed);
    one figure of the error distributions of every cell."""
    from scapo.bench.viz import error_distribution_figure, methods_figure
    from scapo.eval import Predictions

    paths = []
    for cat in dict.fromkeys(c.category for c in cells):
        data = dataset_dir(work, cat, instances, views, data_seed, data_kwargs)
        preds, absent = {}, []
        for c in sorted((c for c in cells if c.category == cat), key=lambda c: -1 if c.seed is None else c.seed):
            path = cell_paths(data, c, protocol).predictions
            if c.label not in preds and path.is_file():
                preds[c.label] = Predictions.load(path)
            elif not path.is_file():
                absent.append(c.key)
        if absent:  # restored from an archive kept without predictions: the figure shows the rows it can
            print(f"{cat}: no predictions for {', '.join(absent)} (restored without them); the figure of test "
                  "views leaves them out", flush=True)
        if preds:
            paths.append(methods_figure(data, preds, Path(out_dir) / f"{name}_{cat}.png",
                                        names={k: (describe(k) or (k,))[0] for k in preds}))
    paths.append(error_distribution_figure(results, Path(out_dir) / f"{name}_errors.png",
                                           names={r.method: (describe(r.method) or (r.method,))[0] for r in results}))
    return paths


#: The tables that get the at-a-glance figure (``<name>_summary.png``, :func:`scapo.bench.viz.summary_figure`) with
#: the paper's values marked (:func:`scapo.eval.tables.paper_values`): Table 2's paper columns are other metrics.
SUMMARY_TABLES = ("table1", "table3")


def summary_paper_rows(table: str, labels: Sequence[str]) -> dict[str, str]:
    """Our row labels -> the paper's row of ``table`` (:func:`scapo.eval.tables.paper_values`): Table 1, a method's
    ``paper_row`` (:class:`scapo.methods.registry.MethodEntry`; one-pass rows only: a ``+refine`` row is not the
    paper's method); Table 3, the ablation's variant (:data:`scapo.eval.tables.TABLE3_VARIANTS`)."""
    from scapo.eval.tables import TABLE3_VARIANTS

    if table == "table3":
        return {k: TABLE3_VARIANTS[k][0] for k in labels if k in TABLE3_VARIANTS}
    return {k: METHODS.get(k).paper_row for k in labels if k in METHODS and METHODS.get(k).paper_row}


def _with_summary(write, table: str, out_dir, name: str):
    """``write`` followed by the table's at-a-glance figure of the test-split results (``<name>_summary.png``)."""
    def write_all(results, done, prov):
        from scapo.bench.viz import summary_figure
        from scapo.eval.tables import TABLE3_VARIANTS, paper_values

        paths = write(results, done, prov)
        test = [r for r in results if r.split == "test"]
        if test:
            labels = list(dict.fromkeys(r.method for r in test))
            cats = list(dict.fromkeys(r.category for r in test))
            names = ({k: TABLE3_VARIANTS[k][1] for k in labels if k in TABLE3_VARIANTS} if table == "table3" else
                     {k: (describe(k) or (k,))[0] for k in labels})
            paths.append(summary_figure(test, Path(out_dir) / f"{name}_summary.png", names=names,
                                        paper=paper_values(table, summary_paper_rows(table, labels), cats)))
        return paths

    return write_all


#: The paper's Table 2 categories (OP-Align's real data), rendered from our procedural objects.
TABLE2_CATEGORIES = ("basket", "drawer", "laptop", "scissors", "suitcase")
#: Trained methods that also get a semi-supervised row ("SJ", as the paper's Table 2 trains OP-Align and SCAPO).
TABLE2_SJ_METHODS = ("op-align", "scapo")


def table2_cells(methods: Sequence[str], categories: Sequence[str], preset: str, seeds: Sequence[int],
                 category_seeds: dict[str, list[int]] | None = None, sj: bool = True,
                 sj_methods: Sequence[str] = TABLE2_SJ_METHODS, refine_rows: bool = True) -> list[Cell]:
    """Table 1's cells of ``methods`` (with their ``+refine`` rows unless ``refine_rows`` is False) plus, with
    ``sj``, the semi-supervised rows ``<method>-sj`` (preset ``<preset>/sj``) of the methods in ``sj_methods``
    among them."""
    cells = table1_cells(methods, categories, preset, seeds, category_seeds, refine_rows)
    if sj:
        for cat in categories:
            for m in methods:
                if m in sj_methods:
                    p = method_preset(m, f"{preset}/sj")
                    cells += [Cell(m, cat, int(s), p, label=f"{m}-sj")
                              for s in (category_seeds or {}).get(cat, seeds)]
    return cells


@dataclass(frozen=True)
class TableSpec:
    """One of the paper's tables as the bench makes it: which cells, on which data, scored how, written how.

    Attributes:
        key: ``scapo bench KEY``. name: default file stem in the table folder. title: the provenance's title.
        categories: default categories, in the table's column order. protocol: default evaluation protocol.
        writer: the :mod:`scapo.eval.tables` function that writes it (``write_table1`` ...). figures: also write
            per-category figures and the error distributions.
        data: dataset settings beyond Table 1's (:func:`~scapo.data.make_config` keywords), per category in
            ``category_data``. sj_methods: trained methods that also get a semi-supervised row (``--no-sj`` drops
            them). ablation_of: the method whose ablations (its entry's ``ablations``) are the rows; the table
            then takes no ``--methods``.
    """

    key: str
    name: str
    title: str
    categories: tuple[str, ...]
    protocol: str
    writer: str
    figures: bool = True
    data: Mapping[str, object] = field(default_factory=dict)
    category_data: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    sj_methods: tuple[str, ...] = ()
    ablation_of: str | None = None
    viewpoints: str = "paper"
    """The default ``--viewpoints`` setting (:data:`VIEWPOINT_DATA`; Table 2's data, ``data``, is upright: real
    scans are natural views, and it takes no other setting)."""

    def cells(self, methods: Sequence[str], categories: Sequence[str], opts: BenchOptions) -> list[Cell]:
        """The table's cells for ``methods`` (ignored for an ablation table) and ``categories``."""
        seeds, per = opts.seeds, opts.category_seeds
        if self.ablation_of is not None:
            return table3_cells(categories, opts.preset, seeds, per, opts.ablations, method=self.ablation_of)
        if self.sj_methods:
            return table2_cells(methods, categories, opts.preset, seeds, per, opts.sj, self.sj_methods,
                                opts.refine_rows)
        return table1_cells(methods, categories, opts.preset, seeds, per, opts.refine_rows, opts.parts,
                            opts.option_rows)


@dataclass(frozen=True)
class BenchOptions:
    """How a bench runs (:func:`run_table`): the data drawn (``instances`` x ``views`` per category, assets,
    splits and views from ``data_seed``), the training preset and seeds (``category_seeds``: category -> seeds,
    overriding ``seeds``), where it works and writes, and what it does (``dry_run``: list the cells only;
    ``finished_only``: compute nothing, write the done cells' tables; ``recompute_dirty``: compute again the cells
    computed from uncommitted code). ``protocol`` and ``name`` default to the table's; ``sj`` keeps the
    semi-supervised rows; ``ablations`` limits an ablation table's rows."""

    instances: int = 150
    views: int = 8
    data_seed: int = 0
    work_dir: Path = Path("bench_work")
    out_dir: Path | None = None
    preset: str = "cpu"
    seeds: Sequence[int] = (0,)
    category_seeds: Mapping[str, Sequence[int]] | None = None
    protocol: str | None = None
    workers: int = 1
    cache_dir: Path | None = None
    name: str | None = None
    dry_run: bool = False
    progress: bool = True
    device: str | None = None
    figures: bool = True
    finished_only: bool = False
    recompute_dirty: bool = False
    sj: bool = True
    ablations: Sequence[str] | None = None
    upright: bool = False
    """``viewpoints="upright"`` (its older spelling)."""
    viewpoints: str | None = None
    """Tables 1 and 3 (:data:`VIEWPOINT_DATA`): ``paper`` (the default: EAP's views, which the paper follows,
    ``PAPER_TRAIN_VIEWS`` views per training instance), ``sphere`` (whole sphere: objects under uniform SO(3) rotations,
    harder than the paper; the tables before the paper's viewpoints existed) or ``upright`` (the category's view
    ranges: a diagnostic of how much of the errors the rotation accounts for). The paper's datasets are named
    ``..._paper``; the whole sphere's keep the older names in ``work_dir`` and the upright ones theirs in
    ``<work_dir>/upright/``; the table is ``<name>`` for the paper's setting and ``<name>_sphere`` /
    ``<name>_upright`` otherwise; the provenance names the setting. Table 2 (upright: real scans are natural views)
    refuses the others."""
    train_views: int | None = None
    """Views per training instance (None: ``PAPER_TRAIN_VIEWS`` for the paper's viewpoints, ``views`` otherwise)."""
    parts_alone: bool = False
    """Tables 1 and 3: every part rendered in a scene of its own (:attr:`~scapo.sim.render.RenderConfig.parts_alone`,
    EAP's data regime: no part hides another), a labelled variant of the chosen viewpoints; the table is
    ``<name>_parts_alone`` (after the viewpoints' suffix), its datasets ``..._parts``. Table 2 refuses it."""
    parts: Sequence[str] = ()
    """Table 1: extra rows ``METHOD/PART`` (:func:`table1_cells`), e.g. ``scapo/principal``: the method trained with
    its preset's part ``PART``, labelled ``<method>-<PART>``."""
    option_rows: Sequence[str] = ()
    """Table 1: extra rows ``METHOD:LABEL:KEY=VALUE[,...]`` (:func:`table1_cells`), e.g.
    ``scapo:base-frame:base_frame=principal``: the method's own runs predicted with those options, labelled
    ``<method>-<LABEL>``."""
    refine_rows: bool = True
    """Tables 1 and 2: a ``<method>+refine`` row (:mod:`scapo.steps.refine`) beside the one-pass row of every
    method with a whole-object model (``MethodEntry.refinable``)."""
    allow_dirty: bool = False
    """Compute or score cells from a checkout with uncommitted changes, and write tables holding such cells (their
    records say ``<sha>-dirty``: the code behind them cannot be recovered); refused otherwise."""
    allow_mixed_commits: bool = False
    """Write a table whose cells were computed at several commits (the provenance lists each cell's); refused
    otherwise, naming the cells of each commit."""
    archive: Path | None = None
    """A cells archive (:mod:`scapo.bench.archive`): every done cell's small files (record with its predictions'
    sha256, per-sample metrics, the run's identity and timing) are copied there, and the archived cells of a dataset are
    restored into the work folder once the dataset is generated (same dataset hash only), so that a work folder lost
    with its machine costs only the datasets. The archive also pins each dataset's bytes: a dataset generated on
    another kind of CPU, which differs from the pinned one only by the rounding of double-precision ground truth, is
    made the pinned one before its cells are restored. An upright bench uses ``<archive>/upright/``."""
    archive_predictions: bool = False
    """With ``archive``, also keep each cell's predictions there (xz-compressed; restored byte for byte). Without them
    (the default: they are most of an archive's size, and reproducible from the commit, the dataset and the seed) a
    restored cell is scored and tabled from its record and per-sample metrics; a cell whose record the evaluator no
    longer accepts is then computed again, and the tables' per-category figures of predictions are left out."""
    budget_minutes: float | None = None
    """The equal training budget (:func:`budget_cells`): every trained cell trains for the epochs that fill this many
    core-minutes of one CPU core on its dataset (its preset named ``<preset>/epochs-...``); None: the presets' own
    schedules."""
    data_only: bool = False
    """Generate the datasets (with ``archive``: reconcile, pin, restore their cells) and compute no cell; writes
    no table. Prepares a work folder whose cells are computed by another checkout (a clean worktree of the commit)."""


#: The paper's tables: ``scapo bench table1|table2|table3``.
TABLES: Registry[TableSpec] = Registry("table")
TABLES.add("table1", TableSpec("table1", "table1_synthetic", "scapo bench table1", TABLE1_CATEGORIES, "scapo",
                               "write_table1"))
TABLES.add("table2", TableSpec("table2", "table2_real_style", "scapo bench table2", TABLE2_CATEGORIES, "op-align",
                               "write_table2", data=REAL_STYLE_DATA, category_data=REAL_STYLE_CATEGORY_DATA,
                               sj_methods=TABLE2_SJ_METHODS, viewpoints="upright"))
TABLES.add("table3", TableSpec("table3", "table3_ablation", "scapo bench table3", ("laptop", "eyeglasses"), "scapo",
                               "write_table3", figures=False, ablation_of="scapo"))


def run_table(table: str | TableSpec, methods: Sequence[str] | None = None, categories: Sequence[str] | None = None,
              **options):
    """Make one of the paper's tables (:data:`TABLES`): its cells computed one by one (resumable; a finished cell
    is never recomputed), then written from the cells' records (``<name>.{csv,md,tex,json}`` and, for Tables 1
    and 2, figures) into ``out_dir``. ``methods`` default to every registered method in the paper's row order
    (:func:`table_methods`), ``categories`` to the table's; ``options`` are :class:`BenchOptions` fields.

    Returns:
        The plan rows with ``dry_run`` (nothing is computed or written), else the test-split
        :class:`~scapo.eval.EvalResult` of every cell (of every done cell with ``finished_only``).

    Raises:
        ConfigError / UnknownNameError: unknown table, method, category, preset, protocol or option; bad seeds;
        ``--methods`` for an ablation table (all refused before any dataset is rendered). OutputError:
        unwritable work or table folder.
    """
    from scapo.eval import tables as writers

    spec = TABLES.get(table) if isinstance(table, str) else table
    unknown = sorted(set(options) - {f.name for f in fields(BenchOptions)})
    if unknown:
        raise ConfigError(f"unknown bench option(s) {', '.join(unknown)}; known: "
                          f"{', '.join(f.name for f in fields(BenchOptions))}")
    opts = BenchOptions(**options)
    if opts.archive_predictions and opts.archive is None:
        raise ConfigError("--archive-predictions keeps predictions in a cells archive: give --archive DIR too")
    data = spec.data or None
    if opts.upright and opts.viewpoints not in (None, "upright"):
        raise ConfigError(f"--upright is --viewpoints upright; it contradicts --viewpoints {opts.viewpoints}")
    viewpoints = "upright" if opts.upright else opts.viewpoints
    if viewpoints is not None and viewpoints not in VIEWPOINT_DATA:
        raise ConfigError(f"unknown viewpoints {viewpoints!r}; known: {', '.join(VIEWPOINT_DATA)}")
    if opts.train_views is not None and (isinstance(opts.train_views, bool) or int(opts.train_views) < 1):
        raise ConfigError(f"--train-views must be >= 1, got {opts.train_views}")
    if spec.data:  # Table 2: its own (upright) data
        if viewpoints not in (None, spec.viewpoints) or opts.train_views is not None or opts.parts_alone:
            raise ConfigError(f"bench {spec.key}'s views are upright (real scans are natural views) under the "
                              "realistic sensor; --viewpoints, --upright, --train-views and --parts-alone are for "
                              "Tables 1 and 3")
    else:
        viewpoints = viewpoints or spec.viewpoints
        data = dict(VIEWPOINT_DATA[viewpoints])
        if opts.train_views is not None:
            data["train_views"] = int(opts.train_views)
        if viewpoints == "upright":
            opts = replace(opts, work_dir=Path(opts.work_dir) / "upright", name=opts.name or f"{spec.name}_upright",
                           archive=None if opts.archive is None else Path(opts.archive) / "upright")
        elif viewpoints == "sphere":
            opts = replace(opts, name=opts.name or f"{spec.name}_sphere")
        if opts.parts_alone:
            data["parts_alone"] = True
            opts = replace(opts, name=opts.name or (f"{spec.name}_parts_alone" if viewpoints == "paper"
                                                    else f"{spec.name}_{viewpoints}_parts_alone"))
    if spec.ablation_of is not None:
        if methods and list(methods) != [spec.ablation_of]:
            raise ConfigError(f"bench {spec.key} is {spec.ablation_of}'s ablation; it takes no --methods")
        methods = [spec.ablation_of]
    methods = list(methods) if methods else table_methods()
    categories = list(categories) if categories else list(spec.categories)
    for what, names in (("--methods", methods), ("--categories", categories), ("--seeds", list(opts.seeds))):
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ConfigError(f"{what} names {', '.join(map(str, twice))} more than once; give each once")
    if opts.parts and spec.key != "table1":
        raise ConfigError(f"--part adds rows to bench table1; bench {spec.key} takes none")
    if opts.option_rows and spec.key != "table1":
        raise ConfigError(f"--option-row adds rows to bench table1; bench {spec.key} takes none")
    name = opts.name or spec.name
    cells = spec.cells(methods, categories, opts)
    if opts.progress or opts.dry_run:  # the data setting, said wherever the bench prints
        kw = data or {}
        vp = viewpoints_of(kw)
        tv = int(kw.get("train_views") or 0)
        print(f"scapo bench {spec.key}: viewpoints {vp}: {VIEWPOINT_LABELS[vp]}"
              + ("; every part rendered alone (EAP's data regime)" if kw.get("parts_alone") else "")
              + f"; {opts.instances} instances, "
              f"{tv or opts.views} views per training instance, {opts.views} per val/test instance; data seed "
              f"{opts.data_seed}", flush=True)
    write_table = getattr(writers, spec.writer)
    if spec.figures:
        write = _writer(write_table, name, opts.out_dir, opts.figures, opts.work_dir, opts.instances, opts.views,
                        opts.data_seed, data)
    else:
        def write(results, done, prov):
            return write_table(results, opts.out_dir, prov, name=name)
    if spec.key in SUMMARY_TABLES and opts.figures:
        write = _with_summary(write, spec.key, opts.out_dir, name)
    return _bench(spec.title, cells, methods, categories, write, opts.instances, opts.views, opts.data_seed,
                  opts.work_dir, opts.out_dir, opts.preset, opts.protocol or spec.protocol, opts.workers,
                  opts.cache_dir, opts.dry_run, opts.progress, opts.device, opts.finished_only, data,
                  opts.recompute_dirty, spec.category_data or None, opts.allow_dirty, opts.allow_mixed_commits,
                  opts.archive, opts.data_only, opts.archive_predictions, opts.budget_minutes)


def run_table1(methods: Sequence[str], categories: Sequence[str] = TABLE1_CATEGORIES, **options):
    """Table 1 on our synthetic data (:func:`run_table` with :data:`TABLES` ``table1``): every method x category
    x training seed under ``protocol`` (default ``scapo``), in the paper's layout with the robust statistics
    (:func:`scapo.eval.tables.write_table1`), per category a figure of test views and one of the error
    distributions."""
    return run_table("table1", methods, categories, **options)


def run_table2(methods: Sequence[str], categories: Sequence[str] = TABLE2_CATEGORIES, **options):
    """The paper's Table 2 in real-world style (:func:`run_table` with ``table2``): OP-Align's real-scan
    categories rendered from our procedural objects with the realistic sensor (:mod:`scapo.sim.sensor`; cropped
    views rejected), every method and, with ``sj``, the semi-supervised rows of OP-Align-style and SCAPO, under
    ``protocol`` (default ``op-align``); use its own work folder (the datasets differ from Table 1's)."""
    return run_table("table2", methods, categories, **options)


def run_table3(categories: Sequence[str] = ("laptop", "eyeglasses"), **options):
    """The paper's Table 3 (:func:`run_table` with ``table3``): SCAPO full and without each of L_shape-var,
    L_dir-align, L_joint-prox, L_joint-boundary (or ``ablations``), per category and training seed
    (:func:`scapo.eval.tables.write_table3`); sharing Table 1's work folder reuses its SCAPO cells."""
    return run_table("table3", None, categories, **options)
