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
from scapo.methods.learned import LearnedOptions, check_run_fits, post_suffix, training_points, training_views
from scapo.methods.registry import register_method
from scapo.models.predict import Predictor
from scapo.models.presets import ABLATIONS, PRESETS, get_preset


@dataclass(frozen=True)
class SCAPOOptions(LearnedOptions):
    """Options of the ``scapo`` method (``scapo predict --run RUN --option k=v``): those of every trained
    method (:class:`~scapo.methods.learned.LearnedOptions`; ``label`` defaults to ``scapo``, e.g.
    ``scapo-no-refine`` for a second row of one run) and the test-time refinement's."""

    refine_steps: int | None = None
    """Steps of the test-time refinement (default: the run's preset; 0 turns it off)."""
    refine_margin: float | None = None
    """Residual margin of the refinement's multi-start (default: the run's preset); choose it on val."""
    refine_upright_deg: float | None = None
    """Cone of the refinement's upright prior in degrees (default: the run's preset; 0 turns it off;
    :class:`~scapo.models.refine.RefineConfig`); its direction is fitted on the training split."""
    base_frame: str = ""
    """"principal": snap each prediction's frame to the principal axes of the points it labels as the base part,
    through an offset fitted on the training split (:mod:`scapo.methods.base_frame`, an addition to the paper; a
    one-pass inference step on the method's own segmentation, no ground truth), each view's signed permutation of
    the axes the one nearest the network's frame; "parts": the same axes with their signs from the other parts'
    centroid (:func:`scapo.methods.base_frame.parts_signed_axes`), the network's frame used for nothing but the
    offset; "" (default): the network's frame."""
    base_slot: str = "0"
    """The part slot taken as the base: "0" (default; the model's base slot), another slot number, or "auto": the
    slot whose predicted camera-frame rotations spread least over up to 512 training views
    (:func:`scapo.methods.base_frame.choose_base_slot`: a base turns with the viewpoint alone, a child also with its
    joint; no labels). With ``base_frame`` the snap works on that slot and the snapped frame is its pose; without it
    the object frame ``T_cam_obj`` is that slot's pose and nothing else changes (part labels, part poses and joints
    stay as the network gives them; the label gets ``+slot-<option>``): an object frame on the part that acts as the
    base when the network's slot 0 holds a child (an addition to the paper)."""
    stage2_starts: str | None = None
    """The hypothesis set of stage 2's first frame in one-pass prediction, for a run trained with ``stage2_frame =
    "parts"`` (:attr:`scapo.models.refine.RefineConfig.stage2_starts`): "off", "D2" (the stage-1 frame and its half
    turns), "T", "O" or "I"; default (also ``none``, which the option parser reads as no value): the run's preset.
    Given, the label gets ``+starts-<value>`` (its ablation row: ``--option stage2_starts=off``)."""
    parts_axes: str = ""
    """For a run trained with ``stage2_frame = "parts"``: how its prediction passes find the base's directions,
    "pca" or "plane" (:attr:`scapo.models.presets.TrainConfig.parts_axes`; the label gets ``+parts-plane`` /
    ``+parts-pca``); "" (default): as the run was trained. A diagnosis of the prediction step alone; a run of any
    other kind refuses it."""

    def __post_init__(self):
        super().__post_init__()
        from scapo.models.refine import STAGE2_STARTS

        if self.stage2_starts is not None and self.stage2_starts not in ("off", *STAGE2_STARTS[1:]):
            raise ConfigError(f"stage2_starts must be 'off' or one of {', '.join(STAGE2_STARTS[1:])}, got "
                              f"{self.stage2_starts!r}")
        if self.parts_axes not in ("", "pca", "plane"):
            raise ConfigError(f"parts_axes must be '' (the run's), 'pca' or 'plane', got {self.parts_axes!r}")
        if self.base_frame not in ("", "principal", "parts"):
            raise ConfigError(f"base_frame must be '' (off), 'principal' or 'parts', got {self.base_frame!r}")
        if str(self.base_slot) != "auto" and not (str(self.base_slot).isascii() and str(self.base_slot).isdigit()):
            raise ConfigError(f"base_slot must be a part slot number or 'auto', got {self.base_slot!r}")
        if self.hinge_frames and self.base_frame:
            raise ConfigError(f"hinge_frames=true and base_frame={self.base_frame} both set the part rotations; give "
                              "one")
        if self.hinge_frames and str(self.base_slot) != "0":
            raise ConfigError(f"hinge_frames=true chooses its own base slot; drop base_slot={self.base_slot}")
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
        slot = f"+slot-{self.options.base_slot}" if self.object_slot_only else ""
        starts = f"+starts-{self.options.stage2_starts}" if self.options.stage2_starts is not None else ""
        self.label = str(self.options.label or ("scapo" + axes + starts + post_suffix(self.options) + slot))
        self.predictor: Predictor | None = None
        self.base_offset: np.ndarray | None = None
        """``(3, 3)`` the fitted base-axes offset (``base_frame``, :func:`.base_frame.fit_base_offset`)."""
        self.base_support = float("nan")
        self.base_slot = 0
        """The part slot taken as the base (``base_slot``; chosen on the training split when "auto")."""
        self.base_pair: tuple[int, int] | None = None
        """``base_frame=parts``: the signed ranks of the base's axes (:func:`.base_frame.choose_signed_pair`)."""
        self.base_dispersion: np.ndarray | None = None
        self.sweep = None
        """The ``axis_sweep`` step (:class:`scapo.methods.sweep.SweepAxes`), fitted on the training split."""
        self.frames = None
        """The ``hinge_frames`` step (:class:`scapo.methods.hinge.HingeFrames`), fitted on the training split."""
        self.bar_ranks: list | None = None
        """``hinge_bar_axis``: per joint the rank of :func:`scapo.methods.hinge.bar_axis_choice` (fitted in ``fit``)."""

    @property
    def object_slot_only(self) -> bool:
        """Whether ``base_slot`` sets the object frame alone (a slot other than 0 or "auto", without ``base_frame``)."""
        return str(self.options.base_slot) != "0" and not self.options.base_frame

    def fit(self, train: ArticulationDataset) -> None:
        """Load the run and check that it was trained on this dataset's category and kinematic structure.

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
        if rc.steps > 0 and rc.starts == "octahedral" and rc.upright_deg > 0:
            self.predictor.fit_upright(train.arrays(["points"])["points"])
        raw = None
        if self.options.hinge_bar_axis or self.options.hinge_frames or self.options.axis_sweep:  # one one-pass of
            pts = training_points(train)  # the training views for all three
            raw = self.predictor.predict(pts, self.options.batch_size, False)
        mc = self.predictor.model.cfg
        if self.options.axis_sweep:  # first: the other steps read its axes
            from scapo.methods.sweep import SweepAxes

            self.sweep = SweepAxes(mc.joint_types, mc.joint_parts).fit(pts, raw)
            raw = self.sweep(raw)
        if self.options.hinge_bar_axis:  # before the base frame's fit, whose one-pass predictions take the step
            from scapo.methods.hinge import bar_axis_choice

            self.bar_ranks = bar_axis_choice(pts, raw["part_label"], mc.joint_types, mc.joint_parts)
        if self.options.base_frame:
            self.fit_base_frame(train.arrays(["points"])["points"])
        elif self.object_slot_only:
            self.fit_base_slot(train.arrays(["points"])["points"])
        if self.options.hinge_frames:
            from scapo.methods.hinge import HingeFrames

            self.frames = HingeFrames(mc.joint_types, mc.joint_parts, self.options.hinge_view_prior)
            self.frames.fit(pts, self._hinged(pts, raw))

    def fit_base_frame(self, points, max_views: int = 512) -> tuple[np.ndarray, float]:
        """Fit the base-axes offset (``base_frame``) on training clouds ``(M, N, 3)`` (camera frame, metres; no
        labels) from the network's predictions of up to ``max_views`` evenly spaced clouds, after choosing the base
        slot (``base_slot``). Returns (``O (3, 3)``, the share of those views that agree with it within 15 deg).

        Raises:
            ConfigError: not loaded, or a base slot the model does not have. InputError: the network labels no
            training view's points as the base.
        """
        from scapo.methods.base_frame import base_axes, choose_signed_pair, fit_base_offset, parts_signed_axes

        pts, o = self.fit_base_slot(points, max_views)
        pose, slot = np.asarray(o["part_pose"]), self.base_slot
        if self.options.base_frame == "parts":
            self.base_pair = choose_signed_pair(pts, o["part_label"], slot)
            E, ok = parts_signed_axes(pts, o["part_label"], self.base_pair, slot)
            self.base_offset, self.base_support, _ = fit_base_offset(pose[ok, slot, :3, :3], E[ok],
                                                                     group=np.eye(3)[None])
            return self.base_offset, self.base_support
        E, ok = base_axes(pts, o["part_label"], slot=slot)
        self.base_offset, self.base_support, _ = fit_base_offset(pose[ok, slot, :3, :3], E[ok])
        return self.base_offset, self.base_support

    def fit_base_slot(self, points, max_views: int = 512) -> tuple[np.ndarray, dict]:
        """Choose the base slot (``base_slot``; "auto": :func:`~scapo.methods.base_frame.choose_base_slot` on the
        network's one-pass part poses) from training clouds ``(M, N, 3)`` (camera frame, metres; no labels), of which
        up to ``max_views`` evenly spaced ones are read. Sets :attr:`base_slot` and :attr:`base_dispersion` (each
        slot's rotation dispersion); returns those clouds and their one-pass prediction.

        Raises:
            ConfigError: not loaded, or a base slot the model does not have.
        """
        from scapo.methods.base_frame import choose_base_slot

        if self.predictor is None:
            raise ConfigError(f"{self.run} is not loaded; call load() (or scapo.methods.load(run)) first")
        pts = np.asarray(points)
        pts = pts[training_views(len(pts), max_views)]
        o = self._one_pass(pts, False)
        pose = np.asarray(o["part_pose"])
        slot, self.base_dispersion = choose_base_slot(pose)
        if str(self.options.base_slot) != "auto":
            slot = int(self.options.base_slot)
            if slot >= pose.shape[1]:
                raise ConfigError(f"base_slot={slot}: the model has part slots 0-{pose.shape[1] - 1}")
        self.base_slot = slot
        return pts, o

    def _one_pass(self, points, progress: bool) -> dict:
        """The network's prediction for ``points (B, N, 3)``, re-split about its hinges with ``hinge``
        (:mod:`scapo.methods.hinge`; before the base-axes snap, which reads the base's points)."""
        return self._hinged(points, self._swept(self.predictor.predict(points, self.options.batch_size, progress)))

    def _swept(self, o: dict) -> dict:
        """The ``axis_sweep`` step on the network's one-pass prediction ``o`` (``o`` itself without it).

        Raises:
            ConfigError: before ``fit`` fitted the axes on a training split."""
        if not self.options.axis_sweep:
            return o
        if self.sweep is None:
            raise ConfigError("axis_sweep=true needs its axes fitted on a training split first: fit(train)")
        return self.sweep(o)

    def _hinged(self, points, o: dict) -> dict:
        """The hinge step on the network's one-pass prediction ``o`` of ``points (B, N, 3)`` (``o`` itself without
        ``hinge``).

        Raises:
            ConfigError: ``hinge_bar_axis`` before ``fit`` chose the bar axes' ranks."""
        if self.options.hinge:
            from scapo.methods.hinge import hinge_prediction

            if self.options.hinge_bar_axis and self.bar_ranks is None:
                raise ConfigError("hinge_bar_axis=true needs its ranks chosen on a training split first: fit(train)")
            mc = self.predictor.model.cfg
            o = hinge_prediction(np.asarray(points), o, mc.joint_types, mc.joint_parts,
                                 axis_from_planes=self.options.hinge_axis, bar_axes=self.bar_ranks)
        return o

    def _base_frame(self, points, o: dict) -> dict:
        """The prediction steps on the part rotations: ``hinge_frames`` or ``base_frame`` (at most one is set)."""
        if self.options.hinge_frames:
            if self.frames is None:
                raise ConfigError("hinge_frames=true needs its offsets fitted on a training split first: fit(train)")
            return self.frames(np.asarray(points), o)
        if self.object_slot_only:  # the object frame on the chosen slot; nothing else changes
            if self.base_dispersion is None:
                raise ConfigError(f"base_slot={self.options.base_slot} needs its slot chosen on a training split "
                                  "first: fit(train) or fit_base_slot(points)")
            return {**o, "T_cam_obj": np.asarray(o["part_pose"])[:, self.base_slot].copy()}
        if not self.options.base_frame:
            return o
        if self.base_offset is None:
            raise ConfigError("base_frame=principal needs its offset fitted on a training split first: fit(train) "
                              "or fit_base_frame(points)")
        from scapo.methods.base_frame import snap_to_base

        return snap_to_base(np.asarray(points), o, self.base_offset, slot=self.base_slot, pair=self.base_pair)

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
            if _starts(o.stage2_starts) and not self.predictor.model.uses_parts_frame:  # it would change nothing
                raise ConfigError(f"stage2_starts={o.stage2_starts} applies to a run trained with stage2_frame='parts' "
                                  f"(preset part stage2-parts); {self.run} was not, so its rows would be labelled "
                                  "+starts without a start tried: drop the option")
            self.predictor.refine = dataclasses.replace(self.predictor.refine, stage2_starts=_starts(o.stage2_starts))
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
                self.label = f"scapo-{sup.lower()}" + post_suffix(self.options)
        return self

    @property
    def module(self):
        """The trained :class:`~scapo.models.scapo_model.SCAPOModel` (an ``nn.Module``); None before :meth:`load`."""
        return None if self.predictor is None else self.predictor.model

    def predict_points(self, points) -> dict:
        """:meth:`Predictor.predict <scapo.models.predict.Predictor.predict>` on clouds ``(B, N, 3)`` (metres)."""
        if self.predictor is None:
            raise ConfigError(f"{self.run} is not loaded; call load() (or scapo.methods.load(run)) first")
        return self._base_frame(points, self._one_pass(points, self.options.progress))

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        a = dataset.arrays(["points"])
        t0 = time.perf_counter()
        o = self._base_frame(a["points"], self._one_pass(a["points"], self.options.progress))
        mc = self.predictor.model.cfg
        extra = {}
        if self.options.refine:
            from scapo.methods.refine import refine_info, refine_prediction

            o = refine_prediction(a["points"], o, o["template_rest"], o["template_label"], mc.joint_types,
                                  mc.joint_parts, batch_size=self.options.batch_size)
            extra = refine_info(o)
        if self.options.hinge:
            from scapo.methods.hinge import hinge_info

            extra["hinge"] = hinge_info(o, self.options.hinge_axis, self.bar_ranks)
        if self.options.hinge_frames:
            extra["hinge_frames"] = self.frames.info(o)
        if self.options.axis_sweep:
            extra["axis_sweep"] = self.sweep.info()
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
                  "predict_ms_per_cloud": round(1000 * seconds / max(M, 1), 2), **extra,
                  **({"base_frame": {"offset": np.round(self.base_offset, 6).tolist(),
                                     "train_support": round(self.base_support, 4),
                                     "slot": self.base_slot, "slot_option": str(self.options.base_slot),
                                     "dispersion": np.round(self.base_dispersion, 4).tolist(),
                                     "snap_deg_median": round(float(np.median(o["base_snap_deg"])), 2),
                                     "mode": self.options.base_frame,
                                     **({"signed_ranks": list(self.base_pair)} if self.base_pair else {})}}
                     if self.options.base_frame else {}),
                  **({"object_slot": {"slot": self.base_slot, "option": str(self.options.base_slot),
                                      "dispersion": np.round(self.base_dispersion, 4).tolist()}}
                     if self.object_slot_only else {})},
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
        rc = dataclasses.replace(rc, stage2_starts=_starts(str(o["stage2_starts"])))
    return dataclasses.asdict(rc)


def _starts(option: str) -> str:
    """:attr:`SCAPOOptions.stage2_starts` as :attr:`~scapo.models.refine.RefineConfig.stage2_starts` ("off": "")."""
    return "" if option == "off" else option


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
                 train_speed=_train_speed)
def make_scapo(**options) -> SCAPOMethod:
    """SCAPO (ours) from a trained run; options are :class:`SCAPOOptions` fields."""
    return SCAPOMethod(**options)
