"""``scapo generate``: render a dataset of partial point clouds with ground truth, resumably.

The work is planned up front as shards of ``(sample_id, instance_id, view_id)`` items; every
sample's randomness is derived from ``(seed, category, instance_id, view_id, attempt)``, so the
output is identical for an identical config whatever the number of workers, and an interrupted
run resumes by skipping the shards already on disk. Each worker process owns one SAPIEN scene.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from scapo import __version__
from scapo.data.config import FORMAT_VERSION, GenerateConfig
from scapo.data.storage import (
    read_shard,
    sha256_file,
    write_json,
    write_shard,
)
from scapo.errors import ConfigError, CorruptShardError, DatasetError
from scapo.sim.assets import GENERATOR_VERSION, build_category, parse_urdf
from scapo.sim.render import Renderer, render_many


@dataclass(frozen=True)
class ShardTask:
    """One shard to render: its file name, split and ``(sample_id, instance_id, view_id)`` items."""

    name: str
    split: str
    items: tuple[tuple[int, int, int], ...]


@dataclass
class GenerateReport:
    """Summary of a ``generate`` run."""

    out: Path
    samples: int
    rendered: int
    skipped_shards: int
    rejections: Counter = field(default_factory=Counter)
    seconds: float = 0.0
    steady_seconds: float = 0.0

    @property
    def samples_per_second(self) -> float:
        """Rendered samples per second of the rendering phase (worker start-up included)."""
        return self.rendered / self.seconds if self.seconds > 0 else float("nan")

    @property
    def steady_samples_per_second(self) -> float:
        """Rendered samples per second from the first shard's start to the last shard's end."""
        return self.rendered / self.steady_seconds if self.steady_seconds > 0 else float("nan")


def split_instances(instances: int, test_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Deterministic split of instance ids into (train, test); at least one test instance if 2+ exist."""
    n_test = int(round(test_fraction * instances))
    if test_fraction > 0 and instances >= 2:
        n_test = min(max(n_test, 1), instances - 1)
    rng = np.random.default_rng([int(seed), 0x5CA90])
    test = sorted(int(i) for i in rng.choice(instances, size=n_test, replace=False)) if n_test else []
    train = [i for i in range(instances) if i not in set(test)]
    return train, test


def plan(cfg: GenerateConfig) -> list[ShardTask]:
    """All shards of a dataset, train first, samples ordered by instance then view."""
    train, test = split_instances(cfg.instances, cfg.test_fraction, cfg.seed)
    tasks, sid = [], 0
    for split, ids in (("train", train), ("test", test)):
        items = []
        for inst in ids:
            for v in range(cfg.views):
                items.append((sid, inst, v))
                sid += 1
        for k in range(0, len(items), cfg.shard_size):
            tasks.append(ShardTask(f"{split}-{k // cfg.shard_size:05d}", split, tuple(items[k:k + cfg.shard_size])))
    return tasks


def sample_seed_key(cfg: GenerateConfig, instance_id: int, view_id: int) -> tuple[int, ...]:
    """Seed tuple of one sample (the attempt number is appended when rendering)."""
    return (int(cfg.seed), zlib.crc32(cfg.category.encode()), int(instance_id), int(view_id))


# ---------------------------------------------------------------------------- workers
_WORKER: dict = {}


def _init_worker(cfg_json: str, urdfs: dict[int, str], queue) -> None:
    cfg = GenerateConfig.from_dict(json.loads(cfg_json))
    _WORKER.update(cfg=cfg, urdfs=urdfs, queue=queue, specs={},
                   renderer=Renderer(cfg.render.camera, cfg.render.shader))


def _render_shard(task: ShardTask, shard_dir: str) -> dict:
    cfg: GenerateConfig = _WORKER["cfg"]
    renderer: Renderer = _WORKER["renderer"]
    t0 = time.time()
    jobs = []
    for sample_id, inst, vid in task.items:
        spec = _WORKER["specs"].get(inst)
        if spec is None:
            spec = _WORKER["specs"][inst] = parse_urdf(_WORKER["urdfs"][inst], category=cfg.category)
        jobs.append((sample_id, spec, sample_seed_key(cfg, inst, vid)))
    samples, reasons = [], Counter()
    for _, s, r in render_many(renderer, jobs, cfg.render, cfg.view_config):
        samples.append(s)
        reasons.update(r)
        if _WORKER["queue"] is not None:
            _WORKER["queue"].put(1)
    meta = {
        "sample_id": np.array([i[0] for i in task.items]),
        "instance_id": np.array([i[1] for i in task.items]),
        "view_id": np.array([i[2] for i in task.items]),
        "attempts": np.array([s["attempts"] for s in samples]),
    }
    digest = write_shard(Path(shard_dir) / f"{task.name}.npz", samples, meta, dict(reasons))
    return {"name": task.name, "sha256": digest, "reasons": dict(reasons), "t0": t0, "t1": time.time(),
            "samples": len(samples)}


def _shard_is_complete(path: Path, task: ShardTask) -> bool:
    if not path.is_file():
        return False
    try:
        arrays = read_shard(path)
    except CorruptShardError:
        return False
    return [int(i) for i in arrays["sample_id"]] == [i[0] for i in task.items]


# ---------------------------------------------------------------------------- driver
def generate(
    cfg: GenerateConfig,
    out: str | Path,
    workers: int = 1,
    progress: bool = True,
    cache_dir: Path | None = None,
    on_shard_done: Callable[[str], None] | None = None,
) -> GenerateReport:
    """Render the dataset described by ``cfg`` into ``out`` (resuming if ``out`` holds a partial run).

    Args:
        cfg: what to render. out: dataset directory. workers: worker processes (one SAPIEN
            scene each); 1 renders in this process. progress: show a progress bar.
        cache_dir: asset cache (default ``~/.cache/scapo/assets``).
        on_shard_done: called with each shard name after it is written (used by tests to
            interrupt a run).

    Raises:
        ConfigError: ``out`` holds a dataset made with a different config.
        RenderError: a sample's views were all rejected, or no Vulkan device.
    """
    t0 = time.perf_counter()
    out = Path(out)
    shard_dir = out / "shards"
    shard_dir.mkdir(parents=True, exist_ok=True)
    cfg_json = cfg.to_json()
    cfg_path = out / "config.json"
    if cfg_path.is_file():
        old = json.loads(cfg_path.read_text())
        if old != json.loads(cfg_json):
            diff = sorted(k for k in set(old) | set(cfg.to_dict()) if old.get(k) != cfg.to_dict().get(k))
            raise ConfigError(f"{out} already holds a dataset generated with a different config (differs in "
                              f"{diff}); choose another --out or delete {out}")
    else:
        write_json(cfg_path, json.loads(cfg_json))
    for stale in shard_dir.glob(".*.tmp-*"):  # leftovers of an interrupted write
        stale.unlink()

    records = build_category(cfg.category, cfg.instances, cfg.seed, cache_dir, progress=False)
    urdfs = {r.instance_id: str(r.urdf) for r in records}
    tasks = plan(cfg)
    todo = [t for t in tasks if not _shard_is_complete(shard_dir / f"{t.name}.npz", t)]
    total = sum(len(t.items) for t in tasks)
    n_todo = sum(len(t.items) for t in todo)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, initial=total - n_todo, desc=f"generate {cfg.category}", unit="sample",
                   dynamic_ncols=True)
    rejections: Counter = Counter()
    spans: list[tuple[float, float]] = []

    def done(res: dict) -> None:
        rejections.update(res["reasons"])
        spans.append((res["t0"], res["t1"]))
        if on_shard_done is not None:
            on_shard_done(res["name"])

    t_render = time.perf_counter()
    try:
        if todo and workers <= 1:
            _init_worker(cfg_json, urdfs, None)
            for t in todo:
                done(_render_shard(t, str(shard_dir)))
                if bar is not None:
                    bar.update(len(t.items))
        elif todo:
            _run_pool(cfg_json, urdfs, todo, shard_dir, workers, bar, done)
    finally:
        if bar is not None:
            bar.close()
    render_seconds = time.perf_counter() - t_render
    steady = (max(s[1] for s in spans) - min(s[0] for s in spans)) if spans else 0.0
    card = _finalize(cfg, out, tasks, records)
    _write_run_log(out, workers, n_todo, render_seconds, time.perf_counter() - t0, rejections)
    rej = Counter(card["rejections"]["by_reason"])
    return GenerateReport(out, total, n_todo, len(tasks) - len(todo), rej, render_seconds, steady)


def _run_pool(cfg_json, urdfs, todo, shard_dir, workers, bar, done) -> None:
    import multiprocessing as mp
    from functools import partial

    ctx = mp.get_context("spawn")
    queue = ctx.Queue()

    def drain():
        while True:
            n = queue.get()
            if n is None:
                return
            if bar is not None:
                bar.update(n)

    th = threading.Thread(target=drain, daemon=True)
    th.start()
    try:
        with ctx.Pool(workers, initializer=_init_worker, initargs=(cfg_json, urdfs, queue)) as pool:
            for res in pool.imap_unordered(partial(_render_shard, shard_dir=str(shard_dir)), todo):
                done(res)
    finally:
        queue.put(None)
        th.join(timeout=5)


def _finalize(cfg: GenerateConfig, out: Path, tasks: list[ShardTask], records) -> dict:
    """Check every shard, write ``manifest.parquet`` and ``card.json``; returns the card."""
    shard_dir = out / "shards"
    rows, shards, reasons = [], {}, Counter()
    for t in tasks:
        path = shard_dir / f"{t.name}.npz"
        arrays = read_shard(path)
        if [int(i) for i in arrays["sample_id"]] != [i[0] for i in t.items]:
            raise DatasetError(f"shard {path} holds other samples than planned; delete it and rerun")
        shards[t.name] = {"sha256": sha256_file(path), "samples": len(t.items), "split": t.split}
        if "rejections" in arrays:
            reasons.update(json.loads(str(arrays["rejections"])))
        for r in range(len(t.items)):
            rows.append({
                "sample_id": int(arrays["sample_id"][r]),
                "split": t.split,
                "shard": t.name,
                "row": r,
                "category": cfg.category,
                "instance_id": int(arrays["instance_id"][r]),
                "view_id": int(arrays["view_id"][r]),
                "seed": int(cfg.seed),
                "attempts": int(arrays["attempts"][r]),
                "joint_state": [float(x) for x in arrays["joint_state"][r]],
            })
    manifest = pd.DataFrame(rows)
    manifest.to_parquet(out / ".manifest.parquet.tmp", index=False)
    os.replace(out / ".manifest.parquet.tmp", out / "manifest.parquet")
    spec = parse_urdf(records[0].urdf, category=cfg.category)
    train, test = split_instances(cfg.instances, cfg.test_fraction, cfg.seed)
    attempts = manifest["attempts"].to_numpy()
    reasons_total = int((attempts - 1).sum())
    h = hashlib.sha256(cfg.to_json().encode())
    for name in sorted(shards):
        h.update(shards[name]["sha256"].encode())
    card = {
        "scapo_version": __version__,
        "format_version": FORMAT_VERSION,
        "generator_version": GENERATOR_VERSION,
        "category": cfg.category,
        "part_names": list(spec.part_names),
        "joint_names": [j.name for j in spec.gt_joints],
        "joint_type": spec.joint_type.tolist(),
        "joint_parts": spec.joint_parts.tolist(),
        "num_points": cfg.render.num_points,
        "config": cfg.to_dict(),
        "splits": {"train": {"instances": train, "samples": int((manifest["split"] == "train").sum())},
                   "test": {"instances": test, "samples": int((manifest["split"] == "test").sum())}},
        "assets": {str(r.instance_id): r.digest for r in records},
        "shards": shards,
        "rejections": {"total": reasons_total, "by_reason": dict(sorted(reasons.items()))},
        "dataset_hash": h.hexdigest(),
    }
    write_json(out / "card.json", card)
    return card


def _write_run_log(out, workers, rendered, render_seconds, seconds, rejections) -> None:
    entry = {
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "host": platform.node(),
        "workers": workers,
        "rendered_samples": rendered,
        "render_seconds": round(render_seconds, 3),
        "total_seconds": round(seconds, 3),
        "samples_per_second": round(rendered / render_seconds, 3) if render_seconds > 0 and rendered else None,
        "rejections": dict(rejections),
    }
    with open(out / "run_log.jsonl", "a") as f:
        f.write(json.dumps(entry) + "\n")
