"""The learned baselines' side of training and inference (OP-Align-style, EAP-style, NPCS-style); the
training loop and the run folder are the engine's (:mod:`scapo.engine`).

A learned baseline module provides a :class:`LearnedSpec`: its preset registry, the dataset fields its
training reads (``points`` only for the self-supervised ones), and a network class with ``losses``
(one training step's loss terms and weighted total) and ``infer`` (outputs for a batch of clouds).
This harness does the rest, the same way for every such method, as ``scapo train`` does for SCAPO:

- ``scapo train --method NAME --preset P --out RUN [--seed S]`` trains into a run folder holding
  ``run.json`` (method, preset, dataset, structure), ``checkpoint.pt`` (written atomically after every
  epoch with optimiser, schedule and RNG seeds, so a resumed run continues where it stopped),
  ``log.csv`` (one row per step), ``losses.png`` and ``timing.json``;
- a run folder of another method, preset, seed or dataset is refused before anything is written; a
  file, a foreign folder, another process training into it, an unreadable checkpoint and a NaN loss
  are clear errors (the last good checkpoint is kept);
- ``scapo predict --run RUN`` loads a finished run (never trains) and checks that it was trained on
  the dataset's category and kinematic structure.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from scapo.data.dataset import ArticulationDataset, load
from scapo.engine import CloudSet, FitConfig, Stage, TrainJob, lifecycle
from scapo.engine.lifecycle import RunSpec
from scapo.engine.runs import read_checkpoint, resolve_device
from scapo.errors import ConfigError, TrainingError
from scapo.eval.predictions import Predictions
from scapo.registry import Registry, apply_schedule, parse_preset
from scapo.steps import StepOptions, StepPipeline, training_views


@dataclass(frozen=True)
class LearnedPreset:
    """Training settings every learned baseline has (a method's preset class adds its own fields)."""

    name: str = "cpu"
    epochs: int = 40
    """Passes over the training clouds."""
    batch_size: int = 16
    lr: float = 1e-3
    """Adam learning rate, annealed to ``min_lr`` by a cosine schedule."""
    min_lr: float = 1e-5
    weight_decay: float = 1e-6
    points: int = 512
    """Points per training cloud (a random subset each step)."""
    max_steps_per_epoch: int = 0
    """0: every batch; otherwise at most this many steps per epoch."""
    grad_clip: float = 1.0
    seed: int = 0
    device: str = "auto"
    iterations: int = 0
    """> 0: train this many optimiser steps (the epochs follow from the training split's size; the originals'
    schedules count iterations) instead of ``epochs``."""
    lr_schedule: str = "cosine"
    """``"cosine"`` to ``min_lr``, or ``"step"``: ``lr_decay`` every ``lr_decay_steps`` steps
    (:class:`~scapo.engine.loop.Stage`)."""
    lr_decay: float = 0.5
    lr_decay_steps: int = 5000
    compile: bool = False
    """Compile the network's parts for the training steps (``torch.compile``,
    :func:`scapo.engine.loop.compile_network`); the compilation is charged to the run's ledger
    (``stage<k>/compile``)."""

    def __post_init__(self):
        from scapo.config import check_settings

        try:  # every float finite (a subclass's own fields too); the training fields in range
            check_settings(self, positive=("grad_clip",), non_negative=("min_lr", "weight_decay"))
        except ValueError as e:
            raise ConfigError(f"preset {self.name!r}: {e}") from None
        if self.lr > 0 and self.min_lr > self.lr:
            raise ConfigError(f"preset {self.name!r}: min_lr {self.min_lr} exceeds lr {self.lr} (the cosine schedule "
                              "falls from lr to min_lr)")
        bad = [k for k, ok in {"epochs": self.epochs >= 1, "batch_size": self.batch_size >= 1, "lr": self.lr > 0,
                                "points": self.points >= 64, "seed": self.seed >= 0,
                                "max_steps_per_epoch": self.max_steps_per_epoch >= 0,
                                "iterations": self.iterations >= 0,
                                "lr_schedule": self.lr_schedule in ("cosine", "step"),
                                "lr_decay": 0 < self.lr_decay <= 1, "lr_decay_steps": self.lr_decay_steps >= 1,
                                }.items() if not ok]
        if bad:
            raise ConfigError(f"invalid preset value(s) {', '.join(f'{k}={getattr(self, k)!r}' for k in bad)}: need "
                              "epochs >= 1, batch_size >= 1, lr > 0, points >= 64, seed >= 0, "
                              "max_steps_per_epoch >= 0, iterations >= 0, lr_schedule cosine | step, "
                              "0 < lr_decay <= 1, lr_decay_steps >= 1")


@dataclass(frozen=True)
class LearnedSpec:
    """What a learned baseline module gives the harness.

    Attributes:
        method: registry name. presets: name -> preset (a :class:`LearnedPreset` subclass).
        fields: dataset array fields read for training (``("points",)`` for self-supervised methods).
        build: ``build(card, preset) -> network`` (an ``nn.Module`` with ``losses(batch, progress)
            -> (terms: dict[str, Tensor], total: Tensor)``, ``progress`` in [0, 1] the fraction of
            training done, and ``infer(points (B, N, 3) metres) -> dict`` of numpy outputs).
        extras: optional ``extras(network, train_arrays) -> dict`` computed once after training from the
            training split's ``extras_fields`` (e.g. rest-state statistics) and stored in the checkpoint;
            the network gets it back through ``network.set_extras(dict)`` at load time.
        extras_fields: dataset fields ``extras`` reads (default: ``fields``).
        options: the method's prediction options (a :class:`LearnedOptions` subclass); a network with a
            ``configure(options)`` method gets them after loading.
        derive: optional ``derive(train_arrays, card, preset) -> dict`` of per-cloud training targets computed once
            from the training split's arrays (with ``instance_id`` and ``view_id``), e.g. statistics over all
            views of an instance (NPCS-style's per-part boxes); each value is ``(M, ...)`` over the ``M`` clouds
            and reaches ``losses`` in the batch whole (not subsampled with the points).
    """

    method: str
    presets: Registry
    fields: tuple[str, ...]
    build: Callable[[dict, Any], torch.nn.Module]
    extras: Callable[[torch.nn.Module, dict], dict] | None = None
    extras_fields: tuple[str, ...] | None = None
    options: type | None = None
    derive: Callable[[dict, dict, Any], dict] | None = None


def _preset_from_dict(cls: type, d: dict):
    return cls(**{f.name: (tuple(d[f.name]) if isinstance(d[f.name], list) else d[f.name])
                  for f in dataclasses.fields(cls) if f.name in d})


#: preset fields added after runs were trained, with the value those runs had: left out of a run's identity
#: at that value, so older runs keep their identity
ADDED_FIELDS = {"supervision": "", "sup_weight": 1.0, "part_npcs": False, "compile": False}


def resolve_preset(spec: LearnedSpec, preset):
    """A preset object from a name of ``spec.presets`` or ``"BASE/sj"`` (``/s``, ``/j``): the semi-supervised
    setting of the paper's Table 2 (:mod:`scapo.losses.supervised`) for methods whose preset has a
    ``supervision`` field; its ``name`` is the full string (:func:`scapo.registry.parse_preset`). A part
    ``epochs-N`` (``iterations-N``) sets the schedule (:func:`scapo.registry.apply_schedule`).

    Raises:
        UnknownNameError: unknown base preset, or a suffix this method does not take."""
    from scapo.errors import UnknownNameError

    if not isinstance(preset, str):
        return preset
    name = parse_preset(preset)
    pc = spec.presets.get(name.base)
    if not name.mods:
        return pc
    pc = apply_schedule(pc, name, preset)  # epochs-N / iterations-N (a budget's schedule)
    if len(name.mods) == len(name.schedule):
        return pc
    sup = name.supervision
    if len(name.mods) != len(name.schedule) + 1 or sup is None or not hasattr(pc, "supervision"):
        raise UnknownNameError(f"unknown {spec.method} preset {preset!r}: "
                               + ("its presets take a suffix /sj, /s or /j (training with segmentation and / or joint "
                                  "labels)" if hasattr(pc, "supervision") else "it takes no suffix (no supervised "
                                                                              "setting)"))
    return dataclasses.replace(pc, name=preset, supervision=sup)


def _identity(spec: LearnedSpec, preset, card: dict) -> dict:
    fields = {k: v for k, v in dataclasses.asdict(preset).items() if not (k in ADDED_FIELDS and v == ADDED_FIELDS[k])}
    return {"method": spec.method, "preset": fields, "dataset_hash": card["dataset_hash"],
            "category": card["category"], "part_names": list(card["part_names"]),
            "joint_type": list(card["joint_type"]), "joint_parts": [list(p) for p in card["joint_parts"]]}


def run_spec(spec: LearnedSpec) -> RunSpec:
    """``spec`` as the engine's run lifecycle sees it (:class:`scapo.engine.lifecycle.RunSpec`): presets by
    :func:`resolve_preset`, a run's own preset from its ``run.json`` (``method`` must be ``spec.method``), the
    identity of :func:`_identity` and the job of :func:`learned_job`."""
    cls = type(spec.presets.get(spec.presets.names()[0]))

    def stored(ident: dict):
        if ident.get("method") != spec.method or not isinstance(ident.get("preset"), dict):
            return None
        try:
            return _preset_from_dict(cls, ident["preset"])
        except (TypeError, ValueError, KeyError):
            return None

    return RunSpec(method=spec.method, preset=lambda name: resolve_preset(spec, name), stored_preset=stored,
                   identity=lambda pc, card: _identity(spec, pc, card),
                   job=lambda pc, data, run, dev, ctx: learned_job(spec, pc, load(data, "train"), dev))


def train_learned(spec: LearnedSpec, data: str | Path, run: str | Path, preset=None, progress: bool = True,
                  device: str | None = None, seed: int | None = None, overrides: dict | None = None) -> Path:
    """Train (or resume) a learned baseline into the run folder ``run`` with the engine's run lifecycle
    (:func:`scapo.engine.lifecycle.train`: ``preset`` None resumes a run with its own preset and starts a new one
    with ``cpu``; ``overrides`` replace preset fields; ``seed`` the preset's seed, a different run) and one stage
    of ``spec.build(card, preset).losses``; returns the checkpoint path.

    Raises:
        UnknownNameError: unknown preset. ConfigError: bad seed, override, device, or run folder (a file or a
        foreign non-empty folder). OutputError: run folder not writable. DatasetError: empty training
        split or missing fields. TrainingError: a checkpoint or run.json of another method, preset, seed
        or dataset; an unreadable checkpoint; a NaN/inf loss (the last good checkpoint is kept).
    """
    return lifecycle.train(run_spec(spec), data, run, preset, seed=seed, overrides=overrides, device=device,
                           progress=progress)


def learned_job(spec: LearnedSpec, pc, train: ArticulationDataset, dev: torch.device) -> TrainJob:
    """The engine's job for a learned baseline: ``spec.build(card, pc)`` (initialised from ``pc.seed``), one
    stage of ``pc.epochs`` over its ``losses(batch, progress)`` (or the stages of the network's
    ``training_stages()``: dicts of :class:`~scapo.engine.loop.Stage` fields without the learning rate and schedule,
    which are the preset's), the training split's ``spec.fields`` (and the
    labels ``pc.supervision`` allows) subsampled to ``pc.points`` points; ``spec.extras`` stored with the
    final checkpoint."""
    from scapo.losses.supervised import supervised_fields

    fields = list(dict.fromkeys([*spec.fields, *supervised_fields(getattr(pc, "supervision", ""))]))
    arrays = train.arrays(fields)
    tensors = {k: torch.from_numpy(np.ascontiguousarray(arrays[k])) for k in fields}
    if spec.derive is not None:
        derived = spec.derive(arrays, train.card, pc)
        tensors.update({k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in derived.items()})
    torch.manual_seed(pc.seed)  # parameter initialisation is part of the run's identity
    net = spec.build(train.card, pc).to(dev)

    def extras(done: bool) -> dict:
        if not done or spec.extras is None:
            return {"extras": None}
        net.eval()
        return {"extras": spec.extras(net, train.arrays(list(spec.extras_fields or spec.fields)))}

    cfg = FitConfig(batch_size=pc.batch_size, weight_decay=pc.weight_decay, min_lr=pc.min_lr, grad_clip=pc.grad_clip,
                    max_steps_per_epoch=pc.max_steps_per_epoch, seed=pc.seed, order="permutation",
                    compile=pc.compile)
    data = CloudSet(tensors, pc.points)
    sched = {"lr": pc.lr, "schedule": pc.lr_schedule, "decay": pc.lr_decay, "decay_steps": pc.lr_decay_steps}
    if hasattr(net, "training_stages"):  # a network with stages of its own (EAP-style: the whole object first)
        stages = [Stage(**sched, **kw) for kw in net.training_stages()]
    else:
        epochs = pc.epochs
        if pc.iterations > 0:  # the original's iteration count on one process: epochs of this training split
            per_epoch = TrainJob(model=net, data=data, stages=[], config=cfg).steps_per_epoch(1)
            epochs = max(1, -(-pc.iterations // per_epoch))
        stages = [Stage(index=1, epochs=epochs, params=lambda: list(net.parameters()), losses=net.losses, **sched)]
    return TrainJob(model=net, data=data, stages=stages, config=cfg, extras=extras,
                    desc=f"train {spec.method} {train.card['category']} ({pc.name})")


# ---------------------------------------------------------------------------------------------- predict
@dataclass(frozen=True)
class _RunOptions:
    run: Path | None = None
    """Run folder written by ``scapo train --method NAME``; required. Prediction never trains."""
    device: str | None = None
    """cpu | cuda | cuda:N (default: CUDA when available)."""
    batch_size: int = 32
    """Clouds per inference batch."""
    label: str = ""
    """Method name written into the predictions (default: the method's name and the steps' labels,
    :meth:`scapo.steps.StepOptions.label_suffix`)."""
    cross_category: bool = False
    """Allow predicting on a dataset of another category with the same kinematic structure."""
    progress: bool = False


@dataclass(frozen=True)
class LearnedOptions(StepOptions, _RunOptions):
    """Options of a learned baseline at prediction time (``scapo predict --run RUN --option k=v``): the run and how
    it is read (``run``, ``device``, ``batch_size``, ``label``, ``cross_category``, ``progress``) and the prediction
    steps every trained method takes alike (:class:`scapo.steps.StepOptions`: ``refine``, ``hinge``..., all off by
    default)."""

    def __post_init__(self):
        super().__post_init__()  # the steps' rules
        if self.batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1, got {self.batch_size}")
        if self.label:  # it names the evaluator's output files: it must stay inside their folder
            from scapo.files import check_name

            check_name(self.label, "label")


def training_points(train: ArticulationDataset, most: int = 512) -> np.ndarray:
    """The points ``(V, N, 3)`` of up to ``most`` evenly spaced views of ``train`` (:func:`training_views`)."""
    pts = train.arrays(["points"])["points"]
    return pts[training_views(len(pts), most)]


def check_run_fits(run: Path, ident: dict, data: ArticulationDataset, cross_category: bool, todo: str) -> None:
    """Refuse to predict ``data`` with a run (identity ``ident``: category, part_names, joint_type,
    joint_parts) of another kinematic structure, or of another category unless ``cross_category``.

    Raises:
        ConfigError: naming the run's and the dataset's category and structure, and ``todo``.
    """
    card = data.card
    same = (len(ident["part_names"]) == len(card["part_names"])
            and [int(t) for t in ident["joint_type"]] == [int(t) for t in card["joint_type"]]
            and [list(map(int, p)) for p in ident["joint_parts"]] == [list(map(int, p)) for p in card["joint_parts"]])
    what = (f"run {run} was trained on {ident['category']!r} ({structure_text(ident)}), but {data.root} is "
            f"{card['category']!r} ({structure_text(card)})")
    if not same:
        raise ConfigError(f"{what}: a model predicts only the structure it was trained on; {todo}")
    if ident["category"] != card["category"] and not cross_category:
        raise ConfigError(f"{what}; train a run on this category, or pass --option cross_category=true to predict "
                          "across categories anyway")


def structure_text(d: dict) -> str:
    """``"2 parts (base, lid), joints: revolute"`` for a dataset card or a run identity."""
    kinds = ", ".join("revolute" if t == 0 else "prismatic" for t in d["joint_type"]) or "none"
    return f"{len(d['part_names'])} parts ({', '.join(d['part_names'])}), joints: {kinds}"


class LearnedMethod:
    """A learned baseline in the method registry: loads a finished run and predicts (never trains).

    Raises (from :meth:`fit`):
        ConfigError: no ``run`` given; a run of another method, kinematic structure, or (without
            ``cross_category``) category. TrainingError: no finished run in the folder, or an
            unreadable checkpoint.
    """

    def __init__(self, spec: LearnedSpec, supervision: dict, needs_alignment: bool, options: LearnedOptions):
        self.spec = spec
        self.name = spec.method
        self.supervision = dict(supervision)
        self.needs_alignment = needs_alignment
        self.options = options
        if options.run is None:
            raise ConfigError(f"the {spec.method} method needs a trained run: --run RUN (a folder written by "
                              f"'scapo train --method {spec.method}')")
        self.run = Path(options.run)
        self.label = options.label or (spec.method + options.label_suffix())
        self.net = None
        self.steps: StepPipeline | None = None
        """The prediction steps (:class:`scapo.steps.StepPipeline`), made by :meth:`load`, fitted by :meth:`fit`."""

    def fit(self, train: ArticulationDataset) -> None:
        """Load the finished run (:meth:`load`), check it against ``train``'s category and structure, and fit the
        prediction steps that need it on the training split (:meth:`scapo.steps.StepPipeline.fit`)."""
        self.load(f"--data {train.root} ")
        check_run_fits(self.run, self.identity, train, self.options.cross_category, f"train a run on this dataset "
                       f"first ('scapo train --method {self.spec.method} --data {train.root} --out RUN')")
        self.steps.fit(train.arrays(["points"])["points"], self._infer)

    def load(self, data_hint: str = "") -> LearnedMethod:
        """Load the finished run (no dataset needed; :func:`scapo.methods.load`); returns self.

        Raises:
            TrainingError: no checkpoint, an unreadable one (damaged, or not a scapo checkpoint), an unfinished run.
            ConfigError: a run of another method; an unknown or unavailable device.
        """
        o = self.options
        ck = self.run / "checkpoint.pt"
        hint = f"train it first: scapo train --method {self.spec.method} {data_hint or '--data DATA '}--out {self.run}"
        if not ck.is_file():
            raise TrainingError(f"{self.run} holds no checkpoint; {hint}")
        dev = resolve_device(o.device or "auto")
        state = read_checkpoint(ck, dev)
        ident = state.get("identity", {})
        if ident.get("method") != self.spec.method:
            raise ConfigError(f"{self.run} is a run of method {ident.get('method', 'scapo')!r}, not "
                              f"{self.spec.method!r}")
        if not state.get("done"):
            raise TrainingError(f"{self.run} is an unfinished run (epoch {state.get('epoch')}); resume it: "
                                f"scapo train --method {self.spec.method} --out {self.run} --data ...")
        cls = type(self.spec.presets.get(self.spec.presets.names()[0]))
        self.preset = _preset_from_dict(cls, ident["preset"])
        self.net = self.spec.build(ident, self.preset).to(dev)
        self.net.load_state_dict(state["model"])
        if state.get("extras") is not None:
            self.net.set_extras(state["extras"])
        if hasattr(self.net, "configure"):
            self.net.configure(o)
        self.net.eval()
        self.device = dev
        self.identity = ident
        sup = getattr(self.preset, "supervision", "")
        if sup:  # the semi-supervised setting: its marks, and a label of its own unless one was given
            from scapo.losses.supervised import supervision_marks

            self.supervision = supervision_marks(sup)
            if not o.label:
                self.label = f"{self.spec.method}-{sup.lower()}" + o.label_suffix()
        if o.refine and self.spec.method not in refinable_methods():
            raise ConfigError(f"method {self.spec.method!r} has no canonical shape or template for the test-time "
                              f"refinement; --refine applies to: {', '.join(refinable_methods())}")
        self.steps = StepPipeline(o, ident["joint_type"], ident["joint_parts"], "template", o.batch_size)
        return self

    @property
    def module(self) -> torch.nn.Module:
        """The trained network (an ``nn.Module``, in eval mode); None before :meth:`load`."""
        return self.net

    @torch.no_grad()
    def predict_points(self, points) -> dict[str, np.ndarray]:
        """The network's outputs for clouds ``points (B, N, 3)`` (camera frame, metres; numpy or torch): numpy
        arrays ``part_label (B, N)``, ``part_pose (B, P, 4, 4)``, ``joint_axis``, ``joint_pivot (B, J, 3)``,
        ``joint_state (B, J)``, ``T_cam_obj (B, 4, 4)`` (one-pass, even with the ``refine`` option), and for a
        refinable method ``template (B, M, 3)``, ``template_label (B, M)`` (:mod:`scapo.steps.refine`).

        Raises:
            InputError: not a finite ``(B, N, 3)`` array of real numbers. TrainingError: not loaded."""
        if self.net is None:
            raise TrainingError(f"{self.run} is not loaded; call load() (or scapo.methods.load(run)) first")
        return self._infer(check_clouds(points))

    @torch.no_grad()
    def _infer(self, points: np.ndarray, progress: str = "") -> dict[str, np.ndarray]:
        """The network's one-pass outputs for ``points (M, N, 3)`` in batches (a tqdm bar titled ``progress``)."""
        it = range(0, len(points), self.options.batch_size)
        if progress:
            from scapo.report import progress_bar

            it = progress_bar(it, desc=progress, unit="batch")
        outs = []
        for i in it:
            X = torch.from_numpy(np.ascontiguousarray(points[i:i + self.options.batch_size])).float()
            outs.append(self.net.infer(X.to(self.device)))
        return {k: np.concatenate([d[k] for d in outs]) for k in outs[0]} if outs else {}

    @torch.no_grad()
    def predict(self, dataset: ArticulationDataset) -> Predictions:
        """Predictions for every sample of ``dataset`` (batches of ``batch_size`` clouds, no gradient);
        only the ``points`` are read."""
        a = dataset.arrays(["points"])
        M = len(a["points"])
        t0 = time.perf_counter()
        o = self._infer(a["points"], f"{self.spec.method} {dataset.split}" if self.options.progress else "")
        o = self.steps.apply(a["points"], o)
        info = self.steps.info(o)
        seconds = time.perf_counter() - t0
        jt = np.array(self.identity["joint_type"], dtype=np.int64)
        jp = np.array(self.identity["joint_parts"], dtype=np.int64).reshape(-1, 2)
        return Predictions(
            method=self.label, instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(M, dataset.split),
            part_label=o["part_label"].astype(np.int64), part_pose=o["part_pose"].astype(np.float64),
            joint_parts=np.tile(jp, (M, 1, 1)), joint_type=np.tile(jt, (M, 1)),
            joint_axis=o["joint_axis"].astype(np.float64), joint_pivot=o["joint_pivot"].astype(np.float64),
            joint_state=o["joint_state"].astype(np.float64), T_cam_obj=o["T_cam_obj"].astype(np.float64),
            needs_alignment=self.needs_alignment, supervision=dict(self.supervision),
            info={"run": str(self.run), "preset": self.preset.name, "seed": self.preset.seed,
                  "trained_on": self.identity["dataset_hash"], "trained_category": self.identity["category"],
                  "predict_ms_per_cloud": round(1000 * seconds / max(M, 1), 2), **info},
        )


def refinable_methods() -> list[str]:
    """Registered methods that take the method-independent test-time refinement (``MethodEntry.refinable``)."""
    from scapo.methods.registry import METHODS

    return [m for m in METHODS.names() if METHODS.get(m).refinable]


def register_learned(spec: LearnedSpec, *, display: str, supervision: dict, needs_alignment: bool, summary: str,
                     refinable: bool = False, paper_row: str = ""):
    """Register a learned baseline (its factory takes :class:`LearnedOptions` fields; trained by
    :func:`train_learned`). ``refinable``: the network's ``infer`` also returns ``template (B, M, 3)`` and
    ``template_label (B, M)`` (its whole-object model, :mod:`scapo.steps.refine`). ``paper_row``: the paper's
    Table 1 row it re-implements (:class:`scapo.methods.registry.MethodEntry`)."""
    from scapo.methods.registry import register_method

    options_cls = spec.options or LearnedOptions

    def factory(**options) -> LearnedMethod:
        return LearnedMethod(spec, supervision, needs_alignment, options_cls(**options))

    register_method(spec.method, options=options_cls, display=display, supervision=supervision,
                    needs_alignment=needs_alignment, summary=summary, run_spec=lambda: run_spec(spec),
                    presets=tuple(spec.presets.names()), preset=lambda name: resolve_preset(spec, name),
                    speed=lambda **kw: learned_speed(spec, **kw), refinable=refinable,
                    train_speed=lambda preset, device, iters: learned_train_speed(spec, preset, device, iters),
                    paper_row=paper_row)(factory)
    factory.spec = spec
    return factory


#: The kinematic structure the speed measurements build networks for: two parts, one revolute joint.
SPEED_CARD = {"part_names": ["base", "lid"], "joint_type": [0], "joint_parts": [[0, 1]], "category": "perf"}


def learned_speed(spec: LearnedSpec, preset: str = "cpu", device: str | None = None, iters: int = 5,
                  num_points: int = 1024, data=None) -> list[dict]:
    """Inference speed of a freshly initialised network of ``preset``'s size (a two-part, one-revolute-joint
    structure) on box clouds (:func:`scapo.engine.speed.inference_speed`), on ``device`` or on CPU and CUDA
    when present: one row per device. Raises UnknownNameError (preset), ConfigError (device)."""
    from scapo.engine.speed import inference_speed

    pc = resolve_preset(spec, preset)
    devices = [device] if device else ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    resolved = {dev: resolve_device(dev) for dev in devices}
    rows = []
    for dev in devices:
        torch.manual_seed(0)
        net = spec.build(SPEED_CARD, pc).to(resolved[dev]).eval()
        rows.append({"preset": preset, "device": dev, "points": num_points,
                     **inference_speed(net.infer, resolved[dev], num_points, iters),
                     "threads": torch.get_num_threads()})
    return rows


def check_clouds(points) -> np.ndarray:
    """``points`` as a float32 ``(B, N, 3)`` array of finite camera-frame coordinates (metres).

    Raises:
        InputError: another shape, a complex or non-numeric dtype, NaN / inf, or coordinates beyond 1 km (a
            unit error: clouds are in metres)."""
    from scapo.errors import InputError

    if torch.is_tensor(points):
        points = points.detach().cpu().numpy()
    a = np.asarray(points)
    if a.dtype.kind not in "fiu":
        raise InputError(f"clouds must be real numbers (float32 metres), got dtype {a.dtype}")
    if a.ndim != 3 or a.shape[-1] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise InputError(f"clouds must have shape (B, N, 3), got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError("clouds hold NaN or infinite coordinates")
    if np.abs(a).max() > 1e3:
        raise InputError(f"clouds reach {np.abs(a).max():.3g} m from the camera; scapo works in metres (a depth "
                         "camera sees up to a few metres): convert the units")
    return np.ascontiguousarray(a, dtype=np.float32)


def normalize_clouds(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Centre and scale clouds for a network: ``points (B, N, 3)`` metres -> (``(points - c) / s``,
    centre ``c (B, 3)``, scale ``s (B,)`` = 2 x RMS radius, as SCAPO normalises)."""
    c = points.mean(1)
    x = points - c[:, None]
    s = 2.0 * (x ** 2).sum(-1).mean(-1).sqrt().clamp_min(1e-6)
    return x / s[:, None, None], c, s


def learned_train_speed(spec: LearnedSpec, preset: str = "cpu", device: str = "cpu", iters: int = 5) -> dict:
    """Clouds/s of one training step (loss, backward, Adam) of a freshly initialised ``spec`` network of ``preset``'s
    size (``scapo bench perf --what train``): a two-part, one-revolute structure, the preset's batch of box clouds
    (:func:`scapo.engine.speed.box_clouds`) at its training points; a supervised method gets labels and NPCS
    derived from the clouds (left and right halves as parts). ``{"batch_size", "points", "stage<k>_clouds_per_s",
    "stage<k>_epochs", "max_steps_per_epoch", "iterations", "compile"}`` per training stage (with the preset's
    ``compile``, the eager step measured first in the same run: ``stage<k>_eager_clouds_per_s``,
    ``stage<k>_speedup_vs_eager`` and ``stage<k>_compile_s``, the first compiled step's seconds beyond a step's)
    (the network's ``training_stages()`` where it has them; the epochs, steps cap and iterations: the preset's
    schedule).

    Raises:
        UnknownNameError: unknown preset. ConfigError: an unavailable device."""
    import dataclasses

    from scapo.engine.runs import resolve_device
    from scapo.engine.speed import box_clouds, step_seconds

    dev = resolve_device(device)
    pc = resolve_preset(spec, preset)
    if getattr(pc, "supervision", ""):
        pc = dataclasses.replace(pc, supervision="")
    torch.manual_seed(0)
    net = spec.build(SPEED_CARD, pc).to(dev)
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    pts = torch.from_numpy(box_clouds(pc.batch_size, pc.points)).to(dev)
    batch = {"points": pts}
    if "part_label" in spec.fields or "npcs" in spec.fields:
        x = pts - pts.mean(1, keepdim=True)
        batch["part_label"] = (x[..., 0] > 0).long()
        batch["npcs"] = x / (2 * x.norm(dim=-1).amax(1)[:, None, None])
    if spec.derive is not None:  # each box cloud its own instance
        a = {k: v.cpu().numpy() for k, v in batch.items()}
        a.update(instance_id=np.arange(pc.batch_size), view_id=np.zeros(pc.batch_size, dtype=np.int64))
        batch.update({k: torch.from_numpy(v).to(dev) for k, v in spec.derive(a, SPEED_CARD, pc).items()})

    from scapo.registry import schedule_fields

    losses = [st["losses"] for st in net.training_stages()] if hasattr(net, "training_stages") else [net.losses]
    row = {"batch_size": pc.batch_size, "points": pc.points, "compile": pc.compile}
    for k, fn in enumerate(losses, 1):
        def step(fn=fn):
            _, total = fn(batch, 0.5)
            opt.zero_grad()
            total.backward()
            opt.step()

        t = step_seconds(step, net, pc.compile, iters, dev.type == "cuda")
        row[f"stage{k}_clouds_per_s"] = round(pc.batch_size / t["step_s"], 2)
        if pc.compile:
            row[f"stage{k}_eager_clouds_per_s"] = round(pc.batch_size / t["eager_s"], 2)
            row[f"stage{k}_speedup_vs_eager"] = round(t["eager_s"] / t["step_s"], 2)
            row[f"stage{k}_compile_s"] = round(t["compile_s"], 2)
    row.update({f"stage{k}_epochs": getattr(pc, f) for k, f in enumerate(schedule_fields(pc), 1)})
    return {**row, "max_steps_per_epoch": pc.max_steps_per_epoch, "iterations": pc.iterations}
