"""One training-run lifecycle for every trained method: resolve the preset once, then train with the engine.

A trained method describes itself with a :class:`RunSpec` (its presets, how a ``run.json`` names the preset a run
was started with, the run's identity, and its training job); :func:`train` is the only place where a run is set up:

1. the preset: the one given (a name, resolved by the method, or a preset object), else the run folder's own
   (from its ``run.json``, so that resuming a run or ``scapo train --set`` on it starts from what it was
   trained with), else :data:`DEFAULT_PRESET`;
2. ``overrides`` (``scapo train --set`` / ``--config``: field -> value, dotted for nested settings) replace fields of
   that preset, checked against its dataclass (:func:`scapo.config.override`);
3. ``seed`` replaces the preset's training seed, checked once here;
4. the run folder's identity (``spec.identity(preset, training card)``), then :func:`scapo.engine.loop.train_run`
   (checks, lock, resume, ``spec.job(preset, data, run, device, ctx)``, the loop).

``scapo train`` -> :func:`scapo.methods.train_method` -> the method's entry (``RunSpec``) -> :func:`train` -> the
engine's loop reads the stages' epochs from the job: one pass downward.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from scapo.engine.distributed import DistContext
from scapo.engine.loop import TrainJob, train_run
from scapo.engine.runs import RunFolder, read_run_json, resolve_device
from scapo.errors import ConfigError, DatasetError, warn_few_instances

#: The preset of a new run when none is given (a resumed run keeps its own).
DEFAULT_PRESET = "cpu"
#: Training seeds are numpy/torch seeds: integers in [0, 2**32).
MAX_TRAIN_SEED = 2 ** 32


@dataclass(frozen=True)
class RunSpec:
    """What the engine needs from a trained method to set up and train one run.

    Attributes:
        method: the registry name (``scapo train --method NAME``).
        preset: ``preset(name) -> preset object`` (a frozen dataclass with ``name``, ``seed`` and ``device``
            fields); raises UnknownNameError for a name the method does not take.
        stored_preset: ``stored_preset(run_json: dict) -> preset object | None``: the preset a run folder of this
            method was started with (None when ``run_json`` is not such a run's).
        identity: ``identity(preset, card) -> dict``: the run's ``run.json`` (preset fields, dataset hash, the
            category's structure) from the training split's card.
        job: ``job(preset, data, run, device, ctx) -> TrainJob``: the network (initialised from ``preset.seed``),
            the training clouds of dataset folder ``data`` and the stages (``run``: the run folder, for files a job
            writes besides the engine's); called once the run folder is checked, only for a run not finished.
        compare: ``compare(identity) -> dict``: the part of an identity that decides whether a checkpoint fits
            (e.g. without inference-only fields); None compares the whole identity.
        check: ``check(preset, card, training_clouds)``: the method's relations between its preset and the data,
            raising ConfigError before anything is written (None: the engine's own checks only).
    """

    method: str
    preset: Callable[[str], Any]
    stored_preset: Callable[[dict], Any]
    identity: Callable[[Any, dict], dict]
    job: Callable[[Any, Path, Path, torch.device, DistContext], TrainJob]
    compare: Callable[[dict], dict] | None = None
    check: Callable[[Any, dict, int], None] | None = None


def check_seed(seed, what: str = "training seed") -> None:
    """Raise ConfigError unless ``seed`` is None or an integer in ``[0, 2**32)``."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < MAX_TRAIN_SEED):
        raise ConfigError(f"{what} must be an integer in [0, 2**32), got {seed!r}")


def run_preset(spec: RunSpec, run: str | Path | None = None, preset=None, overrides: Mapping[str, Any] | None = None,
               seed: int | None = None):
    """The preset object a run trains with (steps 1-3 of the module docstring).

    Args:
        run: the run folder (its ``run.json`` names its own preset when ``preset`` is None); None: a new run.
        preset: a preset name, a preset object, or None. overrides: field -> value (text values are converted).
        seed: replaces the preset's seed.

    Raises:
        UnknownNameError: an unknown preset name. ConfigError: an unknown field or a bad value in ``overrides``,
            a seed that is not an integer in [0, 2**32), a damaged ``run.json`` where the run's own preset is read.
    """
    from scapo.config import override

    if preset is None:
        stored = read_run_json(run) if run is not None else None
        if run is not None and stored is None and (Path(run) / "run.json").is_file():
            raise ConfigError(f"{Path(run) / 'run.json'} is damaged (not a JSON object): a run resumed without "
                              "--preset reads its preset there. Give --preset NAME (the run's own preset) to resume, "
                              "or restore run.json; its checkpoint is kept")
        preset = (spec.stored_preset(stored) if isinstance(stored, dict) else None) or DEFAULT_PRESET
    pc = spec.preset(preset) if isinstance(preset, str) else preset
    if overrides:
        if seed is not None and "seed" in overrides:
            raise ConfigError(f"the training seed is given twice (--seed {seed} and --set seed="
                              f"{overrides['seed']}); give it once")
        pc = override(pc, dict(overrides), f"{spec.method} preset")
    check_seed(seed)
    check_seed(getattr(pc, "seed", None), "training seed (the preset's seed field)")
    if seed is not None:
        pc = dataclasses.replace(pc, seed=int(seed))
    return pc


def _training_card(data: str | Path, batch_size: int | None = None) -> tuple[dict, int, int]:
    """The training split's card, clouds and instances, after the checks every trained method needs."""
    from scapo.data.dataset import load

    train = load(data, "train")
    if len(train) == 0:
        raise DatasetError(f"{data}: the training split is empty; generate a dataset with training instances")
    if not train.card.get("joint_type"):
        raise ConfigError(f"{data} is a dataset of {train.card.get('category')!r}, which has no movable joint: the "
                          "trained methods estimate articulated poses (parts and joints); use an articulated object")
    if batch_size is not None and batch_size > len(train):  # the engine drops a last partial batch: no step at all
        raise ConfigError(f"the batch size {batch_size} exceeds the {len(train)} training clouds of {data}: no "
                          f"training step would run; set batch_size to {len(train)} or fewer")
    return train.card, len(train), train.num_instances


def train(spec: RunSpec, data: str | Path, run: str | Path, preset=None, *, seed: int | None = None,
          overrides: Mapping[str, Any] | None = None, device: str | None = None, progress: bool = True) -> Path:
    """Train (or resume, or find finished) one run of ``spec``'s method; returns the checkpoint path.

    Args:
        data: dataset folder (its training split). run: run folder. preset, overrides, seed: :func:`run_preset`.
        device: overrides the preset's device (``cpu``, ``cuda``, ``auto``).

    Raises:
        As :func:`run_preset`. ConfigError: ``overrides`` for a finished run (nothing would change); a preset that
        trains on more points per cloud than the dataset's clouds have; an unusable run folder. DatasetError: an
        empty training split. OutputError: an unwritable run folder. TrainingError: a checkpoint or ``run.json`` of
        another method, preset, seed or dataset, an unreadable checkpoint, a NaN/inf loss or weight (the last good
        checkpoint is kept).
    """
    if overrides and (Path(run) / "timing.json").is_file():
        raise ConfigError(f"{run} is a finished run: --set and --config change nothing of it (a finished run is never "
                          f"trained again); give prediction settings to 'scapo predict --run {run} --option "
                          "KEY=VALUE', and train another run (another --out) for other training settings")
    pc = run_preset(spec, run, preset, overrides, seed)
    card, clouds, instances = _training_card(data, getattr(pc, "batch_size", None))
    if os.environ.get("RANK", "0") == "0":  # under torchrun, rank 0 speaks for the run
        warn_few_instances(instances, "train", data, "a model trained on it and its scores")
    if spec.check is not None:
        spec.check(pc, card, clouds)
    stored = card.get("num_points")
    wanted = getattr(pc, "train_points", getattr(pc, "points", None))
    if isinstance(stored, int) and isinstance(wanted, int) and wanted > stored:
        raise ConfigError(f"the preset trains on {wanted} points per cloud, but {data}'s clouds have {stored}; set "
                          f"the preset's points to {stored} or fewer, or generate the dataset with --points {wanted}")
    folder = RunFolder(Path(run), spec.identity(pc, card), spec.compare)
    dev = resolve_device(device or getattr(pc, "device", "auto"))
    return train_run(folder, lambda d, ctx: spec.job(pc, Path(data), Path(run), d, ctx), dev, progress)


def run_is_current(spec: RunSpec, run: str | Path, data: str | Path, preset, seed: int | None = None) -> bool:
    """Whether ``run`` holds the run ``train(spec, data, run, preset, seed=seed)`` would start now: its
    ``run.json`` has the training identity of the preset as registered today (False without a readable
    ``run.json``, or when the preset's training fields changed since: its results are stale).

    Raises:
        UnknownNameError: an unknown preset name."""
    pc = run_preset(spec, None, preset, None, seed)
    return RunFolder(Path(run), spec.identity(pc, _training_card(data)[0]), spec.compare).is_current()
