"""One training loop for every trained method: SCAPO's two stages and each learned baseline.

A method hands the engine a :class:`TrainJob`: its network, its training clouds (:class:`CloudSet`), and a
schedule of :class:`Stage` objects, each with the parameters it trains, a learning rate, a number of epochs
and ``losses(batch, progress) -> (terms, total)``; a term's name is its column of ``log.csv``. The engine
does the rest, the same way for every method:

- the run folder (:class:`~scapo.engine.runs.RunFolder`): refusals before anything is written, a lock
  against a second process, ``run.json``, a checkpoint after every epoch, ``log.csv``, ``losses.png`` (at
  most once a minute, and at the end), ``timing.json``; an interrupted run resumes from its next (stage,
  epoch) and gives the same weights;
- per stage: Adam with weight decay, a cosine schedule to ``min_lr`` over the stage's steps, gradient
  clipping, a stop naming the loss term that became NaN or infinite (the last good checkpoint kept);
- batches from a :class:`~torch.utils.data.DataLoader`; with several processes (``torchrun``) a
  :class:`~torch.utils.data.distributed.DistributedSampler` gives each rank its share and the gradients are
  averaged (:mod:`scapo.engine.distributed`);
- every epoch is seeded by (seed, stage, epoch, rank): a run is a function of its preset and data;
- with :attr:`FitConfig.compile`, the network's parts are compiled (:func:`compile_network`) and each stage's first
  step is compiled before it trains, charged to the ledger's ``stage<k>/compile`` phase; eager where compilation
  fails (a warning).

Usage (a method's ``train`` function)::

    folder = RunFolder(run, identity)
    train_run(folder, lambda dev, ctx: TrainJob(...), device, progress=True)
"""

from __future__ import annotations

import contextlib
import csv
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from torch.utils.data.distributed import DistributedSampler

from scapo.engine.distributed import DistContext, dist_context, per_rank_threads, run_settings
from scapo.engine.ledger import Ledger, cpu_seconds
from scapo.engine.runs import RunFolder, plot_losses, truncate_log
from scapo.errors import TrainingError
from scapo.files import FolderLock, check_output_dir, clean_stale_temps
from scapo.provenance import training_threads

#: the log's leading columns; the loss terms follow
BASE_COLUMNS = ("stage", "epoch", "step", "lr", "total")

LossFn = Callable[[dict, float], "tuple[dict[str, torch.Tensor], torch.Tensor]"]


class CloudSet(Dataset):
    """Training clouds for the engine: sample ``i`` is a dict of its fields, each per-point field
    (``points (N, 3)``, ``part_label (N,)``, ``npcs (N, 3)``) restricted to the same random subset of
    ``points`` points, each per-sample field (e.g. ``joint_axis (J, 3)``) whole; dtypes as stored.

    Args:
        tensors: field -> tensor ``(M, ...)`` over the ``M`` clouds; must hold ``points (M, N, 3)``.
        points: points per training cloud (at most ``N``).
        per_point: fields subsampled with the points.

    The subsets are drawn from :attr:`generator` when one is set (the engine sets it per epoch in the
    ``"permutation"`` order), else from torch's global RNG.
    """

    PER_POINT = ("points", "part_label", "npcs")

    def __init__(self, tensors: dict[str, torch.Tensor], points: int, per_point: Sequence[str] = PER_POINT):
        if "points" not in tensors:
            raise ValueError("CloudSet needs a 'points' field")
        self.tensors = dict(tensors)
        self.per_point = tuple(per_point)
        self.points = min(int(points), self.tensors["points"].shape[1])
        self.generator: torch.Generator | None = None

    @property
    def clouds(self) -> torch.Tensor:
        """``(M, N, 3)`` the whole clouds."""
        return self.tensors["points"]

    @property
    def extra(self) -> dict[str, torch.Tensor]:
        """The fields other than ``points``."""
        return {k: v for k, v in self.tensors.items() if k != "points"}

    def __len__(self) -> int:
        return len(self.tensors["points"])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        N = self.tensors["points"].shape[1]
        idx = torch.randperm(N, generator=self.generator)[: self.points]
        return {k: (v[i, idx] if k in self.per_point else v[i]) for k, v in self.tensors.items()}


@dataclass(frozen=True)
class Stage:
    """One stage of a training schedule.

    Attributes:
        index: 1-based; the ``stage`` column of ``log.csv`` and the checkpoint's resume point; it seeds the
            stage's epochs.
        epochs: passes over the training clouds (0 skips the stage).
        lr: Adam's learning rate at the start of the stage (cosine-annealed to ``FitConfig.min_lr``).
        params: ``params() -> list of parameters`` the stage's optimiser updates (called when it starts).
        losses: ``losses(batch, progress) -> (terms, total)``: ``batch`` a dict of the :class:`CloudSet`
            fields stacked ``(B, ...)`` on the training device, ``progress`` in [0, 1) the fraction of the
            stage done; ``terms`` name -> scalar tensor (logged, checked for NaN), ``total`` the scalar
            that is minimised.
        terms: the loss-term names this stage may log, in column order (declare every stage's terms so that
            the log's header, written at the first step, holds the later stages' columns too).
        on_start: called once when the stage starts from its first epoch (not on a resume inside it),
            e.g. SCAPO's template initialisation before stage 2.
        schedule: ``"cosine"`` (annealed to ``FitConfig.min_lr`` over the stage) or ``"step"`` (multiplied by
            ``decay`` every ``decay_steps`` optimiser steps, as OP-Align's ``exp_decay`` schedule:
            ``options.py`` 121-127 of YC-Che/OP-Align).
    """

    index: int
    epochs: int
    lr: float
    params: Callable[[], list]
    losses: LossFn
    terms: tuple[str, ...] = ()
    on_start: Callable[[], None] | None = None
    schedule: str = "cosine"
    decay: float = 0.5
    decay_steps: int = 5000

    def __post_init__(self):
        if self.schedule not in ("cosine", "step") or not 0 < self.decay <= 1 or self.decay_steps < 1:
            raise ValueError(f"stage {self.index}: schedule must be 'cosine' or 'step' with 0 < decay <= 1 and "
                             f"decay_steps >= 1, got {self.schedule!r}, {self.decay}, {self.decay_steps}")

    def scheduler(self, opt: torch.optim.Optimizer, steps: int, min_lr: float):
        """The stage's learning-rate scheduler for ``steps`` optimiser steps per epoch (stepped once per step)."""
        if self.schedule == "step":
            return torch.optim.lr_scheduler.StepLR(opt, step_size=self.decay_steps, gamma=self.decay)
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, self.epochs * steps), eta_min=min_lr)


@dataclass(frozen=True)
class FitConfig:
    """Settings of the loop shared by every stage.

    Attributes:
        batch_size: clouds per step and rank. weight_decay: Adam's. min_lr: the cosine schedule's floor.
        grad_clip: max gradient norm (0: none). max_steps_per_epoch: 0 = every batch of the rank's share.
        seed: the run's seed. order: how an epoch's batches are drawn:

            - ``"permutation"`` (new methods): DistributedSampler's permutation of the clouds for every world
              size, the point subsets from a generator seeded by the epoch that continues after the
              permutation; a run on one process and its share on each of W processes see the same order.
            - ``"shuffle"``: the DataLoader's shuffle (seeded by the epoch) on one process, the
              DistributedSampler under ``torchrun``, the point subsets from the global RNG seeded by the
              epoch and rank; SCAPO's order since its first runs, kept so that they resume and reproduce.
    """

    batch_size: int
    weight_decay: float = 0.0
    min_lr: float = 0.0
    grad_clip: float = 0.0
    max_steps_per_epoch: int = 0
    seed: int = 0
    order: Literal["permutation", "shuffle"] = "permutation"
    compile: bool = False
    """Compile the network's parts with ``torch.compile`` (:func:`compile_network`) for the training steps."""


@dataclass
class TrainJob:
    """What a method gives the engine to train.

    Attributes:
        model: the network (on the training device). data: the training clouds. stages: the schedule.
        config: the loop's settings. desc: the progress bar's label.
        load_state: ``load_state(model_state_dict)`` on resume (default ``model.load_state_dict``).
        extras: ``extras(done) -> dict`` merged into every checkpoint (e.g. the model's structure; statistics
            computed once training is done).
    """

    model: torch.nn.Module
    data: CloudSet
    stages: list[Stage]
    config: FitConfig
    desc: str = "train"
    load_state: Callable[[dict], None] | None = None
    extras: Callable[[bool], dict] | None = None

    def steps_per_epoch(self, world: int) -> int:
        """Optimiser steps per epoch on each of ``world`` ranks (at least 1)."""
        share = len(self.data) // world
        steps = share // self.config.batch_size if share >= self.config.batch_size else 1
        if self.config.max_steps_per_epoch:
            steps = min(steps, self.config.max_steps_per_epoch)
        return steps


#: Seconds of training between two drawings of ``losses.png`` (it is also drawn after the last epoch): a drawing
#: costs a few tenths of a second of CPU (it cost 1.3 s before :func:`~scapo.engine.runs.loss_figure` fixed its
#: layout), and drawn after every epoch it was half the CPU time of a ``test``-preset run.
PLOT_EVERY_S = 60.0


def train_run(folder: RunFolder, make_job: Callable[[torch.device, DistContext], TrainJob], device: torch.device,
              progress: bool = True, ctx: DistContext | None = None) -> Path:
    """Train (or resume, or find finished) the run of ``folder``; returns the checkpoint path.

    Everything is checked before anything is written: the folder (a file, a foreign non-empty folder, not
    writable), another process training into it, a checkpoint or ``run.json`` of another identity. Then
    ``make_job(device, ctx)`` builds the network and data (not called for a finished run) and :func:`fit`
    trains it, with this process's share of the cores and a private copy of the global RNG.

    Args:
        ctx: the data-parallel context (default: :func:`~scapo.engine.distributed.dist_context`); closed here.

    Raises:
        ConfigError, OutputError: unusable folder. TrainingError: another identity, unreadable checkpoint,
        a NaN/inf loss.
    """
    folder.check_target()
    ctx = ctx or dist_context(device.type)
    device = ctx.device(device)
    try:
        if ctx.is_main:
            check_output_dir(folder.path, "run folder", own="run")
        with FolderLock(folder.path, "train") if ctx.is_main else contextlib.nullcontext():
            if ctx.is_main:
                clean_stale_temps(folder.path, any_pid=True)
            ctx.barrier()  # the other ranks start once rank 0 holds the folder
            with run_settings(per_rank_threads(training_threads(), ctx)):
                state = folder.load_checkpoint(device)
                if state is not None and state.get("done"):
                    return folder.checkpoint
                if ctx.is_main:
                    folder.write_identity()
                try:
                    c0, w0 = cpu_seconds(), time.perf_counter()
                    job = make_job(device, ctx)
                    setup = (cpu_seconds() - c0, time.perf_counter() - w0)
                    return fit(job, folder, state, device, progress, ctx, setup=setup)
                except (TrainingError, OSError) as e:
                    if ctx.is_main and not folder.checkpoint.exists():  # nothing of value was trained: a
                        folder.mark_failed(e)  # corrected rerun may start over here (RunFolder.load_checkpoint)
                    raise
    finally:
        ctx.close()


def fit(job: TrainJob, folder: RunFolder, state: dict | None, device: torch.device, progress: bool = True,
        ctx: DistContext | None = None, setup: tuple[float, float] = (0.0, 0.0)) -> Path:
    """The loop: every stage of ``job`` from the checkpoint ``state``'s next (stage, epoch) (or the start),
    a checkpoint after every epoch, the loss plot (``losses.png``) after an epoch that ends at least
    :data:`PLOT_EVERY_S` after the last one drawn, after the last epoch and at a failure, ``timing.json`` at the
    end, with the run's compute ledger (:class:`~scapo.engine.ledger.Ledger`: charged seconds by phase over every
    session, kept in the checkpoints; ``setup`` = (CPU, wall) seconds of building ``job``, charged as ``setup``).
    Returns the checkpoint path.

    Raises:
        TrainingError: a loss term became NaN or infinite (named, with stage, epoch and step).
    """
    ctx = ctx or DistContext()
    cfg = job.config
    steps = job.steps_per_epoch(ctx.world)
    start = (1, 0)
    if state is not None:
        (job.load_state or job.model.load_state_dict)(state["model"])
        start = (int(state.get("stage", 1)), int(state["epoch"]))
    if ctx.is_main:  # only rank 0 touches the log
        truncate_log(folder.log, *start)
    live = [s for s in job.stages if s.epochs > 0]
    done_before = sum(s.epochs for s in live if s.index < start[0]) + sum(
        min(start[1], s.epochs) for s in live if s.index == start[0])
    bar = None
    if progress and ctx.is_main:
        from scapo.report import progress_bar

        bar = progress_bar(total=steps * sum(s.epochs for s in live), initial=steps * done_before, desc=job.desc,
                           unit="it", dynamic_ncols=True)
    columns = list(dict.fromkeys([*BASE_COLUMNS, *[t for s in job.stages for t in s.terms]]))
    board = _tensorboard(folder, steps * done_before) if ctx.is_main else None
    t0 = plotted = time.perf_counter()
    c0 = cpu_seconds()
    before = float(state.get("seconds", 0.0)) if state is not None else 0.0  # earlier sessions' training time
    ledger = Ledger(device.type != "cpu", state.get("ledger") if state is not None else None, world=ctx.world)
    ledger.add("setup", *setup)
    compiled = compile_network(job.model) if cfg.compile else []
    # this session's "other": what fit's own phases leave of its seconds (the set-up was measured before fit)
    charged_before = {k: dict(v) for k, v in ledger.phases.items()}
    # where this session's time went, per stage (timing.json "stages"; scapo bench perf --what train --data)
    parts = {str(s.index): {"steps": 0, "step_s": 0.0, "epochs": 0, "epoch_s": 0.0, "start_s": 0.0} for s in live}
    final_s = 0.0
    try:
        for stage in live:
            if stage.index < start[0]:
                continue
            part = parts[str(stage.index)]
            first = start[1] if stage.index == start[0] else 0
            opt = torch.optim.Adam(stage.params(), lr=stage.lr, weight_decay=cfg.weight_decay)
            sched = stage.scheduler(opt, steps, cfg.min_lr)
            if state is not None and stage.index == start[0] and first > 0 and "optimizer" in state:
                opt.load_state_dict(state["optimizer"])
                sched.load_state_dict(state["scheduler"])
            name = f"stage{stage.index}"
            if first == 0 and stage.on_start is not None:
                ts = time.perf_counter()
                with ledger.phase(f"{name}/start"):
                    stage.on_start()
                part["start_s"] += time.perf_counter() - ts
            if compiled:  # compiled for this stage's step once per session, after its start
                with ledger.phase(f"{name}/compile"):
                    compiled = warm_up(job, stage, device, compiled, ctx)
            for epoch in range(first, stage.epochs):
                ts, cs = time.perf_counter(), cpu_seconds()
                with ledger.phase(f"{name}/steps"):
                    run_epoch(job, stage, epoch, opt, sched, steps, folder, bar, device, ctx, columns, board)
                    _check_weights(job.model, stage.index, epoch)  # before the checkpoint: the last good one is kept
                te = time.perf_counter()
                ce = cpu_seconds()
                # each epoch's CPU seconds of steps (timing.json): whether a step's cost drifts over the training
                part.setdefault("epoch_step_cpu_s", []).append(round(ce - cs, 2))
                part["steps"], part["epochs"], part["step_s"] = part["steps"] + steps, part["epochs"] + 1, \
                    part["step_s"] + te - ts
                last_stage = stage is live[-1]
                done = last_stage and epoch == stage.epochs - 1
                nxt = (stage.index, epoch + 1) if epoch + 1 < stage.epochs or last_stage else (
                    live[live.index(stage) + 1].index, 0)
                if done:  # the work after training runs eagerly (in eval mode, on other shapes)
                    compiled = uncompile_network(compiled)
                extras = job.extras(done) if job.extras is not None else {}
                if done:  # the final extras (e.g. statistics over the training split) happen once per run
                    final_s += time.perf_counter() - te
                    ledger.add("final", cpu_seconds() - ce, time.perf_counter() - te)
                    te, ce = time.perf_counter(), cpu_seconds()
                if ctx.is_main:  # every rank holds the same model, optimiser and schedule
                    folder.save({"model": job.model.state_dict(), "optimizer": opt.state_dict(),
                                 "scheduler": sched.state_dict(), "stage": nxt[0], "epoch": nxt[1], "done": done,
                                 "world_size": ctx.world, "seconds": before + time.perf_counter() - t0,
                                 "ledger": ledger.to_dict(), **extras})
                    if done or time.perf_counter() - plotted >= PLOT_EVERY_S:
                        plot_losses(folder.log, folder.path / "losses.png")
                        plotted = time.perf_counter()
                ctx.barrier()
                part["epoch_s"] += time.perf_counter() - te
                ledger.add(f"{name}/epochs", cpu_seconds() - ce, time.perf_counter() - te)
    except TrainingError:
        if ctx.is_main:  # the curves up to the failing step, to look at
            plot_losses(folder.log, folder.path / "losses.png")
        raise
    finally:
        uncompile_network(compiled)
        if bar is not None:
            bar.close()
        if board is not None:
            board.close()
    if ctx.is_main:  # the training time over every session that trained this run (resumes included)
        spent = {k: (v["cpu_s"] - charged_before.get(k, {}).get("cpu_s", 0.0),
                     v["wall_s"] - charged_before.get(k, {}).get("wall_s", 0.0)) for k, v in ledger.phases.items()}
        w = ledger.world  # spent is charged for every rank; this process's own seconds in fit are what remains
        ledger.add("other", cpu_seconds() - c0 - sum(c for c, _ in spent.values()) / w,
                   time.perf_counter() - t0 - sum(s for _, s in spent.values()) / w)
        folder.write_timing(before + time.perf_counter() - t0, device, ctx.world,
                            steps=sum(stage.epochs * steps for stage in live),
                            breakdown={**_breakdown(parts, final_s, time.perf_counter() - t0),
                                       "ledger": ledger.to_dict()})
    return folder.checkpoint


def compile_network(model: torch.nn.Module) -> list[torch.nn.Module]:
    """Compile, in place (as ``nn.Module.compile``: ``torch.compile`` with the default inductor backend; parameters
    and state-dict keys unchanged), each direct child of ``model`` that holds parameters; returns them. Compilation
    itself happens at their first call (:func:`warm_up`). Inductor's compiled kernels are cached on disk
    (``TORCHINDUCTOR_CACHE_DIR``, default ``~/.cache/scapo/inductor`` where it is not set), so a later run of the
    same network and shapes compiles less. Random operations inside the compiled parts draw from torch's generator as
    eagerly (inductor's ``fallback_random``; its own generator would give a run other noise and augmentations)."""

    import os

    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(Path.home() / ".cache" / "scapo" / "inductor"))
    import torch._inductor.config

    torch._inductor.config.fallback_random = True  # random numbers from torch's generator, as the eager step draws them
    torch._inductor.config.compile_threads = 1  # no worker pool: the C++ compilers are children that finish (charged)
    parts = [m for m in model.children() if any(True for _ in m.parameters())]
    for m in parts:
        m._compiled_call_impl = torch.compile(_called(m))
    return parts


def _called(module: torch.nn.Module) -> Callable:
    """``module``'s call as a function of this file, with a code object of its own (torch 2.13's ``nn.Module.compile``
    hands dynamo the bound ``_call_impl``, a frame of torch itself, which it does not trace: that module would run
    eagerly). Dynamo keeps its compiled graphs and its recompilation count per code object, so one closure shared by
    every part would give each part a recompilation of one frame and, past ``recompile_limit`` (8) parts and modes,
    run the rest eagerly after compiling them."""
    import types

    def call(*args, **kwargs):
        return module._call_impl(*args, **kwargs)

    code = call.__code__.replace(co_name=f"call_{type(module).__name__}_{id(module):x}")
    return types.FunctionType(code, call.__globals__, code.co_name, call.__defaults__, call.__closure__)


def uncompile_network(parts: list[torch.nn.Module]) -> list[torch.nn.Module]:
    """Undo :func:`compile_network` on ``parts`` (they run eagerly again); returns ``[]``."""
    for m in parts:
        m._compiled_call_impl = None
    return []


def warm_up(job: TrainJob, stage: Stage, device: torch.device, parts: list[torch.nn.Module], ctx: DistContext
            ) -> list[torch.nn.Module]:
    """Compile ``stage``'s training step: one forward and backward of its loss on a batch of the first clouds (the
    training batch's shapes), leaving the training untouched: no optimiser step, the gradients cleared, the
    network's buffers (batch-norm statistics) and every random generator (torch's, numpy's, the clouds' own) as
    they were. Returns ``parts``, or ``[]`` after a failed compilation, with a warning: the network then trains
    eagerly (the same function)."""
    import warnings

    from torch.utils.data import default_collate

    data = job.data
    n = max(1, min(job.config.batch_size, len(data) // ctx.world))
    buffers = {k: v.detach().clone() for k, v in job.model.named_buffers()}
    generator = getattr(data, "generator", None)
    np_state = np.random.get_state()  # noqa: NPY002 - restored as it was
    try:
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            if generator is not None:
                data.generator = None
            batch = {k: v.to(device) for k, v in default_collate([data[i] for i in range(n)]).items()}
            _, total = stage.losses(batch, 0.0)
            total.backward()
    except Exception as e:  # noqa: BLE001 - any failure of the compiler: train eagerly
        warnings.warn(f"scapo: torch.compile failed for stage {stage.index} ({type(e).__name__}: "
                      f"{str(e).splitlines()[0] if str(e) else ''}); training eagerly", RuntimeWarning, stacklevel=2)
        parts = uncompile_network(parts)
    finally:
        if generator is not None:
            data.generator = generator
        np.random.set_state(np_state)  # noqa: NPY002
        job.model.zero_grad(set_to_none=True)
        with torch.no_grad():
            for k, v in job.model.named_buffers():
                v.copy_(buffers[k])
    return parts


def _breakdown(parts: dict, final_s: float, session_s: float) -> dict:
    """timing.json's record of where a session's time went: the per-stage parts, the final extras, the session's
    seconds and ``other_s``, the rest (optimiser set-up between stages, closing the TensorBoard writer), so the
    parts sum to the session."""
    done = sum(p["step_s"] + p["epoch_s"] + p["start_s"] for p in parts.values()) + final_s
    return {"stages": {k: {n: round(v, 3) if isinstance(v, float) else v for n, v in p.items()}
                       for k, p in parts.items()},
            "final_s": round(final_s, 3), "other_s": round(max(session_s - done, 0.0), 3),
            "session_s": round(session_s, 3)}


def _check_weights(model: torch.nn.Module, stage: int, epoch: int) -> None:
    """Raise TrainingError when a weight of ``model`` is NaN or infinite (an optimiser step can make them so while
    every loss it saw was finite, e.g. at an extreme learning rate), naming the first such tensor."""
    bad = [n for n, p in model.named_parameters() if not bool(torch.isfinite(p).all())]
    if bad:
        raise TrainingError(f"{len(bad)} weight tensor(s) became NaN or infinite in stage {stage}, epoch {epoch} "
                            f"(first: {bad[0]}); the checkpoint of the last finished epoch is kept; lower the stage's "
                            "learning rate or the gradient clip and train into a new run folder")


def epoch_batches(data: CloudSet, cfg: FitConfig, seed: int, ctx: DistContext) -> Iterable[dict]:
    """The batches of one epoch seeded by ``seed`` on this rank (see :attr:`FitConfig.order`)."""
    share = len(data) // ctx.world
    if cfg.order == "permutation":
        g = torch.Generator().manual_seed(seed)
        torch.randperm(len(data), generator=g)  # the sampler's permutation; the subsets' stream continues after it
        data.generator = g
        sampler = DistributedSampler(data, num_replicas=ctx.world, rank=ctx.rank, shuffle=True, seed=seed,
                                     drop_last=True)
        return DataLoader(data, batch_size=cfg.batch_size, sampler=sampler, drop_last=share >= cfg.batch_size,
                          generator=torch.Generator())  # the loader's own seed draw leaves the global RNG alone
    data.generator = None
    if ctx.active:
        sampler = DistributedSampler(data, num_replicas=ctx.world, rank=ctx.rank, shuffle=True, seed=seed,
                                     drop_last=True)
        return DataLoader(data, batch_size=cfg.batch_size, sampler=sampler, drop_last=share >= cfg.batch_size)
    return DataLoader(data, batch_size=cfg.batch_size, shuffle=True, drop_last=len(data) >= cfg.batch_size,
                      generator=torch.Generator().manual_seed(seed))


def _tensorboard(folder: RunFolder, start_step: int):
    """A TensorBoard writer into ``RUN/tensorboard/`` (the ``tensorboard`` extra), or None where it is not installed.
    A resumed run drops the events of the steps it trains again (``purge_step``)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # optional: pip install 'scapo[tensorboard]'
        return None
    return SummaryWriter(log_dir=str(folder.path / "tensorboard"), purge_step=start_step)


def run_epoch(job: TrainJob, stage: Stage, epoch: int, opt, sched, steps: int, folder: RunFolder, bar, device,
              ctx: DistContext, columns: list[str], board=None) -> None:
    """One epoch of ``stage``: ``steps`` optimiser steps, one ``log.csv`` row each (rank 0), and the same scalars
    as TensorBoard events where ``board`` (a ``SummaryWriter``) is given (tag ``stage<k>/<term>``).

    Raises:
        TrainingError: a loss term became NaN or infinite.
    """
    cfg = job.config
    seed = cfg.seed * 1_000_003 + stage.index * 10_007 + epoch
    rank_seed = seed + 7_919 * ctx.rank  # augmentations and point subsets differ between ranks
    torch.manual_seed(rank_seed)
    np.random.seed(rank_seed % (2 ** 32))  # noqa: NPY002 - any legacy-numpy randomness in a run is seeded too
    loader = epoch_batches(job.data, cfg, seed, ctx)
    job.model.train()
    log = folder.log
    new_file = not log.is_file()
    multi = len([s for s in job.stages if s.epochs > 0]) > 1
    first_step = (sum(s.epochs for s in job.stages if s.epochs > 0 and s.index < stage.index) + epoch) * steps
    with open(log, "a", newline="") if ctx.is_main else contextlib.nullcontext() as f:
        writer = None
        for step, batch in enumerate(loader):
            if step >= steps:
                break
            batch = {k: v.to(device) for k, v in batch.items()}
            terms, total = stage.losses(batch, (epoch * steps + step) / max(1, stage.epochs * steps))
            for name, value in terms.items():
                if not torch.isfinite(value):
                    raise TrainingError(f"loss {name!r} became {float(value.detach())} at stage {stage.index}, "
                                        f"epoch {epoch}, step {step}; training stopped (last good checkpoint kept)")
            opt.zero_grad(set_to_none=True)
            total.backward()
            ctx.average_gradients(job.model.parameters())
            if cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_(job.model.parameters(), cfg.grad_clip)
            opt.step()
            sched.step()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(**({"stage": stage.index} if multi else {}), loss=f"{float(total.detach()):.4f}")
            if f is None:  # ranks other than 0 write nothing; the log holds rank 0's losses
                continue
            row = {"stage": stage.index, "epoch": epoch, "step": step, "lr": sched.get_last_lr()[0],
                   "total": float(total.detach()), **{k: float(v.detach()) for k, v in terms.items()}}
            if writer is None:
                fields = columns if len(columns) > len(BASE_COLUMNS) else [*BASE_COLUMNS, *terms]
                if not new_file:  # a resumed run keeps its log's columns (written by the scapo it started with)
                    with open(log, newline="") as g:
                        fields = next(csv.reader(g), None) or fields
                writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
                if new_file:
                    writer.writeheader()
            writer.writerow(row)
            if board is not None:
                for k in ("lr", "total", *terms):
                    board.add_scalar(f"stage{stage.index}/{k}", row[k], first_step + step)
