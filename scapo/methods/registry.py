"""The neutral method registry: one :class:`MethodEntry` per method, one module per method.

An entry carries the method's factory (``entry.factory(**options) -> Method``), its options dataclass
(``scapo predict --option k=v`` is validated against it), its display name and supervision marks for
the tables (Pose / Segmentation / Joint, as in the paper's tables), whether its canonical frame needs
alignment before scoring, and for trained methods the training entry point and preset names
(``scapo train --method NAME --preset P``). A new method is one module that calls
:func:`register_method` and is imported by :mod:`scapo.methods`.

:func:`run_method` fits a method on the training split (or loads its trained run), predicts and writes
the predictions file.
"""

from __future__ import annotations

import dataclasses
import json
import time
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from scapo.data.dataset import ArticulationDataset, load
from scapo.errors import ConfigError, DatasetError, warn_few_instances
from scapo.eval.predictions import Predictions
from scapo.files import check_output_file
from scapo.registry import Registry, split_supervision_label


class Method(Protocol):
    """What the evaluator needs from a method."""

    name: str
    needs_alignment: bool
    supervision: dict

    def fit(self, train: ArticulationDataset) -> None:
        """Learn from the training split (labels may be used only as ``supervision`` declares), or load
        a trained run and check that it fits the dataset."""

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        """Predictions for every sample of ``dataset`` (rows carry ``dataset.split``)."""


#: The supervision marks of the paper's tables, in column order.
SUPERVISION_KEYS = ("pose", "segmentation", "joint")


@dataclass(frozen=True)
class MethodEntry:
    """One registered method.

    Attributes:
        name: registry name (``scapo predict --method NAME``).
        factory: ``factory(**options) -> Method``; options are fields of ``options``.
        options: the options dataclass (typed fields with defaults; validated in ``__post_init__``).
        display: row name in tables (re-implementations of other papers end in "-style").
        supervision: which ground truth the method uses in training or at test time
            ({"pose", "segmentation", "joint"} -> bool), the marks of the paper's tables.
        needs_alignment: its canonical frame is arbitrary (self-supervised), so the evaluator aligns it
            to the ground-truth canonical frame from training-split predictions.
        summary: one line for ``scapo list``.
        run_spec: for trained methods, ``run_spec() -> RunSpec``: how the engine sets up and trains one of its runs
            (:class:`scapo.engine.lifecycle.RunSpec`; :func:`train_method`).
        presets: preset names of a trained method (``scapo train --method NAME --preset P``).
        variants: other labels its predictions may carry (e.g. a second row of one run) -> display name.
        inference: for trained methods whose predictions depend on settings that are not part of the
            run (SCAPO's test-time refinement), ``inference(run, options) -> dict`` of the settings a prediction
            from ``run`` with the prediction ``options`` (a dict) would use now; its predictions record them as
            ``info["inference"]``, so that
            predictions made under other settings are recognised as stale (``scapo.bench``).
        run_is_current: for trained methods (derived from ``run_spec`` when not given:
            :func:`scapo.engine.lifecycle.run_is_current`), ``run_is_current(run, data, preset, seed) -> bool``: the run
            folder holds the run ``train(data, run, preset, seed=seed)`` would start now (False when
            the preset's training fields changed since), so the bench never reports a stale run.
        preset: for trained methods, ``preset(name) -> preset object``: a registered preset or a variant of one
            (``cpu/sj``, ``cpu/no-TERM``); raises UnknownNameError for a name the method does not take.
        ablations: the parts a preset can switch off as ``BASE/no-TERM`` (the paper's Table 3 for SCAPO).
        speed: ``speed(preset, device, iters, num_points, data) -> list of rows`` timing the method's inference
            (``scapo bench perf --what model --method NAME``); None for a method with nothing to time.
        one_pass: prediction options that turn the method's test-time refinement off (its one-pass prediction;
            SCAPO: ``refine_steps=0``). The bench's main rows of Tables 1 and 3 use them, so that no row gets a
            test-time search the others lack; Table 1 reports the refined prediction of the same run as its own
            row, labelled ``<method>+refine``. Empty: the method has no test-time refinement.
        quick_options: prediction options for a quick run of a fitted method (tests, smoke runs); a trained
            method's quick run is its ``test`` preset.
        refinable: the method has a whole-object model (a canonical shape or template) and takes the
            method-independent test-time refinement (:mod:`scapo.steps.refine`; option ``refine=True``,
            ``scapo predict --refine``, label ``<method>+refine``); Table 1 reports it as its own row.
        train_speed: for trained methods, ``train_speed(preset, device, iters) -> dict`` of one training step's
            clouds/s per stage (``stage1_clouds_per_s``, ...) with ``batch_size`` and ``points``
            (``scapo bench perf --what train``).
        paper_row: the row of the paper's Table 1 (``scapo/eval/reference/paper_table1.csv``, its ``method``
            column) that the method is, or re-implements (NPCS-style: ``NPCS-EPN``); "" for none. The tables'
            at-a-glance figure marks that row's values on the method's bars.
    """

    name: str
    factory: Callable[..., Method]
    options: type
    display: str
    supervision: Mapping[str, bool]
    needs_alignment: bool
    summary: str = ""
    run_spec: Callable[[], Any] | None = None
    presets: tuple[str, ...] = ()
    variants: Mapping[str, str] = field(default_factory=dict)
    inference: Callable[[Path, dict], dict] | None = None
    run_is_current: Callable[..., bool] | None = None
    preset: Callable[[str], Any] | None = None
    ablations: tuple[str, ...] = ()
    speed: Callable[..., list] | None = None
    quick_options: Mapping[str, Any] = field(default_factory=dict)
    one_pass: Mapping[str, Any] = field(default_factory=dict)
    refinable: bool = False
    train_speed: Callable[[str, str, int], dict] | None = None
    paper_row: str = ""

    @property
    def trained(self) -> bool:
        """Whether the method is trained by ``scapo train`` (else its ``fit`` is all it needs)."""
        return self.run_spec is not None

    def marks(self) -> str:
        """Supervision marks as three characters, e.g. ``"-S-"`` (Pose, Segmentation, Joint)."""
        return "".join(k[0].upper() if self.supervision.get(k) else "-" for k in SUPERVISION_KEYS)


#: name -> MethodEntry
METHODS: Registry[MethodEntry] = Registry("method")


def register_method(name: str, *, options: type, display: str, supervision: Mapping[str, bool],
                    needs_alignment: bool, summary: str = "", run_spec: Callable[[], Any] | None = None,
                    presets: tuple[str, ...] = (), variants: Mapping[str, str] | None = None,
                    inference: Callable[[Path, dict], dict] | None = None,
                    run_is_current: Callable[..., bool] | None = None, preset: Callable[[str], Any] | None = None,
                    ablations: tuple[str, ...] = (), speed: Callable[..., list] | None = None,
                    quick_options: Mapping[str, Any] | None = None, one_pass: Mapping[str, Any] | None = None,
                    refinable: bool = False, train_speed: Callable[[str, str, int], dict] | None = None,
                    paper_row: str = ""):
    """Decorator registering a method factory under ``name`` (see :class:`MethodEntry`).

    Raises:
        ValueError: ``name`` registered twice, ``options`` not a dataclass, or supervision keys other
            than pose, segmentation, joint.
    """
    if not dataclasses.is_dataclass(options):
        raise ValueError(f"method {name!r}: options must be a dataclass, got {options!r}")
    if set(supervision) != set(SUPERVISION_KEYS):
        raise ValueError(f"method {name!r}: supervision must have exactly the keys {SUPERVISION_KEYS}")

    if run_spec is not None and run_is_current is None:  # the engine's one check, for every trained method
        def run_is_current(run, data, preset, seed=None):
            from scapo.engine import lifecycle

            return lifecycle.run_is_current(run_spec(), run, data, preset, seed)

    def deco(factory):
        METHODS.add(name, MethodEntry(name, factory, options, display, dict(supervision), needs_alignment, summary,
                                      run_spec, tuple(presets), dict(variants or {}), inference, run_is_current,
                                      preset, tuple(ablations), speed, dict(quick_options or {}),
                                      dict(one_pass or {}), bool(refinable), train_speed, str(paper_row)))
        factory.options = options
        return factory

    return deco


def describe(label: str) -> tuple[str, dict] | None:
    """(display name, supervision marks) for a predictions label: a registered name, or one of an
    entry's variants (``scapo-no-refine``) or ``<label>+refine`` (:mod:`scapo.steps.refine`), either with a
    supervision suffix ``-sj`` / ``-s`` / ``-j`` (a run
    trained with those labels, :mod:`scapo.losses.supervised`: "SCAPO (ours) (SJ)" with its marks); None
    for a label no entry knows."""
    if label in METHODS:
        e = METHODS.get(label)
        return e.display, dict(e.supervision)
    if label.endswith("+refine") and len(label) > len("+refine"):  # the method-independent refinement's rows
        known = describe(label[:-len("+refine")])
        if known is not None:
            return f"{known[0]} + refine", known[1]
    for name in METHODS:
        e = METHODS.get(name)
        if label in e.variants:
            return e.variants[label], dict(e.supervision)
    split = split_supervision_label(label)
    if split is not None:
        base, sup = split
        known = describe(base)
        if known is not None:
            display, marks = known
            return f"{display} ({sup})", {**marks, "segmentation": marks["segmentation"] or "S" in sup,
                                          "joint": marks["joint"] or "J" in sup}
    return None


def list_methods() -> list[str]:
    return METHODS.names()


def options_class(name: str) -> type:
    """The options dataclass of method ``name``."""
    return METHODS.get(name).options


def _parse_text(method: str, key: str, text: str, tp) -> Any:
    """Convert the command-line text of option ``key`` to the field type ``tp``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if text.strip().lower() in ("none", "null") and len(args) < len(typing.get_args(tp)):
            return None
        tp = args[0]
    bad = ConfigError(f"option {key}={text!r} of method {method!r} is not a valid {getattr(tp, '__name__', tp)}")
    if tp is bool:
        low = text.strip().lower()
        if low in ("true", "1", "yes", "on"):
            return True
        if low in ("false", "0", "no", "off"):
            return False
        raise bad
    if tp in (int, float):
        try:
            return tp(text)
        except ValueError:
            raise bad from None
    if tp is Path:
        return Path(text)
    return text


def validate_options(name: str, options: dict[str, Any]) -> dict[str, Any]:
    """Check ``options`` against method ``name``'s options dataclass; strings are converted to the
    field types (``"30"`` -> 30 for an int field, ``"true"`` -> True for a bool).

    Raises:
        UnknownNameError: unknown method.
        ConfigError: an unknown option (the message lists the valid ones), a value that does not convert to the
            field's type, or options that the options dataclass's own checks refuse together.
    """
    cls = options_class(name)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    out = {}
    for k, v in options.items():
        if k not in fields:
            raise ConfigError(f"unknown option {k!r} for method {name!r}; valid options: {', '.join(fields)}")
        out[k] = _parse_text(name, k, v, hints[k]) if isinstance(v, str) else v
    try:  # the options' own rules between fields (e.g. hinge_axis needs hinge), before any work that uses them
        cls(**out)
    except TypeError as e:
        raise ConfigError(f"options of method {name!r}: {e}") from None
    return out


def run_method(name: str, data: str | Path, out: str | Path | None = None, **options) -> Predictions:
    """Fit method ``name`` on the training split of ``data``, predict the test split, the val split
    when the dataset has one (so choices can be made on it with the same file), and the training split
    when the method needs canonical-frame alignment, and save to ``out``. The predictions' ``info`` records the
    fit's seconds and, per predicted evaluation split, the wall and CPU (core) milliseconds per cloud
    (``ms_per_cloud_<split>``, ``cpu_ms_per_cloud_<split>``).

    Options are validated (:func:`validate_options`) and ``out`` is checked to be writable before
    any work; the file is written atomically.

    Raises:
        UnknownNameError: unknown method (lists the known ones).
        ConfigError: unknown or invalid options.
        OutputError: ``out`` cannot be written.
        DatasetError: ``data`` is not a dataset, or its test split is empty.
    """
    method = METHODS.get(name).factory(**validate_options(name, options))
    if out is not None:
        from scapo.eval.predictions import is_predictions_file

        check_output_file(out, "predictions file", "predictions.npz", replaceable=is_predictions_file)
        _check_replace(Path(out), name, options.get("run"))
    train = load(data, "train")
    test = load(data, "test")
    if len(test) == 0:
        raise DatasetError(f"the test split of {data} is empty (generated with --test-fraction "
                           f"{train.card.get('config', {}).get('test_fraction')} and "
                           f"{train.card.get('config', {}).get('instances')} instances); regenerate it with test "
                           "instances")
    if not METHODS.get(name).trained:  # a trained method's run was trained (and warned about) by train_method
        warn_few_instances(train.num_instances, "train", data, "what it fits on them")
    t0 = time.perf_counter()
    method.fit(train)
    t_fit = time.perf_counter() - t0
    timed = {}  # per split: wall and CPU (core) milliseconds per cloud

    def predict(split: str, ds):
        t, c = time.perf_counter(), time.process_time()
        out = method.predict(ds)
        timed[split] = (time.perf_counter() - t, time.process_time() - c, len(ds))
        return out

    parts = [predict("test", test)]
    if "val" in train.card.get("splits", {}):
        val = load(data, "val")
        if len(val):
            parts.append(predict("val", val))
    if method.needs_alignment:
        parts.append(method.predict(train))
    preds = Predictions.concatenate(parts)
    preds.dataset_hash = test.dataset_hash
    preds.info = {**preds.info, "fit_seconds": round(t_fit, 3), "predict_seconds_test": round(timed["test"][0], 3),
                  **{f"{k}_{split}": round(1000 * v / max(n, 1), 3) for split, (w, c, n) in timed.items()
                     for k, v in (("ms_per_cloud", w), ("cpu_ms_per_cloud", c))},
                  "predict_seconds_total": round(time.perf_counter() - t0, 3)}  # fit and every split
    if out is not None:
        preds.save(out)
    return preds


def _check_replace(out: Path, method: str, run) -> None:
    """Refuse to replace the predictions file ``out`` with those of another run (a trained method's predictions name
    their run; a new prediction from the same run replaces them, as a rerun does, and a fitted method's replace a
    fitted method's); a file that cannot be read is left to :func:`~scapo.files.check_output_file`'s rule.

    Raises:
        OutputError: ``out`` holds the predictions of another run (names it)."""
    import numpy as np

    from scapo.errors import OutputError

    if not out.is_file():
        return
    try:
        with np.load(out, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
        had_run = meta["info"].get("run")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return
    same = (had_run is None and run is None) or (
        had_run is not None and run is not None and Path(str(had_run)).resolve() == Path(str(run)).resolve())
    if not same:
        raise OutputError(f"{out} holds the predictions of {meta.get('method', 'another method')}"
                          + (f" from run {had_run}" if had_run else " (a fitted method)") + f", not of {method}"
                          + (f" from run {run}" if run is not None else "") + ": give another --out, or delete it "
                          "first")


def method_of_run(run: str | Path) -> str:
    """The method a run folder was trained for: ``run.json``'s ``method`` (runs written before the
    registry held other trained methods are SCAPO runs). A folder without a readable ``run.json`` (a
    typo, an unfinished or damaged run) is taken for a SCAPO run, whose loader then says what is wrong.
    """
    try:
        ident = json.loads((Path(run) / "run.json").read_text())
    except (OSError, ValueError):
        return "scapo"
    return str(ident.get("method", "scapo")) if isinstance(ident, dict) else "scapo"


def load_run(run: str | Path, device: str | None = None, **options):
    """A finished run of any trained method, loaded for prediction (the method is read from ``run.json``):
    the method object, with ``predict_points(points (B, N, 3) metres) -> dict`` of numpy outputs,
    ``predict(dataset)`` and ``module`` (its trained ``nn.Module``). ``options`` are the method's prediction
    options (:func:`options_class`).

    Raises:
        TrainingError: no run there (no checkpoint), a damaged checkpoint, an unfinished run, weights that are NaN or
        infinite. ConfigError: a run of a method that is not trained, an unknown option, an unavailable device.
    """
    from scapo.errors import TrainingError

    run = Path(run)
    if not (run / "checkpoint.pt").is_file():
        what = "is a file" if run.is_file() else ("does not exist" if not run.exists() else "holds no checkpoint.pt")
        raise TrainingError(f"{run} {what}: not a trained run; train one with 'scapo train --method M --data DATA "
                            f"--out {run}'")
    name = method_of_run(run)
    entry = METHODS.get(name)
    if not entry.trained:
        raise ConfigError(f"{run} names method {name!r}, which is not trained")
    method = entry.factory(run=run, device=device, **options)
    loaded = method.load()
    module = getattr(loaded, "module", None)
    if module is not None:  # as the command line does: a run whose weights are NaN predicts nothing
        import torch

        bad = [n for n, t in module.state_dict().items() if t.is_floating_point() and not bool(torch.isfinite(t).all())]
        if bad:
            raise TrainingError(f"{run}: the checkpoint's weights hold NaN or infinite values ({len(bad)} tensor(s), "
                                f"first: {bad[0]}); it would predict NaN poses. Train the run again (another --out)")
    return loaded


#: training seeds are 32-bit: the engine derives each epoch's seed from them (scapo.engine.loop)


def train_method(name: str, data: str | Path, run: str | Path, preset=None, progress: bool = True,
                 device: str | None = None, seed: int | None = None, overrides: dict | None = None) -> Path:
    """Train (or resume) method ``name`` on ``data`` into the run folder ``run``; returns the checkpoint.

    The run is set up once, by the engine (:func:`scapo.engine.lifecycle.train`): ``preset`` (a name, a preset
    object, or None: the run's own preset, else ``cpu``), then ``overrides`` (``scapo train --set``: field ->
    value), then ``seed``.

    Raises:
        UnknownNameError: unknown method or preset. ConfigError: a method that is not trained (its
        ``fit`` is all it needs). Otherwise as the engine's :func:`~scapo.engine.lifecycle.train` (which also
        refuses a dataset of a category without a movable joint, a bad override or seed).
    """
    entry = METHODS.get(name)
    if entry.run_spec is None:
        trained = [n for n in METHODS if METHODS.get(n).trained]
        raise ConfigError(f"method {name!r} is not trained ('scapo predict --method {name}' fits it); trained "
                          f"methods: {', '.join(trained)}")
    from scapo.engine import lifecycle

    return lifecycle.train(entry.run_spec(), data, run, preset, seed=seed, overrides=overrides, device=device,
                           progress=progress)
