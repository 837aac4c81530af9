"""Throughput benchmarks (``scapo bench perf``); each reports a reference measured in the same run.

``generate``: samples/s of ``scapo generate`` (the real command, into a temporary directory) next
to the bare SAPIEN render-only rate on the same objects and viewpoint distribution with the same
number of worker processes: per frame only ``set_qpos``, camera pose, ``update_render``,
``take_picture`` and ``get_picture`` of ``Position`` and ``Segmentation``. Their ratio shows how
close generation comes to the renderer's limit. Rates are steady-state: from the first shard's
start to the last shard's end, excluding process start-up and asset building.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import tempfile
import time
from pathlib import Path

import numpy as np

from scapo.data.config import make_config
from scapo.data.generate import _POOL_WORKER, ShardWorker, _pool_init, generate, plan, sample_seed_key
from scapo.files import atomic_write_text, check_output_dir
from scapo.ops.rigid import sapien_camera_pose
from scapo.provenance import provenance, render_device
from scapo.registry import schedule_fields
from scapo.report import markdown_table
from scapo.sim.assets import build_category
from scapo.sim.render import sample_camera_pose, sample_state


def _bare_render_shard(worker: ShardWorker, task) -> tuple[float, float, int]:
    cfg = worker.cfg
    r = worker.renderer
    view = cfg.view_config
    import sapien

    t0 = time.time()
    for _, inst, vid in task.items:
        spec = worker.spec(inst)
        rng = np.random.default_rng((*sample_seed_key(cfg, inst, vid), 0))
        state = sample_state(spec, rng)
        T = sample_camera_pose(view, spec.bbox_diag, rng)
        r.load(spec)
        r.set_state(state)
        r.camera.set_entity_pose(sapien.Pose(sapien_camera_pose(T)))
        r.scene.update_render()
        r.camera.take_picture()
        r.camera.get_picture("Position")
        r.camera.get_picture("Segmentation")
    return t0, time.time(), len(task.items)


def _warm(_):
    return _POOL_WORKER[0].ready()


def _pool_bare(task):
    return _bare_render_shard(_POOL_WORKER[0], task)


def render_only_rate(cfg, workers: int, cache_dir=None) -> float:
    """Steady-state bare SAPIEN frames/s over the same plan as ``generate`` (see module doc)."""
    records = build_category(cfg.category, cfg.instances, cfg.seed, cache_dir)
    urdfs = {r.instance_id: str(r.urdf) for r in records}
    tasks = plan(cfg)
    args = (cfg.to_json(), urdfs)
    if workers <= 1:
        worker = ShardWorker(*args)
        worker.ready()
        res = [_bare_render_shard(worker, t) for t in tasks]
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_pool_init, initargs=(args, None)) as pool:
            pool.map(_warm, range(workers * 4))
            res = pool.map(_pool_bare, tasks, chunksize=1)
    t0, t1 = min(r[0] for r in res), max(r[1] for r in res)
    return sum(r[2] for r in res) / (t1 - t0)


def bench_generate(category: str = "laptop", instances: int = 20, views: int = 30, workers=(1, 2), seed: int = 0,
                   cache_dir=None, repeats: int = 1) -> list[dict]:
    """Measure generation and bare-render throughput for each worker count; returns one row each.

    Besides the reference with the generator's own shader ("trivial": positions and segmentation
    only), the bare render rate with SAPIEN's "default" shader (which also shades colour) is
    reported for context.
    """
    cfg = make_config(category, instances, views, seed)
    cfg_default = make_config(category, instances, views, seed, shader="default")
    build_category(category, instances, seed, cache_dir)  # not timed
    rows = []
    for w in workers:
        best_ro, best_gen, best_e2e, best_def = 0.0, 0.0, 0.0, 0.0
        for _ in range(repeats):
            best_ro = max(best_ro, render_only_rate(cfg, w, cache_dir))
            best_def = max(best_def, render_only_rate(cfg_default, w, cache_dir))
            with tempfile.TemporaryDirectory(prefix="scapo-perf-") as tmp:
                t = time.perf_counter()
                rep = generate(cfg, Path(tmp) / "ds", workers=w, progress=False, cache_dir=cache_dir)
                e2e = rep.samples / (time.perf_counter() - t)
            best_gen = max(best_gen, rep.steady_samples_per_second)
            best_e2e = max(best_e2e, e2e)
        rows.append({
            "category": category,
            "workers": w,
            "samples": cfg.instances * cfg.views,
            "image": f"{cfg.render.camera.width}x{cfg.render.camera.height}",
            "num_points": cfg.render.num_points,
            "shader": cfg.render.shader,
            "generate_samples_per_s": round(best_gen, 2),
            "render_only_frames_per_s": round(best_ro, 2),
            "ratio": round(best_gen / best_ro, 3),
            "generate_end_to_end_samples_per_s": round(best_e2e, 2),
            "render_only_default_shader_frames_per_s": round(best_def, 2),
        })
    return rows


def write_perf(rows: list[dict], out_dir: Path, name: str, **prov) -> list[Path]:
    """Write ``<name>.csv``, ``<name>.md`` and ``<name>.json`` (rows + provenance) into ``out_dir``."""
    import pandas as pd

    out_dir = check_output_dir(out_dir, "benchmark output folder")
    p = provenance(render_device=render_device(), **prov)
    df = pd.DataFrame(rows)
    paths = [out_dir / f"{name}.csv", out_dir / f"{name}.md", out_dir / f"{name}.json"]
    atomic_write_text(paths[0], df.to_csv(index=False))
    md = [f"# {name}", "", markdown_table(list(df.columns), df.astype(str).values.tolist()), "",
          "Provenance: " + ", ".join(f"{k}={v}" for k, v in p.items())]
    atomic_write_text(paths[1], "\n".join(md) + "\n")
    atomic_write_text(paths[2], json.dumps({"rows": rows, "provenance": p}, indent=1) + "\n")
    return paths


def compare_train(rows: list[dict], baseline: str | Path) -> tuple[list[dict], dict]:
    """Speed-up of ``--what train`` rows over an earlier run's JSON (``scapo bench perf --what train --baseline
    FILE``): each row of the same method and preset gains, per stage, ``<stage>_before`` (the baseline's clouds/s)
    and ``<stage>_speedup`` (now / before); also returns the baseline's provenance under ``baseline_*`` keys
    (commit, time, device) for the output's provenance. Compare runs from the same idle machine and threads.

    Raises:
        ConfigError: an unreadable or malformed baseline file, or one with other threads or batch sizes (a
        different measurement, not a before/after)."""
    from scapo.errors import ConfigError

    try:
        data = json.loads(Path(baseline).read_text())
        before = {(r["method"], r["preset"]): r for r in data["rows"]}
        prov = data.get("provenance", {})
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"cannot read the baseline {baseline} ({e}); give the .json that an earlier "
                          "'scapo bench perf --what train --out DIR' wrote") from None
    out = []
    for r in rows:
        b = before.get((r["method"], r["preset"]))
        r = dict(r)
        if b is not None:
            for k in ("threads", "batch_size", "points"):
                if k in b and b[k] != r.get(k):
                    raise ConfigError(f"baseline {baseline}: {r['method']} was timed with {k}={b[k]}, now {r.get(k)}; "
                                      "a before/after comparison needs the same setting")
            for k in [k for k in r if k.endswith("_clouds_per_s")]:
                if k in b:
                    r[f"{k}_before"] = b[k]
                    r[f"{k}_speedup"] = round(r[k] / b[k], 2) if b[k] else float("nan")
        out.append(r)
    return out, {f"baseline_{k}": prov[k] for k in ("commit", "time", "device") if k in prov}


def bench_train_data(data: str | Path, methods=None, preset: str = "cpu", steps: int = 20,
                     work: str | Path | None = None, device: str | None = None, sets: dict | None = None
                     ) -> list[dict]:
    """Training speed on a real dataset through the engine, as a table cell trains (``scapo bench perf --what train
    --data DATASET``): each trained method's ``preset`` trains for two epochs of ``steps`` steps per stage on the
    training split in a fresh run folder under ``work`` (default: a temporary folder), and the engine's record of
    where the compute went (``timing.json``'s ledger, :mod:`scapo.engine.ledger`: charged core-seconds, or seconds of
    an accelerator) gives per stage the clouds/s of its steps (``stage<k>_clouds_per_s``) and the charged seconds
    each epoch adds around them (``stage<k>_epoch_s``: checkpoint, loss plot), and the run's one-time charged seconds
    (``fixed_s``, by phase in ``one_time_s``: set-up, stage starts such as SCAPO's stage-2 initialisation, the work
    after the last epoch such as EAP-style's joint estimation, the rest of the session), with the preset's schedule,
    for :func:`training_budget`; on a CPU, ``wall_per_cpu``: the steps' wall over CPU seconds (about 1 when the run had
    its core; more when other processes took it, which also slows each step's CPU time: see
    :data:`scapo.bench.ladder.MAX_WALL_PER_CPU`), and ``steps_cpu_s``, those CPU seconds. Needs ``steps * batch_size``
    training clouds. Measure as the cells run (one torch thread per core, the other core busy with the other chain).
    ``device`` (default: the preset's, the CPU for the ``cpu`` presets) trains on that torch device (e.g. ``cuda``): its
    clouds/s there, for a budget in minutes of that device. ``sets``: preset fields replaced first (``scapo train
    --set`` keys; a ladder variant).

    Raises:
        UnknownNameError: an unknown method or preset. ConfigError: a method that is not trained, ``steps < 2``,
        a training split too small for ``steps`` batches. DatasetError: an unreadable dataset."""
    import tempfile

    import torch

    from scapo.config import override
    from scapo.data.dataset import load
    from scapo.engine.ledger import one_time_s
    from scapo.errors import ConfigError
    from scapo.methods import METHODS, train_method
    from scapo.provenance import cpu_kind

    if steps < 2:
        raise ConfigError(f"--steps must be >= 2, got {steps}")
    names = list(methods) if methods else [m for m in METHODS.names() if METHODS.get(m).trained]
    for m in names:
        if not METHODS.get(m).trained or METHODS.get(m).preset is None:
            raise ConfigError(f"method {m!r} is not trained; --what train times: "
                              f"{', '.join(n for n in METHODS.names() if METHODS.get(n).trained)}")
    clouds = len(load(data, "train"))
    root = Path(work) if work is not None else Path(tempfile.mkdtemp(prefix="scapo_train_speed_"))
    rows = []
    for m in names:
        base = METHODS.get(m).preset(preset)
        if sets:
            base = override(base, sets, f"{m} preset")
        fields = schedule_fields(base)
        batch = base.batch_size
        if clouds < steps * batch:
            raise ConfigError(f"{data}: {clouds} training clouds, fewer than the {steps * batch} that {steps} "
                              f"steps of {batch} need; give a larger dataset or a smaller --steps")
        values = {"max_steps_per_epoch": steps}
        values.update({f: 2 for f in fields})
        if hasattr(base, "iterations"):
            values["iterations"] = 0
        run = root / f"{m}_{preset.replace('/', '-')}"
        train_method(m, data, run, override(base, values, f"{m} preset"), progress=False, device=device)
        timing = json.loads((run / "timing.json").read_text())
        row = {"method": m, "preset": preset, "batch_size": batch,
               "points": getattr(base, "train_points", getattr(base, "points", None))}
        ledger = timing["ledger"]  # charged seconds by phase (scapo.engine.ledger)
        for k, part in sorted(timing["stages"].items()):
            steps_s = float(ledger["phases"].get(f"stage{k}/steps", {}).get("charged_s", 0.0))
            epochs_s = float(ledger["phases"].get(f"stage{k}/epochs", {}).get("charged_s", 0.0))
            row[f"stage{k}_clouds_per_s"] = round(part["steps"] * batch / max(steps_s, 1e-9), 2)
            row[f"stage{k}_epoch_s"] = round(epochs_s / max(part["epochs"], 1), 2)
        steps = [p for n, p in ledger["phases"].items() if n.endswith("/steps")]
        if ledger.get("unit") == "core-seconds" and sum(p["cpu_s"] for p in steps) > 0:
            # wall over CPU seconds of the steps: about 1 when the process had its core, more when it waited for one
            row["wall_per_cpu"] = round(sum(p["wall_s"] for p in steps) / sum(p["cpu_s"] for p in steps), 2)
            row["steps_cpu_s"] = round(sum(p["cpu_s"] for p in steps), 2)
        one_time = {n: float(p["charged_s"]) for n, p in ledger["phases"].items()
                    if not (n.endswith("/steps") or n.endswith("/epochs"))}
        fixed = one_time_s(ledger)
        row.update({f"stage{k}_epochs": getattr(base, f) for k, f in enumerate(fields, 1)})
        if len(fields) == 1:
            row["iterations"] = base.iterations
        row.update(max_steps_per_epoch=base.max_steps_per_epoch, fixed_s=round(fixed, 1),
                   one_time_s={n: round(v, 1) for n, v in one_time.items()}, unit=ledger["unit"], train_clouds=clouds,
                   data=str(data), device=timing.get("device") or device or "cpu",
                   threads=torch.get_num_threads(), cpu_kind=cpu_kind())
        rows.append(row)
    return rows


def training_budget(rows: list[dict], minutes: float, train_clouds: int) -> list[dict]:
    """The tables' equal training budget from measured speeds (every method gets the same core-minutes): for each
    ``--what train`` row (its clouds/s per stage and its preset's schedule: ``stage<k>_epochs``,
    ``max_steps_per_epoch``, ``iterations``), the wall time of a training run on ``train_clouds`` clouds at that
    schedule (``planned_min``: ``floor(clouds / batch)`` steps per epoch, as the engine drops a last partial batch,
    capped by ``max_steps_per_epoch``; each step at the measured clouds/s) and the epochs per stage that fill
    ``minutes`` (``stage<k>_epochs_for_budget``: every stage scaled by the same factor, at least 1).
    A row's ``stage<k>_epoch_s`` and ``fixed_s`` (from :func:`bench_train_data`: the charged seconds each epoch
    adds around its steps, and the run's one-time charged seconds) are added: the epochs fill the budget less the
    one-time cost (every core-second a method spends before it can predict counts, :mod:`scapo.engine.ledger`), so a
    method with one-time work gets that work's worth of steps fewer (``steps_for_budget``: the steps per stage the
    rest of the budget buys; ``one_time_s``: the one-time seconds charged).
    The tables' cells run one torch thread per core, so measure with one thread. Rows without a schedule pass
    unchanged.

    Raises:
        ConfigError: ``minutes <= 0`` or ``train_clouds < 1``."""
    from scapo.errors import ConfigError

    if minutes <= 0 or train_clouds < 1:
        raise ConfigError(f"--budget-minutes must be > 0 and --train-clouds >= 1, got {minutes} and {train_clouds}")
    out = []
    for r in rows:
        r = dict(r)
        stages = [k for k in (1, 2) if f"stage{k}_clouds_per_s" in r and f"stage{k}_epochs" in r]
        if not stages:
            out.append(r)
            continue
        per_epoch = max(train_clouds // r["batch_size"], 1)  # the engine drops the last partial batch
        if r.get("max_steps_per_epoch"):
            per_epoch = min(per_epoch, r["max_steps_per_epoch"])
        sec_per_epoch = {k: per_epoch * r["batch_size"] / r[f"stage{k}_clouds_per_s"] + r.get(f"stage{k}_epoch_s", 0.0)
                         for k in stages}
        fixed = float(r.get("fixed_s", 0.0))
        if r.get("iterations"):  # one stage of a fixed step count
            sec = r["iterations"] * r["batch_size"] / r["stage1_clouds_per_s"]
        else:
            sec = sum(r[f"stage{k}_epochs"] * sec_per_epoch[k] for k in stages)
        r["train_clouds"], r["planned_min"] = train_clouds, round((fixed + sec) / 60, 2)
        if minutes * 60 <= fixed:
            raise ConfigError(f"{r.get('method', 'a method')}: its one-time work alone is {fixed:.0f} charged seconds, "
                              f"more than the budget of {minutes * 60:.0f}; make that work cheaper or give a larger "
                              "budget")
        if not r.get("iterations"):
            f = (minutes * 60 - fixed) / sec
            for k in stages:
                r[f"stage{k}_epochs_for_budget"] = max(1, round(r[f"stage{k}_epochs"] * f))
                r[f"stage{k}_steps_for_budget"] = r[f"stage{k}_epochs_for_budget"] * per_epoch
            r["budget_min"] = minutes
        out.append(r)
    return out


def budget_schedule(row: dict, preset, minutes: float) -> dict:
    """The preset fields that fill the budget, from a :func:`training_budget` row: the epochs of each stage
    (:func:`scapo.registry.schedule_fields`: SCAPO's ``stage1_epochs`` and ``stage2_epochs``, EAP-style's
    ``stage0_epochs`` and ``epochs``, a one-stage preset's ``epochs``), or ``iterations`` (a preset of a fixed number
    of iterations: the iterations ``minutes`` buy at the measured clouds/s, less the row's one-time seconds)."""
    if "budget_min" in row:
        return {f: row[f"stage{k}_epochs_for_budget"] for k, f in enumerate(schedule_fields(preset), 1)}
    sec = max(minutes * 60 - float(row.get("fixed_s", 0.0)), 1.0)
    return {"iterations": max(1, int(sec * row["stage1_clouds_per_s"] / row["batch_size"]))}


def bench_agreement(data: str | Path, method: str, preset: str = "cpu", steps: int = 200, seed: int = 0
                    ) -> list[dict]:
    """The compiled training step against the eager one (``scapo bench perf --what agreement``): ``method``'s
    ``preset`` trained twice on ``data`` for its first ``steps`` optimiser steps (the preset's schedule replaced: each
    stage's epochs and steps per epoch set so that the stages share ``steps`` evenly), eagerly and compiled
    (``compile``), from one seed, and the first ``steps`` logged loss totals compared step by step: the relative
    difference at the first step (float32 kernels fused differently: about 1e-7), the largest over the first 10 and
    the median and largest over all (training amplifies rounding: Adam's first updates follow the gradients' signs, so
    the two runs drift apart step by step as two runs of one seed on two CPU kinds do), the eager run's charged
    core-seconds per step
    beside the compiled one's, and the compiled run's compilation (its ``stage<k>/compile`` phases). One row per path.

    Raises:
        UnknownNameError: unknown method or preset. ConfigError: a method that is not trained, ``steps`` below the
        number of stages.
    """
    import csv

    from scapo.errors import ConfigError
    from scapo.methods import METHODS, train_method
    from scapo.registry import schedule_fields

    entry = METHODS.get(method)
    if not entry.trained:
        raise ConfigError(f"method {method!r} is not trained: nothing to compile")
    fields = schedule_fields(entry.preset(preset))
    if steps < len(fields):
        raise ConfigError(f"--steps must be at least {len(fields)} (one per training stage), got {steps}")
    pc = entry.preset(preset)
    per_stage = -(-steps // len(fields))
    from scapo.data.dataset import load

    per_epoch = max(1, len(load(data, "train")) // pc.batch_size)  # the epoch of one process
    epochs = -(-per_stage // per_epoch)
    overrides = {**{f: epochs for f in fields}, "max_steps_per_epoch": -(-per_stage // epochs), "iterations": 0}
    if not hasattr(pc, "iterations"):
        overrides.pop("iterations")
    rows, totals = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for path in ("eager", "compiled"):
            run = Path(tmp) / path
            train_method(method, data, run, preset, progress=False, seed=seed,
                         overrides={**overrides, "compile": path == "compiled"})
            with open(run / "log.csv", newline="") as f:
                totals[path] = np.array([float(r["total"]) for r in csv.DictReader(f)])
            ledger = json.loads((run / "timing.json").read_text())["ledger"]
            phases = ledger["phases"]
            step_s = sum(float(p["charged_s"]) for k, p in phases.items() if k.endswith("/steps"))
            rows.append({"method": method, "preset": preset, "path": path, "steps": len(totals[path]),
                         "charged_s_per_step": round(step_s / max(len(totals[path]), 1), 4),
                         "compile_s": round(sum(float(p["charged_s"]) for k, p in phases.items()
                                                if k.endswith("/compile")), 1)})
    n = min(len(totals["eager"]), len(totals["compiled"]), steps)
    rel = np.abs(totals["compiled"][:n] - totals["eager"][:n]) / np.maximum(np.abs(totals["eager"][:n]), 1e-12)
    for row in rows:
        row["speedup_vs_eager"] = round(rows[0]["charged_s_per_step"] / max(row["charged_s_per_step"], 1e-12), 2)
        row.update({"rel_diff_step0": float(f"{rel[0]:.3g}"), "rel_diff_max_first10": float(f"{rel[:10].max():.3g}"),
                    "rel_diff_median": float(f"{np.median(rel):.3g}"), "rel_diff_max": float(f"{rel.max():.3g}")})
    return rows


def bench_icp(data: str | Path, limit: int = 0, split: str = "val") -> list[dict]:
    """ICP's two searches (``ICPConfig.search``: "exhaustive", the reference, and "batched") on the same clouds of
    ``data``'s ``split`` (val: where a choice between them is made; the test split is for tables) in one run: ms per
    cloud, the speed-up over the reference, and what each gets under the ``scapo`` protocol, so that a speed-up is
    seen not to cost accuracy: median and mean part rotation error, the share of part rotations more than 90 deg off
    (front/back flips of near-symmetric parts, which make the median bimodal), mean S, D and C. ``limit``: only the
    first ``limit`` clouds (0: all; then only R and S are scored, the evaluator scores whole splits; otherwise also
    the symmetry-aware R and the flip rates).

    Raises:
        DatasetError: ``data`` has no such split (older datasets have no val split: give ``split="test"``)."""
    import torch

    from scapo.data.dataset import load
    from scapo.eval import evaluate
    from scapo.eval.metrics import rotation_error_deg, segmentation_iou
    from scapo.methods.icp import ICPBaseline

    test = load(data, split)
    if limit:
        test.manifest = test.manifest.iloc[:limit].reset_index(drop=True)
        test._shard, test._row = test.manifest["shard"].to_numpy(), test.manifest["row"].to_numpy()
    gt = test.arrays(["part_pose", "part_label"])
    rows, ref_ms = [], None
    for search in ("exhaustive", "batched"):
        m = ICPBaseline(search=search)
        m.fit(load(data, "train"))
        t = time.perf_counter()
        preds = m.predict(test)
        ms = 1000 * (time.perf_counter() - t) / len(test)
        preds.dataset_hash = test.dataset_hash  # as scapo predict records it: the evaluator checks it
        ref_ms = ms if ref_ms is None else ref_ms
        R = rotation_error_deg(preds.part_pose[..., :3, :3], gt["part_pose"][..., :3, :3])
        row = {"method": "icp", "search": search, "split": split, "clouds": len(test), "ms_per_cloud": round(ms, 1),
               "speedup_vs_exhaustive": round(ref_ms / ms, 2), "R_median": round(float(np.median(R)), 2),
               "R_mean": round(float(np.mean(R)), 2), "R_over_90deg": round(float(np.mean(R > 90)), 3)}
        if limit:
            row["S"] = round(100 * float(np.mean([np.nanmean(segmentation_iou(p, g, test.num_parts))
                                                  for p, g in zip(preds.part_label, gt["part_label"])])), 2)
        else:
            summary = evaluate(data, preds, split=split).summary
            row.update({k: round(summary[k], 3 if k == "C" else 2) for k in ("S", "D", "C", "R_sym_median",
                                                                             "R_sym_over90")
                        if k in summary})
        row["threads"] = torch.get_num_threads()
        rows.append(row)
    return rows


def bench_maniskill(category: str = "laptop", instances: int = 4, views: int = 32, num_envs: int | None = None,
                    seed: int = 0, cache_dir=None) -> list[dict]:
    """Samples/s of the ManiSkill3 backend (:mod:`scapo.sim.maniskill`; ``num_envs`` views per batch, default
    64 on a GPU, 1 on CPU) next to the SAPIEN backend on the same jobs (objects, seeds, render settings),
    measured in one run; the first object of each backend is loaded before timing."""
    import torch

    from scapo.sim.maniskill import ManiSkillRenderer, render_many_maniskill
    from scapo.sim.render import Renderer, render_many

    cfg = make_config(category, instances, views, seed)
    records = build_category(category, instances, seed, cache_dir)
    from scapo.sim.assets import parse_urdf

    specs = [parse_urdf(r.urdf, category=category) for r in records]
    jobs = [((i, v), specs[i], sample_seed_key(cfg, i, v)) for i in range(instances) for v in range(views)]
    num_envs = num_envs or (64 if torch.cuda.is_available() else 1)
    rows = []
    sap = Renderer(cfg.render.camera, cfg.render.shader)
    sap.load(specs[0])
    t = time.perf_counter()
    n = sum(1 for _ in render_many(sap, jobs, cfg.render, cfg.view_config))
    ref = n / (time.perf_counter() - t)
    sap.close()
    rows.append({"backend": "sapien", "category": category, "samples": n, "views_per_batch": 1,
                 "samples_per_s": round(ref, 2), "ratio_vs_sapien": 1.0})
    ms = ManiSkillRenderer(cfg.render.camera, num_envs=num_envs, shader=cfg.render.shader)
    ms.load(specs[0])
    t = time.perf_counter()
    n = sum(1 for _ in render_many_maniskill(ms, jobs, cfg.render, cfg.view_config))
    rate = n / (time.perf_counter() - t)
    ms.close()
    rows.append({"backend": "maniskill3", "category": category, "samples": n, "views_per_batch": num_envs,
                 "samples_per_s": round(rate, 2), "ratio_vs_sapien": round(rate / ref, 3)})
    return rows


def bench_growth(category: str = "laptop", sizes=(100, 1000, 10000), views: int = 10, workers: int = 1,
                 seed: int = 0, cache_dir=None) -> list[dict]:
    """How generation and evaluation time grow with the number of samples: for each size, a dataset of
    ``size / views`` instances x ``views`` views (built assets excluded from the time), then the evaluator on its
    test split with the ground truth as predictions (the evaluator's own cost, no method's). Each row has the
    seconds, seconds per sample, and the log-log slope against the previous size (1.0: linear)."""
    import math

    from scapo.data.dataset import load
    from scapo.eval import Predictions, evaluate

    rows = []
    for n in sizes:
        instances = max(2, int(math.ceil(n / views)))
        cfg = make_config(category, instances, views, seed, test_fraction=0.5, val_fraction=0.0)
        build_category(category, instances, seed, cache_dir)  # not timed
        with tempfile.TemporaryDirectory(prefix="scapo-growth-") as tmp:
            t = time.perf_counter()
            generate(cfg, Path(tmp) / "ds", workers=workers, progress=False, cache_dir=cache_dir)
            gen_s = time.perf_counter() - t
            ds = load(Path(tmp) / "ds", "test")
            a = ds.arrays()
            preds = Predictions(method="oracle", instance_id=a["instance_id"], view_id=a["view_id"],
                                split=np.full(len(ds), "test"), part_label=a["part_label"], part_pose=a["part_pose"],
                                joint_parts=a["joint_parts"], joint_type=a["joint_type"], joint_axis=a["joint_axis"],
                                joint_pivot=a["joint_pivot"], joint_state=a["joint_state"], T_cam_obj=a["T_cam_obj"],
                                needs_alignment=False, dataset_hash=ds.dataset_hash)
            t = time.perf_counter()
            evaluate(Path(tmp) / "ds", preds)
            ev_s = time.perf_counter() - t
        row = {"category": category, "samples": instances * views, "test_samples": len(ds), "workers": workers,
               "generate_s": round(gen_s, 2), "generate_ms_per_sample": round(1000 * gen_s / (instances * views), 2),
               "evaluate_s": round(ev_s, 3), "evaluate_ms_per_sample": round(1000 * ev_s / max(1, len(ds)), 3)}
        if rows and row["samples"] > rows[-1]["samples"]:
            prev = rows[-1]
            ratio = math.log(row["samples"] / prev["samples"])
            row["generate_growth_exponent"] = round(math.log(gen_s / prev["generate_s"]) / ratio, 3)
            row["evaluate_growth_exponent"] = round(math.log(ev_s / max(prev["evaluate_s"], 1e-6)) / ratio, 3)
        rows.append(row)
    return rows


def bench_method(method: str, preset: str = "cpu", device: str | None = None, data: str | Path | None = None,
                 iters: int = 5, num_points: int = 1024) -> list[dict]:
    """Inference speed of any registered method: ms per cloud at batch 1 (and clouds/s at batch 32 for
    the networks), on the given device, or on CPU and (when available) CUDA; each method times itself through
    its entry's ``speed`` hook (:class:`~scapo.methods.registry.MethodEntry`).

    Learned methods are timed with freshly initialised networks of ``preset``'s size on the
    partial-view-like box clouds of :func:`scapo.engine.speed.box_clouds` (speed does not depend on the weights
    or on what the points show), for a two-part, one-revolute-joint structure; ``scapo`` also reports its
    training samples/s per stage and its test-time refinement. ICP needs ``data``: its template is fitted on
    the training split and it is timed on the test clouds (the ground-truth segmentation it uses is the
    dataset's).

    Raises:
        UnknownNameError: unknown method or preset. ConfigError: ICP without ``data``, an unavailable
        device, or a method without inference to time.
    """
    from scapo.errors import ConfigError
    from scapo.methods import METHODS

    entry = METHODS.get(method)
    if entry.speed is None:
        raise ConfigError(f"method {method!r} has no network to time")
    return [{"method": method, **r} for r in entry.speed(preset=preset, device=device, iters=iters,
                                                          num_points=num_points, data=data)]



def bench_train(methods=None, preset: str = "cpu", device: str | None = None, iters: int = 5,
                threads: int | None = None) -> list[dict]:
    """Training speed of every trained method (``scapo bench perf --what train``; the equal training budget is made
    from it): clouds per second of one optimiser step (loss, backward, Adam step) at ``preset``'s batch size and
    training points, per training stage (SCAPO has two), on the given device (default CPU), with ``threads`` torch
    threads (default: torch's).
    Each method times itself through its entry's ``train_speed`` hook (:class:`~scapo.methods.registry.MethodEntry`:
    freshly initialised networks of the preset's size for a two-part, one-revolute-joint structure on box clouds,
    medians over ``iters`` steps after a warm-up). Compare two commits by running this at each on the same idle
    machine (the rows record the threads).

    Raises:
        UnknownNameError: an unknown method or preset. ConfigError: a method that is not trained, an unavailable
        device, ``threads < 1``.
    """
    import torch

    from scapo.errors import ConfigError
    from scapo.methods import METHODS

    names = list(methods) if methods else [m for m in METHODS.names() if METHODS.get(m).trained]
    for m in names:
        if not METHODS.get(m).trained or METHODS.get(m).train_speed is None:
            raise ConfigError(f"method {m!r} is not trained; --what train times: "
                              f"{', '.join(n for n in METHODS.names() if METHODS.get(n).trained)}")
    if threads is not None:
        if threads < 1:
            raise ConfigError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    rows = []
    for m in names:
        row = {"method": m, "preset": preset, **METHODS.get(m).train_speed(preset, device or "cpu", iters)}
        row.update(device=device or "cpu", threads=torch.get_num_threads())
        rows.append(row)
    return rows
