"""``scapo generate``: render a dataset of partial point clouds with ground truth, resumably.

The work is planned up front as shards of ``(sample_id, instance_id, view_id)`` items; every
sample's randomness is derived from ``(seed, category, instance_id, view_id, attempt)``, so the
output is identical for an identical config whatever the number of workers, and an interrupted
run resumes by skipping the shards already on disk. Each worker process owns one SAPIEN scene.

Nothing on disk is blessed without a check. Every shard written is recorded, with its sha256 and
the sha256 of the config, in the journal ``shards.jsonl`` (and, once all are done, in
``card.json``). On resume a shard counts as done only if its bytes match that record and its
sample keys match the plan; a shard that fails (replaced, edited, truncated, or written by a process
killed before recording it) is moved to ``rejected/`` with a warning and rendered again. The asset
digests the shards were rendered from are recorded too; assets that changed since (another
generator version) make the run refuse rather than mix two versions in one dataset. One process at
a time writes a dataset folder (:class:`~scapo.files.FolderLock`).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import platform
import sys
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from scapo import __version__
from scapo.data.config import FORMAT_VERSION, GenerateConfig, dict_diff
from scapo.data.storage import (
    read_shard,
    sha256_file,
    shard_bytes,
    write_json,
)
from scapo.errors import ConfigError, DatasetError, StaleAssetsError
from scapo.files import FolderLock, atomic_write_bytes, check_output_dir, clean_stale_temps, read_json
from scapo.provenance import usable_cores
from scapo.sim.assets import GENERATOR_VERSION, build_category
from scapo.sim.assets.objects import load_object
from scapo.sim.assets.symmetry import by_view
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
    rejected_shards: list[str] = field(default_factory=list)
    """Shards that failed verification on resume, moved to ``rejected/`` and rendered again."""
    test_samples: int = 0

    @property
    def samples_per_second(self) -> float:
        """Rendered samples per second of the rendering phase (worker start-up included)."""
        return self.rendered / self.seconds if self.seconds > 0 else float("nan")

    @property
    def steady_samples_per_second(self) -> float:
        """Rendered samples per second from the first shard's start to the last shard's end."""
        return self.rendered / self.steady_seconds if self.steady_seconds > 0 else float("nan")


class Splits(NamedTuple):
    """Instance ids of each split (sorted, disjoint)."""

    train: list[int]
    test: list[int]
    val: list[int]


def split_instances(instances: int, test_fraction: float, seed: int, val_fraction: float = 0.0) -> Splits:
    """Deterministic split of instance ids into (train, test, val), by instance.

    The test split is drawn first, as before val splits existed (at least one test instance if 2+
    exist, so the same seed gives the same test instances with or without a val split); the val split
    is then drawn from the rest with its own stream (at least one instance when ``val_fraction > 0``
    and the training split keeps one).
    """
    n_test = int(round(test_fraction * instances))
    if test_fraction > 0 and instances >= 2:
        n_test = min(max(n_test, 1), instances - 1)
    rng = np.random.default_rng([int(seed), 0x5CA90])
    test = sorted(int(i) for i in rng.choice(instances, size=n_test, replace=False)) if n_test else []
    rest = [i for i in range(instances) if i not in set(test)]
    n_val = int(round(val_fraction * instances))
    if val_fraction > 0 and len(rest) >= 2:
        n_val = min(max(n_val, 1), len(rest) - 1)
    else:
        n_val = 0
    rng_val = np.random.default_rng([int(seed), 0x5CA91])
    val = sorted(int(i) for i in rng_val.choice(rest, size=n_val, replace=False)) if n_val else []
    train = [i for i in rest if i not in set(val)]
    return Splits(train, test, val)


def plan(cfg: GenerateConfig) -> list[ShardTask]:
    """All shards of a dataset (train, val, test), samples ordered by instance then view; a training instance has
    ``cfg.views_train`` views, the others ``cfg.views`` (view ``v`` of an instance is the same sample whatever the
    number of views: its seed depends on ``v`` alone)."""
    sp = split_instances(cfg.instances, cfg.test_fraction, cfg.seed, cfg.val_fraction)
    tasks, sid = [], 0
    for split, ids in (("train", sp.train), ("val", sp.val), ("test", sp.test)):
        items = []
        for inst in ids:
            for v in range(cfg.views_train if split == "train" else cfg.views):
                items.append((sid, inst, v))
                sid += 1
        for k in range(0, len(items), cfg.shard_size):
            tasks.append(ShardTask(f"{split}-{k // cfg.shard_size:05d}", split, tuple(items[k:k + cfg.shard_size])))
    return tasks


def sample_seed_key(cfg: GenerateConfig, instance_id: int, view_id: int) -> tuple[int, ...]:
    """Seed tuple of one sample (the attempt number is appended when rendering)."""
    return (int(cfg.seed), zlib.crc32(cfg.category.encode()), int(instance_id), int(view_id))


# ---------------------------------------------------------------------------- workers
@dataclass(frozen=True)
class InstanceAsset:
    """The asset of one dataset instance: a procedural instance (its ``model.urdf``) or a derived object
    (its folder); ``digest`` is recorded in the journal and the card."""

    instance_id: int
    urdf: Path
    digest: str


OBJECTS = "objects"


def dataset_assets(cfg: GenerateConfig, out: Path, cache_dir: Path | None = None,
                   progress: bool = False) -> list[InstanceAsset]:
    """Build (procedural) or derive (existing objects, into ``out/objects/<instance>/``) every instance.

    Raises:
        ConfigError: objects whose part map cannot be applied or whose parts / joints disagree.
        URDFError / MissingMeshError: a malformed source object (named).
    """
    if cfg.one_shape:  # every instance is instance 0's object
        r = build_category(cfg.category, 1, cfg.seed, cache_dir, progress=progress)[0]
        return [InstanceAsset(i, Path(r.urdf), r.digest) for i in range(cfg.instances)]
    if not cfg.objects:
        return [InstanceAsset(r.instance_id, Path(r.urdf), r.digest)
                for r in build_category(cfg.category, cfg.instances, cfg.seed, cache_dir, progress=progress)]
    from scapo.sim.assets.objects import check_compatible, derive_object

    derived = [derive_object(o, cfg.parts, cfg.scale, out / OBJECTS / f"{i:05d}", cfg.category)
               for i, o in enumerate(cfg.objects)]
    check_compatible(derived)
    return [InstanceAsset(i, d.folder, d.digest) for i, d in enumerate(derived)]


def instance_asset_path(cfg: GenerateConfig, data: Path, instance_id: int, cache_dir: Path | None = None) -> Path:
    """Where the asset of one instance of the dataset in ``data`` is (building a procedural one if needed)."""
    if cfg.objects:
        path = Path(data) / OBJECTS / f"{int(instance_id):05d}"
        if not (path / "mobility.urdf").is_file():
            raise DatasetError(f"{data}: the derived object of instance {instance_id} is missing ({path}); rerun "
                               "'scapo generate' with the dataset's arguments to rewrite it")
        return path
    from scapo.sim.assets import build_instance

    return Path(build_instance(cfg.category, 0 if cfg.one_shape else int(instance_id), cfg.seed, cache_dir).urdf)


def load_instance(cfg: GenerateConfig, path: str | Path):
    """Parse an instance asset into an ArticulationSpec (see :func:`dataset_assets`)."""
    return load_object(path, category=cfg.category)


class ShardWorker:
    """Renders shards of one dataset; all of a worker's state lives here (one per process or Ray actor).

    It owns one SAPIEN scene (:class:`~scapo.sim.render.Renderer`, made on first use: a scene costs seconds)
    and the parsed instances. An instance's asset is taken from the driver's path when this machine sees
    it; otherwise (a Ray worker on another machine) a procedural instance is built into this worker's own
    cache (deterministic, checked against the driver's digest); derived objects need the dataset folder on
    a shared filesystem. A shard comes back as the bytes of its ``.npz``: the driver writes and records
    it, so workers need no access to the output folder.

    Args:
        cfg_json: the dataset's config (:meth:`GenerateConfig.to_json`). assets: instance id -> asset path
            on the driver. digests: instance id (str) -> asset digest. data: the dataset folder on the driver.
        cache_dir: asset cache of this worker (default ``~/.cache/scapo/assets``).

    Raises (from :meth:`render`):
        RenderError: a sample's views were all rejected, or no Vulkan device. DatasetError: an asset
            built here differs from the driver's (another scapo version), or a derived object is not visible.
    """

    def __init__(self, cfg_json: str, assets: dict[int, str], digests: dict[str, str] | None = None,
                 data: str | None = None, cache_dir: str | None = None, num_envs: int = 1):
        self.cfg = GenerateConfig.from_dict(json.loads(cfg_json))
        self.assets = {int(k): str(v) for k, v in assets.items()}
        self.digests = dict(digests or {})
        self.data = data
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self.specs: dict = {}
        self._renderer = None
        self.num_envs = int(num_envs)
        self.queue = None  # a local pool's progress queue

    @property
    def renderer(self):
        """The scene: a SAPIEN :class:`~scapo.sim.render.Renderer`, or with ``cfg.backend == "maniskill"`` a
        :class:`~scapo.sim.maniskill.ManiSkillRenderer` of ``num_envs`` parallel sub-scenes."""
        if self._renderer is None:
            if self.cfg.backend == "maniskill":
                from scapo.sim.maniskill import ManiSkillRenderer

                self._renderer = ManiSkillRenderer(self.cfg.render.camera, num_envs=self.num_envs,
                                                   shader=self.cfg.render.shader)
            else:
                self._renderer = Renderer(self.cfg.render.camera, self.cfg.render.shader)
        return self._renderer

    def ready(self) -> bool:
        """Start the scene now (so that start-up is not counted in the first shard's time)."""
        return self.renderer is not None

    def spec(self, inst: int):
        """The parsed asset of instance ``inst`` (see the class docstring)."""
        if inst not in self.specs:
            path = Path(self.assets[inst])
            if not path.exists():
                if self.cfg.objects:
                    raise DatasetError(f"derived object {path} is not visible on this worker; put the dataset folder "
                                       "on a filesystem every worker shares")
                from scapo.sim.assets import build_instance

                rec = build_instance(self.cfg.category, 0 if self.cfg.one_shape else inst, self.cfg.seed,
                                     self.cache_dir)
                if self.digests and rec.digest != self.digests.get(str(inst)):
                    raise DatasetError(f"instance {inst} built on this worker differs from the driver's (digest "
                                       f"{rec.digest[:12]} vs {str(self.digests.get(str(inst)))[:12]}); run the same "
                                       "scapo version everywhere")
                path = Path(rec.urdf)
            self.specs[inst] = load_instance(self.cfg, path)
        return self.specs[inst]

    def render(self, task: ShardTask, progress=None) -> dict:
        """Render one shard; returns its name, npz ``data`` (bytes), ``sha256``, rejection ``reasons``, times
        ``t0``/``t1`` (s since the epoch) and ``samples``. ``progress(n)`` is called after each sample."""
        cfg = self.cfg
        t0 = time.time()
        groups: list[tuple[int, list]] = []  # consecutive items of one instance share its viewpoint ranges
        for sample_id, inst, vid in task.items:
            spec = self.spec(inst)
            if not groups or groups[-1][0] != inst:
                groups.append((inst, []))
            groups[-1][1].append((sample_id, spec, sample_seed_key(cfg, inst, vid)))
        samples, reasons = [], Counter()
        sym = cfg.symmetry if cfg.render.symmetric_labels == "view" else None
        many = render_many
        if cfg.backend == "maniskill":
            from scapo.sim.maniskill import render_many_maniskill as many
        for inst, jobs in groups:
            for _, s, r in many(self.renderer, jobs, cfg.render, cfg.view_for(inst)):
                samples.append(s if sym is None else by_view(s, sym))
                reasons.update(r)
                if progress is not None:
                    progress(1)
        meta = {
            "sample_id": np.array([i[0] for i in task.items]),
            "instance_id": np.array([i[1] for i in task.items]),
            "view_id": np.array([i[2] for i in task.items]),
            "attempts": np.array([s["attempts"] for s in samples]),
        }
        if cfg.render.cropped == "flag":
            meta["cropped"] = np.array([s["cropped"] for s in samples], dtype=bool)
        data = shard_bytes(samples, meta, dict(reasons))
        return {"name": task.name, "data": data, "sha256": hashlib.sha256(data).hexdigest(), "reasons": dict(reasons),
                "t0": t0, "t1": time.time(), "samples": len(samples)}


#: The :class:`ShardWorker` of this process in a local worker pool (a pool initializer can only leave a handle
#: where the pool's tasks find it; the state itself lives in the object).
_POOL_WORKER: list[ShardWorker] = []


def _pool_init(args: tuple, queue) -> None:
    import warnings

    from scapo.errors import ScapoWarning

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):  # a worker's warning as the CLI prints it
        if issubclass(category, ScapoWarning):
            print(f"scapo generate: warning: {message}", file=sys.stderr, flush=True)
        else:
            shown(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    _POOL_WORKER[:] = [ShardWorker(*args)]
    _POOL_WORKER[0].queue = queue
    _POOL_WORKER[0].ready()


def _pool_render(task: ShardTask) -> dict:
    w = _POOL_WORKER[0]
    return w.render(task, None if w.queue is None else w.queue.put)


JOURNAL = "shards.jsonl"
REJECTED = "rejected"


def config_sha256(cfg: GenerateConfig) -> str:
    """sha256 of the config's canonical JSON (what every shard record is tied to)."""
    return hashlib.sha256(cfg.to_json().encode()).hexdigest()


def _append_journal(out: Path, entry: dict) -> None:
    with open(out / JOURNAL, "a") as f:
        f.write(json.dumps(entry, sort_keys=True) + "\n")
        f.flush()
        os.fsync(f.fileno())


def record_shard(out: Path, name: str, sha256: str, cfg_sha: str, **extra) -> None:
    """Append shard ``name``'s record (its ``sha256``, made with the config of sha256 ``cfg_sha``) to the journal of
    the dataset folder ``out``; the last record of a shard is the one a resumed :func:`generate` checks it against.
    ``extra`` keys are stored beside it (``reconciled_from``: :func:`scapo.bench.archive.reconcile_dataset`)."""
    _append_journal(out, {**extra, "shard": name, "sha256": sha256, "config_sha256": cfg_sha})


def _read_journal(out: Path, cfg_sha: str) -> tuple[dict[str, str], dict[str, str] | None]:
    """Shard records and the asset digests of the last start, of the journal lines made with ``cfg_sha``.

    A torn last line (the process died while appending) is ignored.
    """
    shards: dict[str, str] = {}
    assets = None
    try:
        lines = (out / JOURNAL).read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        return shards, assets
    for line in lines:
        try:
            e = json.loads(line)
        except json.JSONDecodeError:
            continue
        if not isinstance(e, dict) or e.get("config_sha256") != cfg_sha:
            continue
        if "shard" in e and "sha256" in e:
            shards[str(e["shard"])] = str(e["sha256"])
        elif "assets" in e:
            assets = {str(k): str(v) for k, v in e["assets"].items()}
    return shards, assets


def _card_records(out: Path, cfg: GenerateConfig) -> tuple[dict[str, str], dict[str, str] | None]:
    """Shard sha256s and asset digests recorded in an existing ``card.json`` of the same config."""
    try:
        card = json.loads((out / "card.json").read_text())
        if card.get("config") != json.loads(cfg.to_json()):
            return {}, None
        return ({str(k): str(v["sha256"]) for k, v in card.get("shards", {}).items()},
                {str(k): str(v) for k, v in card.get("assets", {}).items()})
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}, None


def _shard_status(path: Path, task: ShardTask, recorded: str | None) -> str:
    """"ok", "missing", "unrecorded" (no record of writing it), "modified" (bytes differ from the
    record) or "foreign" (its sample keys are not the plan's)."""
    if not path.is_file():
        return "missing"
    if recorded is None:
        return "unrecorded"
    if sha256_file(path) != recorded:
        return "modified"
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = list(zip(z["sample_id"].tolist(), z["instance_id"].tolist(), z["view_id"].tolist()))
    except Exception:  # noqa: BLE001 - any unreadable file fails verification
        return "modified"
    return "ok" if keys == [tuple(i) for i in task.items] else "foreign"


def _move_to_rejected(out: Path, path: Path, status: str) -> Path:
    dest_dir = out / REJECTED
    dest_dir.mkdir(exist_ok=True)
    dest = dest_dir / f"{path.stem}.{status}.npz"
    k = 1
    while dest.exists():
        dest = dest_dir / f"{path.stem}.{status}.{k}.npz"
        k += 1
    os.replace(path, dest)
    return dest


def _check_out_folder(out: Path) -> None:
    """Refuse an ``--out`` that is a file, or a non-empty folder that holds no scapo dataset."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is an existing file; give a folder for the dataset")
    if out.is_dir() and not (out / "config.json").exists():
        foreign = [p.name for p in out.iterdir() if p.name != FolderLock.NAME]
        if foreign:
            raise ConfigError(f"--out {out} is a non-empty folder without a scapo dataset (holds "
                              f"{', '.join(sorted(foreign)[:4])}{', ...' if len(foreign) > 4 else ''}); give a new "
                              "or empty folder")


def _warn(msg: str) -> None:
    """A :class:`~scapo.errors.ScapoWarning` (the command line prints it as one ``scapo generate: warning:`` line)."""
    import warnings

    from scapo.errors import ScapoWarning

    warnings.warn(msg, ScapoWarning, stacklevel=3)


# ---------------------------------------------------------------------------- driver
def generate(
    cfg: GenerateConfig,
    out: str | Path,
    workers: int = 1,
    progress: bool = True,
    cache_dir: Path | None = None,
    on_shard_done: Callable[[str], None] | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    num_envs: int = 1,
) -> GenerateReport:
    """Render the dataset described by ``cfg`` into ``out`` (resuming if ``out`` holds a partial run).

    Args:
        cfg: what to render. out: dataset directory. workers: worker processes (one SAPIEN
            scene each; with Ray, actors); 1 renders in this process (local). progress: show a progress bar.
        cache_dir: asset cache (default ``~/.cache/scapo/assets``).
        on_shard_done: called with each shard name after it is written (used by tests to
            interrupt a run).
        executor: "local" (this process or a local process pool) or "ray" (:class:`ShardWorker` actors on
            a Ray cluster: ``ray_address`` of a running one, e.g. "auto" or "ray://host:10001", or None for
            a local Ray instance started and stopped here). Shards are the unit of work either way: the
            output is byte-identical for any executor and number of workers, and resuming works the same.

    Resuming verifies every shard already on disk against its record (see the module docstring);
    failing shards are moved to ``out/rejected/`` and rendered again (listed in the report's
    ``rejected_shards``; a moved shard identical to its new rendering is deleted instead).

    Raises:
        ConfigError: ``out`` holds a dataset made with a different config (the message names the
            differing fields), is a file or a foreign non-empty folder, or ``workers < 1``.
        StaleAssetsError: (a ConfigError) the assets differ from those the finished shards were rendered with.
        DatasetError: ``out/config.json`` is unreadable.
        OutputError: ``out`` cannot be written, or another process is generating into it.
        RenderError: a sample's views were all rejected, or no Vulkan device.
    """
    t0 = time.perf_counter()
    if int(workers) < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    if int(num_envs) < 1:
        raise ConfigError(f"--num-envs must be >= 1 (views rendered at once), got {num_envs}")
    if int(num_envs) > 1 and cfg.backend != "maniskill":
        raise ConfigError(f"--num-envs {num_envs}: parallel sub-scenes are the ManiSkill3 backend's (--backend "
                          "maniskill); the SAPIEN backend renders one view at a time (--workers for processes)")
    if cfg.backend == "maniskill":  # everything the backend needs, checked before the dataset folder is touched
        from scapo.sim.maniskill import available

        if not available():
            raise ConfigError("--backend maniskill needs ManiSkill3: pip install 'scapo[maniskill]'")
        if int(num_envs) > 1:
            import torch

            if not torch.cuda.is_available():
                raise ConfigError(f"--num-envs {num_envs}: ManiSkill's CPU simulation holds one sub-scene; without "
                                  "a GPU use --num-envs 1 (or --workers for processes)")
    if executor == "local" and int(workers) > 4 * usable_cores():
        raise ConfigError(f"--workers {workers} would start {workers} SAPIEN processes on {usable_cores()} usable "
                          f"core(s); use at most {4 * usable_cores()} (one per core is fastest), or --executor ray "
                          "for a cluster")
    if executor not in EXECUTORS:
        raise ConfigError(f"unknown executor {executor!r}; known: {', '.join(EXECUTORS)}")
    if executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError("--executor ray needs Ray: pip install 'scapo[ray]' (or pip install ray)") from None
    out = Path(out)
    _check_out_folder(out)
    check_output_dir(out, "dataset folder", own="dataset")
    with FolderLock(out, "generate"):
        return _generate_locked(cfg, out, workers, progress, cache_dir, on_shard_done, t0, executor, ray_address,
                                num_envs)


EXECUTORS = ("local", "ray")


def _generate_locked(cfg, out, workers, progress, cache_dir, on_shard_done, t0, executor="local",
                     ray_address=None, num_envs: int = 1) -> GenerateReport:
    shard_dir = out / "shards"
    shard_dir.mkdir(parents=True, exist_ok=True)
    for folder in (out, shard_dir):  # leftovers of interrupted writes (we hold the folder's lock)
        clean_stale_temps(folder, any_pid=True)
    cfg_json = cfg.to_json()
    cfg_path = out / "config.json"
    if cfg_path.is_file():
        old = read_json(cfg_path, "dataset config", DatasetError,
                        "if the folder was made with these same arguments, delete that file and rerun to resume; "
                        "otherwise choose another --out")
        started = (out / "card.json").exists() or any(shard_dir.glob("*.npz"))
        if old != json.loads(cfg_json) and not started:  # a run that failed before its first shard: taken over
            write_json(cfg_path, json.loads(cfg_json))
            for stale in ("shards.jsonl", "run_log.jsonl"):
                (out / stale).unlink(missing_ok=True)
        elif old != json.loads(cfg_json):
            diff = dict_diff(old, json.loads(cfg_json))
            hint = ""
            if "val_fraction" in diff:
                hint = (f" (its --val-fraction is {old.get('val_fraction', 0)}; a dataset written before val splits "
                        "existed resumes with --val-fraction 0)")
            raise ConfigError(f"{out} already holds a dataset generated with a different config (differs in "
                              f"{', '.join(diff)}){hint}; choose another --out, or delete it: rm -r {out}")
    else:
        write_json(cfg_path, json.loads(cfg_json))
    cfg_sha = config_sha256(cfg)

    records = dataset_assets(cfg, out, cache_dir)
    assets = {str(r.instance_id): r.digest for r in records}
    card_shards, card_assets = _card_records(out, cfg)
    journal_shards, journal_assets = _read_journal(out, cfg_sha)
    recorded = {**card_shards, **journal_shards}
    before = journal_assets if journal_assets is not None else card_assets
    if recorded and before is not None:
        changed = sorted((k for k in assets if k in before and before[k] != assets[k]), key=int)
        if changed:
            raise StaleAssetsError(
                f"{out}: the assets of instance(s) {', '.join(changed)} differ from those its finished shards were "
                "rendered with (the asset generator or its templates changed since); generate into a new --out")
    _append_journal(out, {"event": "start", "config_sha256": cfg_sha, "assets": assets,
                          "time": time.strftime("%Y-%m-%dT%H:%M:%S")})

    urdfs = {r.instance_id: str(r.urdf) for r in records}
    tasks = plan(cfg)
    todo, moved = [], {}
    for t in tasks:
        path = shard_dir / f"{t.name}.npz"
        status = _shard_status(path, t, recorded.get(t.name))
        if status == "ok":
            continue
        if status != "missing":
            moved[t.name] = _move_to_rejected(out, path, status)
        todo.append(t)
    if moved:
        _warn(f"{len(moved)} shard(s) on disk failed verification and will be rendered again (moved to "
              f"{out / REJECTED}): " + ", ".join(f"{n} ({p.name.split('.')[1]})" for n, p in moved.items()))
    total = sum(len(t.items) for t in tasks)
    n_todo = sum(len(t.items) for t in todo)
    bar = None
    if progress:
        from scapo.report import progress_bar

        bar = progress_bar(total=total, initial=total - n_todo, desc=f"generate {cfg.category}", unit="sample",
                   dynamic_ncols=True)
    rejections: Counter = Counter()
    spans: list[tuple[float, float]] = []

    def done(res: dict) -> None:
        atomic_write_bytes(shard_dir / f"{res['name']}.npz", res["data"])
        record_shard(out, res["name"], res["sha256"], cfg_sha)
        recorded[res["name"]] = res["sha256"]
        rejections.update(res["reasons"])
        spans.append((res["t0"], res["t1"]))
        if on_shard_done is not None:
            on_shard_done(res["name"])

    t_render = time.perf_counter()
    args = (cfg_json, urdfs, assets, str(out), None if cache_dir is None else str(cache_dir), num_envs)
    try:
        if todo and executor == "ray":
            _run_ray(args, todo, workers, bar, done, ray_address)
        elif todo and workers <= 1:
            worker = ShardWorker(*args)
            worker.ready()
            for t in todo:
                done(worker.render(t))
                if bar is not None:
                    bar.update(len(t.items))
        elif todo:
            _run_pool(args, todo, workers, bar, done)
    finally:
        if bar is not None:
            bar.close()
    render_seconds = time.perf_counter() - t_render
    steady = (max(s[1] for s in spans) - min(s[0] for s in spans)) if spans else 0.0
    for name, path in list(moved.items()):  # a rejected shard identical to its new rendering was ours
        if sha256_file(path) == recorded.get(name):
            path.unlink()
    if (out / REJECTED).is_dir() and not any((out / REJECTED).iterdir()):
        (out / REJECTED).rmdir()
    card = _finalize(cfg, out, tasks, records, recorded)
    _write_run_log(out, workers, n_todo, render_seconds, time.perf_counter() - t0, rejections)
    rej = Counter(card["rejections"]["by_reason"])
    rejected = [n for n, p in moved.items() if p.exists()]
    return GenerateReport(out, total, n_todo, len(tasks) - len(todo), rej, render_seconds, steady, rejected,
                          card["splits"]["test"]["samples"])


#: Ray system settings of the local cluster generation starts (no ``ray_address``): its worker processes at the
#: normal scheduling priority. Ray's default runs them at niceness 15, so that render actors got about 2 % of a core
#: beside any busy process of normal priority (measured: 12 scissors views on one actor, 109 s beside two CPU-bound
#: trainings; 5 s at niceness 0). A cluster given by address keeps its own settings.
RAY_LOCAL_SYSTEM_CONFIG = {"worker_niceness": 0}


def _run_ray(args: tuple, todo: list[ShardTask], workers: int, bar, done, address: str | None) -> None:
    """Render ``todo`` on ``workers`` Ray actors (:class:`ShardWorker`), each given the next shard as it
    finishes one; the driver writes and records every shard as it comes back. Without ``address`` and with no Ray
    running in this process, a local cluster of ``workers`` CPUs is started (:data:`RAY_LOCAL_SYSTEM_CONFIG`) and
    shut down at the end."""
    import ray

    started = not ray.is_initialized()
    if started:
        kw = ({"address": address} if address else
              {"num_cpus": workers, "include_dashboard": False, "_system_config": dict(RAY_LOCAL_SYSTEM_CONFIG)})
        ray.init(log_to_driver=False, configure_logging=False, **kw)
    Worker = ray.remote(num_cpus=1)(ShardWorker)
    actors = [Worker.remote(*args) for _ in range(workers)]
    queue = list(todo)
    pending = {}
    try:
        ray.get([a.ready.remote() for a in actors])
        for a in actors:
            if queue:
                t = queue.pop(0)
                pending[a.render.remote(t)] = (a, t)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            a, t = pending.pop(ready[0])
            res = ray.get(ready[0])  # an actor's ScapoError is re-raised here as that error
            done(res)
            if bar is not None:
                bar.update(len(t.items))
            if queue:
                t2 = queue.pop(0)
                pending[a.render.remote(t2)] = (a, t2)
    finally:
        for a in actors:
            ray.kill(a)
        if started:
            ray.shutdown()


def _run_pool(args: tuple, todo: list[ShardTask], workers: int, bar, done) -> None:
    import multiprocessing as mp

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
        with ctx.Pool(workers, initializer=_pool_init, initargs=(args, queue)) as pool:
            for res in pool.imap_unordered(_pool_render, todo):
                done(res)
    finally:
        queue.put(None)
        th.join(timeout=5)



def _card_viewpoints(cfg) -> str:
    """The card's ``viewpoints``: the setting every instance is rendered in (:meth:`GenerateConfig.view_for`: the
    dataset's, or an object's own, e.g. its ``object_euler_deg`` of ``--object-options``), "mixed" where objects
    differ."""
    own = {cfg.view_for(i).viewpoints for i in range(len(cfg.objects))} or {cfg.view_config.viewpoints}
    return own.pop() if len(own) == 1 else "mixed"


def _finalize(cfg: GenerateConfig, out: Path, tasks: list[ShardTask], records, recorded: dict[str, str]) -> dict:
    """Check every shard against its record, write ``manifest.parquet`` and ``card.json``; returns the card."""
    shard_dir = out / "shards"
    rows, shards, reasons = [], {}, Counter()
    for t in tasks:
        path = shard_dir / f"{t.name}.npz"
        arrays = read_shard(path, recorded.get(t.name))
        if [int(i) for i in arrays["sample_id"]] != [i[0] for i in t.items]:
            raise DatasetError(f"shard {path} holds other samples than planned; delete it and rerun")
        shards[t.name] = {"sha256": recorded[t.name], "samples": len(t.items), "split": t.split}
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
                **({"cropped": bool(arrays["cropped"][r])} if "cropped" in arrays else {}),
            })
    manifest = pd.DataFrame(rows)
    buf = io.BytesIO()
    manifest.to_parquet(buf, index=False)
    atomic_write_bytes(out / "manifest.parquet", buf.getvalue())
    spec = load_instance(cfg, records[0].urdf)
    sp = split_instances(cfg.instances, cfg.test_fraction, cfg.seed, cfg.val_fraction)
    splits = {name: {"instances": ids, "samples": int((manifest["split"] == name).sum())}
              for name, ids in (("train", sp.train), ("val", sp.val), ("test", sp.test))}
    if not cfg.val_fraction:  # the card of a dataset without a val split is as before val splits existed
        del splits["val"]
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
        "viewpoints": _card_viewpoints(cfg),
        **({"parts_alone": True} if cfg.render.parts_alone else {}),  # each part rendered alone (EAP's regime)
        "views_per_instance": {"train": cfg.views_train, "val": cfg.views, "test": cfg.views},
        "config": cfg.to_dict(),
        "splits": splits,
        "assets": {str(r.instance_id): r.digest for r in records},
        "shards": shards,
        "rejections": {"total": reasons_total, "by_reason": dict(sorted(reasons.items()))},
        "dataset_hash": h.hexdigest(),
    }
    if cfg.symmetry is not None:  # the other ground truth of every view, for the evaluator (op-align protocol)
        card["symmetry"] = {**cfg.symmetry.to_dict(), "labels": cfg.render.symmetric_labels}
    if cfg.objects:
        card["objects"] = [{"instance_id": r.instance_id, "source": o.path, "derived": f"{OBJECTS}/{r.instance_id:05d}",
                            "scale": json.loads((Path(r.urdf) / "meta.json").read_text())["scale"]}
                           for r, o in zip(records, cfg.objects)]
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
