"""SCAPO (ours) in the method registry: predictions from a run trained by ``scapo train``.

The model, its training and its inference live in :mod:`scapo.models`; this module only loads a run
(:class:`~scapo.models.predict.Predictor`), checks that it fits the dataset, and writes predictions.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scapo.data.dataset import ArticulationDataset
from scapo.errors import ConfigError
from scapo.eval.predictions import Predictions
from scapo.losses.supervised import supervision_marks
from scapo.methods.learned import LearnedOptions, check_run_fits
from scapo.methods.registry import register_method
from scapo.models.predict import Predictor
from scapo.models.presets import ABLATIONS, PRESETS, get_preset
from scapo.steps import StepPipeline


@dataclass(frozen=True)
class SCAPOOptions(LearnedOptions):
    """Options of the ``scapo`` method (``scapo predict --run RUN --option k=v``): those of every trained
    method (:class:`~scapo.methods.learned.LearnedOptions`, with the prediction steps of
    :class:`scapo.steps.StepOptions`; ``label`` defaults to ``scapo``, e.g. ``scapo-no-refine`` for a second row of
    one run) and SCAPO's own test-time refinement's."""

    refine_steps: int | None = None
    """Steps of the test-time refinement (default: the run's preset; 0 turns it off)."""
    refine_margin: float | None = None
    """Residual margin of the refinement's multi-start (default: the run's preset); choose it on val."""
    refine_upright_deg: float | None = None
    """Cone of the refinement's upright prior in degrees (default: the run's preset; 0 turns it off;
    :class:`~scapo.models.refine.RefineConfig`); its direction is fitted on the training split."""
    stage2_starts: str | None = None
    """The hypothesis set of stage 2's first frame in one-pass prediction, for a run trained with ``stage2_frame =
    "parts"`` (:attr:`scapo.models.refine.RefineConfig.stage2_starts`, checked by its one check,
    :func:`scapo.models.refine.check_stage2_starts`): "off", "D2" (the stage-1 frame and its half turns), "T", "O" or
    "I"; default (also ``none``, which the option parser reads as no value): the setting the run stored.
    Given, the label gets ``+starts-<value>`` (its ablation row: ``--option stage2_starts=off``)."""
    parts_axes: str = ""
    """For a run trained with ``stage2_frame = "parts"``: how its prediction passes find the base's directions,
    "pca" or "plane" (:attr:`scapo.models.presets.TrainConfig.parts_axes`; the label gets ``+parts-plane`` /
    ``+parts-pca``); "" (default): as the run was trained. A diagnosis of the prediction step alone; a run of any
    other kind refuses it."""

    def __post_init__(self):
        super().__post_init__()
        from scapo.models.refine import check_stage2_starts

        if self.stage2_starts is not None:
            try:
                check_stage2_starts(self.stage2_starts)
            except ValueError as e:
                raise ConfigError(str(e)) from None
        if self.parts_axes not in ("", "pca", "plane"):
            raise ConfigError(f"parts_axes must be '' (the run's), 'pca' or 'plane', got {self.parts_axes!r}")
        if self.refine_steps is not None and self.refine_steps < 0:
            raise ConfigError(f"refine_steps must be >= 0, got {self.refine_steps}")
        if self.refine and self.refine_steps:
            raise ConfigError("refine=True (the method-independent refinement, scapo predict --refine) replaces "
                              f"SCAPO's own; give one of them, not also refine_steps={self.refine_steps}")


class SCAPOMethod:
    """SCAPO in the method registry: loads a trained run (never trains; that is ``scapo train``)."""

    name = "scapo"
    needs_alignment = True
    supervision = {"pose": False, "segmentation": False, "joint": False}

    def __init__(self, options: SCAPOOptions | None = None, **overrides):
        self.options = dataclasses.replace(options or SCAPOOptions(), **overrides)
        if self.options.run is None:
            raise ConfigError("the scapo method needs a trained run: --run RUN (a folder written by 'scapo train')")
        self.run = Path(self.options.run)
        axes = f"+parts-{self.options.parts_axes}" if self.options.parts_axes else ""
        starts = f"+starts-{self.options.stage2_starts}" if self.options.stage2_starts is not None else ""
        self.label = str(self.options.label or ("scapo" + axes + starts + self.options.label_suffix()))
        self.predictor: Predictor | None = None
        self.steps: StepPipeline | None = None
        """The prediction steps (:class:`scapo.steps.StepPipeline`), made by :meth:`load`, fitted by :meth:`fit`."""

    def fit(self, train: ArticulationDataset) -> None:
        """Load the run, check that it was trained on this dataset's category and kinematic structure, fit the
        refinement's upright prior and the prediction steps that need it on the training split.

        Raises:
            TrainingError: see :meth:`Predictor.load`.
            ConfigError: the run's parts or joints differ from the dataset's, or its category differs
                (allowed with ``cross_category`` when the structure is the same); names both.
        """
        self.load()
        ident = self.predictor.identity
        check_run_fits(self.run, ident, train, self.options.cross_category,
                       f"train a run on this dataset first ('scapo train --data {train.root} --out RUN')")
        rc = self.predictor.refine
        points = train.arrays(["points"])["points"]
        if rc.steps > 0 and rc.starts == "octahedral" and rc.upright_deg > 0:
            self.predictor.fit_upright(points)
        self.steps.fit(points, self._network)

    def _network(self, points, progress: bool = False) -> dict:
        """The network's prediction (with SCAPO's own refinement, as the run's inference settings say) for
        ``points (B, N, 3)``."""
        return self.predictor.predict(points, self.options.batch_size, progress)

    def load(self) -> SCAPOMethod:
        """Load the run (:meth:`Predictor.load <scapo.models.predict.Predictor.load>`; no dataset needed, so the
        refinement's upright prior, fitted on a training split, stays off); returns self.

        Raises:
            TrainingError, ConfigError: see :meth:`Predictor.load`.
        """
        o = self.options
        # with the method-independent refinement the network predicts one-pass (SCAPO's own refinement off)
        self.predictor = Predictor.load(self.run, o.device, 0 if o.refine else o.refine_steps, o.refine_margin)
        if o.refine_upright_deg is not None:
            try:
                self.predictor.refine = dataclasses.replace(self.predictor.refine,
                                                            upright_deg=float(o.refine_upright_deg))
            except ValueError as e:
                raise ConfigError(str(e)) from None
        if o.stage2_starts is not None:
            if o.stage2_starts != "off" and not self.predictor.model.uses_parts_frame:  # it would change nothing
                raise ConfigError(f"stage2_starts={o.stage2_starts} applies to a run trained with stage2_frame='parts' "
                                  f"(preset part stage2-parts); {self.run} was not, so its rows would be labelled "
                                  "+starts without a start tried: drop the option")
            self.predictor.refine = dataclasses.replace(self.predictor.refine, stage2_starts=o.stage2_starts)
        if o.parts_axes:
            model = self.predictor.model
            if not model.uses_parts_frame:
                raise ConfigError(f"parts_axes={o.parts_axes} applies to a run trained with stage2_frame='parts'; "
                                  f"{self.run} was not: drop the option")
            model.parts_plane.fill_(int(o.parts_axes == "plane"))
        ident = self.predictor.identity
        self.trained_on = ident["dataset_hash"]
        sup = ident["preset"].get("supervision", "")
        if ident["preset"].get("label_init") and "S" not in sup:  # its initial split read segmentation labels
            sup = "S" + sup
        if sup:  # the semi-supervised setting: its marks, and a label of its own unless one was given
            self.supervision = supervision_marks(sup)
            if not self.options.label:
                self.label = f"scapo-{sup.lower()}" + self.options.label_suffix()
        mc = self.predictor.model.cfg
        self.steps = StepPipeline(o, mc.joint_types, mc.joint_parts, "template_rest", o.batch_size)
        return self

    @property
    def module(self):
        """The trained :class:`~scapo.models.scapo_model.SCAPOModel` (an ``nn.Module``); None before :meth:`load`."""
        return None if self.predictor is None else self.predictor.model

    def predict_points(self, points) -> dict:
        """:meth:`Predictor.predict <scapo.models.predict.Predictor.predict>` on clouds ``(B, N, 3)`` (metres), then
        the prediction steps."""
        if self.predictor is None:
            raise ConfigError(f"{self.run} is not loaded; call load() (or scapo.methods.load(run)) first")
        return self.steps.apply(points, self._network(points, self.options.progress))

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        a = dataset.arrays(["points"])
        t0 = time.perf_counter()
        o = self.steps.apply(a["points"], self._network(a["points"], self.options.progress))
        mc = self.predictor.model.cfg
        extra = self.steps.info(o)
        seconds = time.perf_counter() - t0
        M = len(a["points"])
        return Predictions(
            method=self.label, instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(M, dataset.split),
            part_label=o["part_label"], part_pose=o["part_pose"].astype(np.float64),
            joint_parts=np.tile(np.array(mc.joint_parts), (M, 1, 1)), joint_type=np.tile(np.array(mc.joint_types),
                                                                                         (M, 1)),
            joint_axis=o["joint_axis"].astype(np.float64), joint_pivot=o["joint_pivot"].astype(np.float64),
            joint_state=o["joint_state"].astype(np.float64), T_cam_obj=o["T_cam_obj"].astype(np.float64),
            needs_alignment=True, supervision=dict(self.supervision),
            info={"run": str(self.run), "preset": self.predictor.identity["preset"]["name"],
                  "trained_on": self.predictor.identity["dataset_hash"],
                  "trained_category": self.predictor.identity["category"],
                  "seed": self.predictor.identity["preset"].get("seed"),
                  "refine_steps": self.predictor.refine.steps,
                  "refine_margin": self.predictor.refine.margin,
                  "inference": dataclasses.asdict(self.predictor.refine),
                  "upright": None if self.predictor.upright is None else
                  np.round(self.predictor.upright.cpu().double().numpy(), 6).tolist(),
                  "upright_support": self.predictor.upright_support,
                  "predict_ms_per_cloud": round(1000 * seconds / max(M, 1), 2), **extra},
        )


def inference_settings(run, options: dict | None = None) -> dict:
    """The test-time refinement settings a prediction from ``run`` with the prediction ``options``
    (:class:`SCAPOOptions` fields: ``refine_steps``, ``refine_margin``, ``refine_upright_deg``, ``stage2_starts``) uses
    now
    (:func:`~scapo.models.predict.stored_refine`, with the options applied as :meth:`SCAPOMethod.load` applies them),
    as predictions record them in ``info["inference"]``; empty for a folder without a readable ``run.json``."""
    import json

    from scapo.models.predict import stored_refine

    try:
        rc = stored_refine(json.loads((Path(run) / "run.json").read_text())["preset"])
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    o = dict(options or {})
    if str(o.get("refine", False)).lower() in ("true", "1", "yes"):  # the method-independent step replaces SCAPO's own
        o["refine_steps"] = 0
    for key, name in (("refine_steps", "steps"), ("refine_margin", "margin"), ("refine_upright_deg", "upright_deg")):
        if o.get(key) is not None:
            rc = dataclasses.replace(rc, **{name: type(getattr(rc, name))(o[key])})
    if o.get("stage2_starts") is not None:
        rc = dataclasses.replace(rc, stage2_starts=str(o["stage2_starts"]))
    return dataclasses.asdict(rc)


def _run_spec():
    from scapo.models.train import SCAPO_RUN

    return SCAPO_RUN


def _train_speed(preset: str = "cpu", device: str = "cpu", iters: int = 5) -> dict:
    """Clouds/s of one training step per stage (:func:`scapo.models.scapo_speed.bench_train_step`)."""
    from scapo.models.scapo_speed import bench_train_step

    return bench_train_step(preset, device, iters)


def _speed(preset: str = "cpu", device: str | None = None, iters: int = 5, num_points: int = 1024, data=None):
    from scapo.models.scapo_speed import bench_model

    return bench_model(preset, device=device, iters=iters, num_points=num_points)


@register_method("scapo", options=SCAPOOptions, display="SCAPO (ours)", supervision=SCAPOMethod.supervision,
                 needs_alignment=True, summary="self-supervised SE(3)-equivariant skinning (the paper's method)",
                 run_spec=_run_spec, presets=tuple(PRESETS.names()),
                 variants={"scapo-no-refine": "SCAPO (ours, no refinement)"},
                 inference=inference_settings, preset=get_preset,
                 ablations=ABLATIONS, speed=_speed, one_pass={"refine_steps": 0}, refinable=True,
                 train_speed=_train_speed, paper_row="SCAPO")
def make_scapo(**options) -> SCAPOMethod:
    """SCAPO (ours) from a trained run; options are :class:`SCAPOOptions` fields."""
    return SCAPOMethod(**options)
