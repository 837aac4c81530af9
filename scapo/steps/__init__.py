"""The prediction steps: what a trained method may do to its one-pass prediction before it is scored, one pipeline
for every trained method (an addition to the paper, offered to all of them alike; a table shows a step only in a
labelled row, never in a method's main row).

A step reads the method's own one-pass outputs (numpy, camera frame, metres: ``part_label (M, N)`` int,
``part_pose (M, P, 4, 4)``, ``joint_axis`` / ``joint_pivot (M, J, 3)``, ``joint_state (M, J)``, ``T_cam_obj
(M, 4, 4)``) and the clouds ``points (M, N, 3)``; some are fitted first on the training split's one-pass outputs (no
labels). In the order :meth:`StepPipeline.apply` runs them:

==================== ============================================================ ==================================
option               step                                                         module
==================== ============================================================ ==================================
``axis_sweep``       each revolute axis from the sweep of its child part over the :mod:`scapo.steps.sweep`
                     training views (fitted)
``hinge``            each view's part split and pivot re-fitted about its hinges; :mod:`scapo.steps.hinge`
                     ``hinge_axis``: axes from the two parts' planes;
                     ``hinge_bar_axis``: a bar child's axis from its parent's
                     principal direction (rank fitted)
``hinge_frames``     the part rotations read from the hinges through per-part     :class:`scapo.steps.hinge.HingeFrames`
                     offsets (fitted); ``hinge_view_prior``: the root part chosen
                     by the training views' orientation
``base_frame``       the frame snapped to the principal axes of the base's points :mod:`scapo.steps.base_frame`
                     through an offset (fitted); ``base_slot``: the slot taken as
                     the base ("auto": the least spread over the training views)
``refine``           the method's canonical shape fitted to each view             :mod:`scapo.steps.refine`
==================== ============================================================ ==================================

:class:`StepOptions` holds every option and every rule between them (one place), :meth:`StepOptions.label_suffix`
builds the label every method's predictions carry, and :class:`StepPipeline` fits and applies the steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scapo.errors import ConfigError


@dataclass(frozen=True)
class StepOptions:
    """The prediction steps a trained method's prediction takes (``scapo predict --option k=v``; every trained
    method's options inherit these fields). All off by default: the method's one-pass prediction.

    Raises:
        ConfigError: (on construction) a step that needs another one off, or two that set the same outputs; a
            ``base_frame`` or ``base_slot`` that is not one of its values."""

    refine: bool = False
    """Fit the method's own whole-object model (its canonical shape or template) to each view after the other steps
    (:mod:`scapo.steps.refine`, ``scapo predict --refine``); the label gets ``+refine``. Only for methods with a
    canonical shape or template (``scapo list``)."""
    hinge: bool = False
    """Re-fit each view's part split and pivot about every revolute joint from the method's own one-pass prediction
    (:func:`scapo.steps.hinge.hinge_prediction`); the label gets ``+hinge``."""
    hinge_axis: bool = False
    """With ``hinge``: also re-estimate each revolute axis as the line where its two parts' planes meet, where both
    are planar (:func:`scapo.steps.hinge.plane_axis`); the label gets ``+hinge-axis``."""
    hinge_bar_axis: bool = False
    """With ``hinge``: a joint whose child is a bar (an eyeglasses temple) takes as its axis its parent's principal
    direction of the rank its child's length is perpendicular to over the training views
    (:func:`scapo.steps.hinge.bar_axis_choice`, fitted on the training split; :func:`scapo.steps.hinge.bar_axis`
    per view) and its pivot from the two lines about it, its split kept; the label gets ``-bar``."""
    hinge_frames: bool = False
    """With ``hinge``: read each part's rotation from its hinge (the axis and the direction the part runs away from
    it, :func:`scapo.steps.hinge.part_axes`), through per-part offsets fitted on the training split
    (:class:`scapo.steps.hinge.HingeFrames`); the label gets ``+hinge-frames``."""
    hinge_view_prior: bool = False
    """With ``hinge_frames``: choose each view's root part among its root joint's two parts by the training views'
    root orientation in the camera (a viewpoint prior fitted on the training split, used only where those views
    agree); the label gets ``+view-prior``."""
    axis_sweep: bool = False
    """Replace each revolute axis by the one its child part sweeps about in the method's base frame over the
    training views (:class:`scapo.steps.sweep.SweepAxes`, fitted on the training split's one-pass predictions),
    turned into each view by its base rotation; applied first, so that ``hinge`` fits its pivots and split about these
    axes; the label gets ``+axis-sweep``."""
    base_frame: str = ""
    """"principal": snap each prediction's frame to the principal axes of the points it labels as the base part,
    through an offset fitted on the training split (:mod:`scapo.steps.base_frame`), each view's signed permutation
    of the axes the one nearest the network's frame; "parts": the same axes with their signs from the other parts'
    centroid (:func:`scapo.steps.base_frame.parts_signed_axes`); "" (default): the method's frame. The label gets
    ``+base-<value>``."""
    base_slot: str = "0"
    """The part slot taken as the base: "0" (default; the method's base slot), another slot number, or "auto": the
    slot whose predicted camera-frame rotations spread least over up to 512 training views
    (:func:`scapo.steps.base_frame.choose_base_slot`: a base turns with the viewpoint alone, a child also with its
    joint; no labels). With ``base_frame`` the snap works on that slot; without it the object frame ``T_cam_obj`` is
    that slot's pose and nothing else changes; the label gets ``+slot-<value>``."""

    def __post_init__(self):
        if self.hinge_axis and not self.hinge:
            raise ConfigError("hinge_axis=true re-estimates the axes within the hinge step; give hinge=true too")
        if self.hinge_bar_axis and not self.hinge:
            raise ConfigError("hinge_bar_axis=true re-estimates the axes within the hinge step; give hinge=true too")
        if self.hinge_frames and not self.hinge:
            raise ConfigError("hinge_frames=true reads the hinge step's split and pivots; give hinge=true too")
        if self.axis_sweep and (self.hinge_axis or self.hinge_bar_axis):
            raise ConfigError("axis_sweep=true sets the revolute axes; hinge_axis and hinge_bar_axis set them again: "
                              "give one of them")
        if self.hinge_view_prior and not self.hinge_frames:
            raise ConfigError("hinge_view_prior=true is part of the hinge_frames step; give hinge=true and "
                              "hinge_frames=true too")
        if self.base_frame not in ("", "principal", "parts"):
            raise ConfigError(f"base_frame must be '' (off), 'principal' or 'parts', got {self.base_frame!r}")
        slot = str(self.base_slot)
        if slot != "auto" and not (slot.isascii() and slot.isdigit()):
            raise ConfigError(f"base_slot must be a part slot number or 'auto', got {self.base_slot!r}")
        if self.hinge_frames and self.base_frame:
            raise ConfigError(f"hinge_frames=true and base_frame={self.base_frame} both set the part rotations; give "
                              "one")
        if self.hinge_frames and slot != "0":
            raise ConfigError(f"hinge_frames=true chooses its own base slot; drop base_slot={self.base_slot}")

    @property
    def object_slot_only(self) -> bool:
        """Whether ``base_slot`` sets the object frame alone (a slot other than 0, or "auto", without
        ``base_frame``)."""
        return str(self.base_slot) != "0" and not self.base_frame

    @property
    def fitted(self) -> bool:
        """Whether a step must be fitted on the training split first (:meth:`StepPipeline.fit`)."""
        return bool(self.axis_sweep or self.hinge_bar_axis or self.hinge_frames or self.base_frame
                    or self.object_slot_only)

    def label_suffix(self) -> str:
        """The label the steps add to a method's name: ``+refine``, ``+hinge`` (or ``+hinge-axis``, then ``-bar``),
        ``+hinge-frames`` (``+view-prior``), ``+axis-sweep``, ``+base-<mode>``, ``+slot-<slot>``; "" for the one-pass
        prediction. The one place a step's label is built (the order of the labels of earlier tables' rows)."""
        out = "+refine" if self.refine else ""
        if self.hinge:
            out += ("+hinge-axis" if self.hinge_axis else "+hinge") + ("-bar" if self.hinge_bar_axis else "")
        if self.hinge_frames:
            out += "+hinge-frames" + ("+view-prior" if self.hinge_view_prior else "")
        if self.axis_sweep:
            out += "+axis-sweep"
        if self.base_frame:
            out += f"+base-{self.base_frame}"
        if str(self.base_slot) != "0":
            out += f"+slot-{self.base_slot}"
        return out


def step_options(options) -> StepOptions:
    """The :class:`StepOptions` part of a method's options (an instance of a subclass, or of :class:`StepOptions`)."""
    from dataclasses import fields

    return StepOptions(**{f.name: getattr(options, f.name) for f in fields(StepOptions)})


class StepPipeline:
    """The prediction steps ``options`` turn on, for a method of kinematic structure ``joint_types`` /
    ``joint_parts`` (:class:`scapo.data.ArticulationDataset`'s): :meth:`fit` on the training split's clouds, then
    :meth:`apply` to each prediction and :meth:`info` for the predictions' record.

    Args:
        options: the steps (:class:`StepOptions`, or a method's options that inherit it).
        joint_types: ``(J,)`` joint types (0 revolute, 1 prismatic). joint_parts: ``(J, 2)`` (parent, child) slots.
        template_key: the one-pass output holding the method's canonical shape for ``refine`` (``template`` for the
            baselines, ``template_rest`` for SCAPO; its labels in ``template_label``).
        batch_size: clouds per batch of the refinement.
    """

    def __init__(self, options, joint_types, joint_parts, template_key: str = "template", batch_size: int = 32):
        self.options = step_options(options)
        self.joint_types = [int(t) for t in joint_types]
        self.joint_parts = [tuple(int(x) for x in p) for p in np.asarray(joint_parts).reshape(-1, 2)]
        self.template_key = template_key
        self.batch_size = int(batch_size)
        self.sweep = None
        """The ``axis_sweep`` step (:class:`scapo.steps.sweep.SweepAxes`), fitted."""
        self.bar_ranks: list | None = None
        """``hinge_bar_axis``: per joint the rank of :func:`scapo.steps.hinge.bar_axis_choice`, fitted."""
        self.frames = None
        """The ``hinge_frames`` step (:class:`scapo.steps.hinge.HingeFrames`), fitted."""
        self.base_slot = 0
        """The part slot taken as the base (``base_slot``; chosen on the training split when "auto")."""
        self.base_dispersion: np.ndarray | None = None
        """``(P,)`` each slot's rotation dispersion over the training views (:func:`.base_frame.choose_base_slot`)."""
        self.base_offset: np.ndarray | None = None
        """``(3, 3)`` the fitted base-axes offset (``base_frame``, :func:`.base_frame.fit_base_offset`)."""
        self.base_support = float("nan")
        self.base_pair: tuple[int, int] | None = None
        """``base_frame=parts``: the signed ranks of the base's axes (:func:`.base_frame.choose_signed_pair`)."""
        self.fitted = False

    def fit(self, points: np.ndarray, one_pass: Callable[[np.ndarray], dict]) -> StepPipeline:
        """Fit the steps that need it on training clouds ``points (M, N, 3)`` (camera frame, metres; at most 512
        evenly spaced views are read, :func:`training_views`) from the method's one-pass outputs ``one_pass(clouds)``
        (no labels), each step on the outputs of the steps before it. Returns self.

        Raises:
            ConfigError: a base slot the method does not have. InputError: the method labels no training view's points
            as the base (``base_frame``)."""
        o = self.options
        if not o.fitted:
            self.fitted = True
            return self
        pts = np.asarray(points)
        pts = pts[training_views(len(pts))]
        raw = one_pass(pts)
        if o.axis_sweep:  # first: the other steps read its axes
            from scapo.steps.sweep import SweepAxes

            self.sweep = SweepAxes(self.joint_types, self.joint_parts).fit(pts, raw)
            raw = self.sweep(raw)
        if o.hinge_bar_axis:
            from scapo.steps.hinge import bar_axis_choice

            self.bar_ranks = bar_axis_choice(pts, raw["part_label"], self.joint_types, self.joint_parts)
        raw = self._hinged(pts, raw)
        if o.base_frame or o.object_slot_only:
            self._fit_base(pts, raw)
        if o.hinge_frames:
            from scapo.steps.hinge import HingeFrames

            self.frames = HingeFrames(self.joint_types, self.joint_parts, o.hinge_view_prior)
            self.frames.fit(pts, raw)
        self.fitted = True
        return self

    def _fit_base(self, pts: np.ndarray, o: dict) -> None:
        from scapo.steps.base_frame import (
            base_axes,
            choose_base_slot,
            choose_signed_pair,
            fit_base_offset,
            parts_signed_axes,
        )

        pose = np.asarray(o["part_pose"])
        slot, self.base_dispersion = choose_base_slot(pose)
        if str(self.options.base_slot) != "auto":
            slot = int(self.options.base_slot)
            if slot >= pose.shape[1]:
                raise ConfigError(f"base_slot={slot}: the method has part slots 0-{pose.shape[1] - 1}")
        self.base_slot = slot
        if self.options.base_frame == "parts":
            self.base_pair = choose_signed_pair(pts, o["part_label"], slot)
            E, ok = parts_signed_axes(pts, o["part_label"], self.base_pair, slot)
            self.base_offset, self.base_support, _ = fit_base_offset(pose[ok, slot, :3, :3], E[ok],
                                                                     group=np.eye(3)[None])
        elif self.options.base_frame:
            E, ok = base_axes(pts, o["part_label"], slot=slot)
            self.base_offset, self.base_support, _ = fit_base_offset(pose[ok, slot, :3, :3], E[ok])

    def _hinged(self, points: np.ndarray, o: dict) -> dict:
        if not self.options.hinge:
            return o
        from scapo.steps.hinge import hinge_prediction

        return hinge_prediction(np.asarray(points), o, self.joint_types, self.joint_parts,
                                axis_from_planes=self.options.hinge_axis, bar_axes=self.bar_ranks)

    def apply(self, points: np.ndarray, o: dict) -> dict:
        """The steps, in order, on the one-pass outputs ``o`` of ``points (M, N, 3)``: ``axis_sweep``, ``hinge``,
        the part-rotation step (``hinge_frames``, ``base_frame``, or the object frame on ``base_slot``), ``refine``.
        Returns the outputs with the steps' changes (and their per-view diagnostics, e.g. ``base_snap_deg``).

        Raises:
            ConfigError: a step that needs fitting before :meth:`fit`."""
        op = self.options
        if op.fitted and not self.fitted:
            raise ConfigError(f"the prediction steps {op.label_suffix()} are fitted on a training split first: "
                              "fit(train) (scapo predict --data reads its training split)")
        pts = np.asarray(points)
        if op.axis_sweep:
            o = self.sweep(o)
        o = self._hinged(pts, o)
        if op.hinge_frames:
            o = self.frames(pts, o)
        elif op.base_frame:
            from scapo.steps.base_frame import snap_to_base

            o = snap_to_base(pts, o, self.base_offset, slot=self.base_slot, pair=self.base_pair)
        elif op.object_slot_only:  # the object frame on the chosen slot; nothing else changes
            o = {**o, "T_cam_obj": np.asarray(o["part_pose"])[:, self.base_slot].copy()}
        if op.refine:
            from scapo.steps.refine import refine_prediction

            o = refine_prediction(pts, o, o[self.template_key], o["template_label"], self.joint_types,
                                  self.joint_parts, batch_size=self.batch_size)
        return o

    def info(self, o: dict) -> dict:
        """What the predictions record of the steps applied to ``o`` (their fitted values and per-split summaries)."""
        op, out = self.options, {}
        if op.refine:
            from scapo.steps.refine import refine_info

            out.update(refine_info(o))
        if op.hinge:
            from scapo.steps.hinge import hinge_info

            out["hinge"] = hinge_info(o, op.hinge_axis, self.bar_ranks)
        if op.hinge_frames:
            out["hinge_frames"] = self.frames.info(o)
        if op.axis_sweep:
            out["axis_sweep"] = self.sweep.info()
        if op.base_frame:
            out["base_frame"] = {"offset": np.round(self.base_offset, 6).tolist(),
                                 "train_support": round(self.base_support, 4), "slot": self.base_slot,
                                 "slot_option": str(op.base_slot),
                                 "dispersion": np.round(self.base_dispersion, 4).tolist(),
                                 "snap_deg_median": round(float(np.median(o["base_snap_deg"])), 2),
                                 "mode": op.base_frame, **({"signed_ranks": list(self.base_pair)}
                                                           if self.base_pair else {})}
        elif op.object_slot_only:
            out["object_slot"] = {"slot": self.base_slot, "option": str(op.base_slot),
                                  "dispersion": np.round(self.base_dispersion, 4).tolist()}
        return out


def training_views(n: int, most: int = 512) -> np.ndarray:
    """Indices of up to ``most`` evenly spaced views of ``n`` training views: what a prediction step fitted on the
    training split reads."""
    return np.unique(np.linspace(0, n - 1, min(n, int(most))).round().astype(int))


__all__ = ["StepOptions", "StepPipeline", "step_options", "training_views"]
