"""``scapo train``: two-stage self-supervised training of SCAPO on unlabeled clouds, resumable.

Only the ``points`` of the training split are used (no labels, poses or joints), except in the
semi-supervised setting of the paper's Table 2 (``TrainConfig.supervision``, presets ``.../sj``), where
the segmentation and / or joint labels it names are used too (:mod:`scapo.losses.supervised`). A run folder
holds ``run.json`` (preset, dataset, model structure), ``checkpoint.pt`` (written atomically after
every epoch, with optimiser, schedule and RNG state so that a resumed run gives the same result),
``log.csv`` (one row per iteration) and ``losses.png``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import torch

from scapo.data.dataset import load
from scapo.engine import CloudSet, FitConfig, Stage, TrainJob, lifecycle
from scapo.engine.lifecycle import RunSpec
from scapo.errors import ConfigError, DatasetError
from scapo.files import write_json
from scapo.losses import LossConfig, stage1_terms, stage2_terms, weighted_total
from scapo.models.branch import apply_branch
from scapo.models.presets import TrainConfig, get_preset
from scapo.models.refine import refine_from_dict
from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.nn.encoder import EncoderConfig

#: the log's loss-term columns of each stage, in order (stage 2 also logs stage 1's)
STAGE1_TERMS = ("rec", "ortho", "aug_consist", "can_consist", "align", "consensus", "cycle")
STAGE2_TERMS = ("recon", "kp_seg", "seg", "shape_var", "dir_align", "joint_prox", "joint_boundary", "sup_seg",
                "sup_joint")


def loss_terms(model: SCAPOModel, X: torch.Tensor, stage: int, losses, sup: dict | None = None,
               scale: torch.Tensor | None = None, sup_weight: float = 1.0,
               frame: torch.Tensor | None = None) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """One forward pass of a training step on normalised clouds ``X (B, N, 3)``: the unweighted loss
    terms of ``stage`` (1: stage-1 terms; 2: stage-1 and stage-2 terms) and their weighted total
    under ``losses`` (a :class:`~scapo.losses.LossConfig`).

    ``sup``: in the semi-supervised setting (:mod:`scapo.losses.supervised`), the batch's labels:
    ``part_label (B, N)`` and / or ``joint_axis``, ``joint_pivot (B, J, 3)`` (camera frame, metres;
    ``scale (B,)`` is the normalisation of ``X``); stage 2 then adds ``sup_seg`` (NLL of the skinning
    weights) and ``sup_joint`` (the camera-frame joints), weighted by ``sup_weight``. ``frame (B, 3, 3)``: stage 2's
    frames (canonical -> camera) where not all zeros (``TrainConfig.stage2_frame = "parts"``,
    :meth:`~scapo.models.scapo_model.SCAPOModel.stage2`)."""
    out = model(X, stage=stage) if stage == 1 or frame is None else model(X, stage=stage, frame=frame)
    terms = stage1_terms(model, X, out, losses, align=stage == 1 or losses.align_in_stage2, scale=scale)
    if stage == 2:
        terms.update(stage2_terms(model, X, out, losses))
    total = weighted_total(terms, losses, stage)
    if stage == 2 and sup:
        from scapo.losses.supervised import joint_loss, seg_nll

        extra = {}
        if "part_label" in sup:
            extra["sup_seg"] = seg_nll(out.w, sup["part_label"])
        if "joint_axis" in sup and model.cfg.joint_types:
            R, t = out.R, out.enc.t
            axis = out.axis_x @ R.transpose(1, 2)
            pivot = out.pivot_x @ R.transpose(1, 2) + t[:, None]
            extra["sup_joint"] = joint_loss(axis, pivot, sup["joint_axis"].to(X), sup["joint_pivot"].to(X)
                                            / scale[:, None, None], model.cfg.joint_types)
        terms.update(extra)
        total = total + sup_weight * sum(extra.values())
    return terms, total


class TrainingClouds(CloudSet):
    """The training split's point clouds for the engine (:class:`~scapo.engine.CloudSet`), each a random subset
    of ``points`` points; ``points`` only (the paper's setting), or, with ``supervision``
    (:mod:`scapo.losses.supervised`), also the labels it allows (the subset's ``part_label``, the sample's
    ``joint_axis`` / ``joint_pivot``).

    Raises:
        DatasetError: an empty training split, or a dataset without the fields the supervision needs."""

    def __init__(self, data: str | Path, points: int, supervision: str = ""):
        from scapo.losses.supervised import supervised_fields

        ds = load(data, "train")
        if len(ds) == 0:
            raise DatasetError(f"{data}: the training split is empty")
        fields = supervised_fields(supervision)
        arrays = ds.arrays(["points", *fields])
        super().__init__({"points": torch.from_numpy(arrays["points"]).float(),
                          **{k: torch.from_numpy(arrays[k]) for k in fields}}, points)


def labelled_centroids(K: torch.Tensor, template: torch.Tensor, template_labels: torch.Tensor | None,
                       points: torch.Tensor, point_labels: torch.Tensor, min_points: int = 8) -> torch.Tensor:
    """Initial keypoints ``(P, 3)`` from segmentation labels (``TrainConfig.label_init``), canonical frame.

    Part ``p``'s keypoint is the centroid of the ``template (M, 3)`` points labelled ``p`` by
    ``template_labels (M,)`` when there are at least ``min_points`` of them (the template is one cloud in
    one articulation state), else of ``points (U, 3)`` labelled ``p`` by ``point_labels (U,)`` (all the
    canonical clouds: a part hidden in the template's view), else ``K[p]`` (the unlabeled split's, for a
    part no cloud shows). Labels -1 (background) are ignored."""
    out = K.clone()
    for p in range(len(K)):
        if template_labels is not None and int((template_labels == p).sum()) >= min_points:
            out[p] = template[template_labels == p].mean(0)
        elif bool((point_labels == p).any()):
            out[p] = points[point_labels == p].mean(0)
    return out.to(K)


def model_config(card: dict, preset: TrainConfig) -> ModelConfig:
    """The network's structure for a dataset's category (parts and joints from its card)."""
    return ModelConfig(num_parts=len(card["part_names"]), joint_types=tuple(card["joint_type"]),
                       joint_parts=tuple(tuple(p) for p in card["joint_parts"]), encoder=preset.encoder,
                       template_points=preset.template_points, gamma=preset.gamma, root_motion=preset.root_motion,
                       anchors=preset.anchors, stage1_template=preset.losses.template > 0)


#: preset fields that only affect inference; a checkpoint is not refused when they differ
INFERENCE_FIELDS = ("refine",)
#: preset fields added after runs were trained, with the value those runs had: at that value a field is
#: left out of the identity, so older runs keep their identity (and their checkpoints stay valid)
ADDED_FIELDS = {"branch_flip": False, "supervision": "", "sup_weight": 1.0, "label_init": False, "anchors": "",
                "axis_init": "motion", "split_init": "rigid", "split_labels": False, "split_frame": "stage1",
                "stage2_frame": "stage1", "parts_axes": "pca", "axis_fixed": False, "split_overseg": 0,
                "compile": False}
#: preset fields removed after runs were trained with them (switches whose val results did not earn them a place;
#: docs/canonical_ladder.md), with the value at which a run trained then is what training does now: at that value the
#: field is dropped (from the run's identity too, so its checkpoints stay valid); at another value the run cannot be
#: continued or read by this code (:func:`preset_from_dict` says which commit still can)
REMOVED_FIELDS = {"relabel": 0, "relabel_frames": True, "frame_target": 0.0, "label_starts": "", "label_retry": 0.0,
                  "label_stride": 1}
#: the same for the preset's LossConfig
LOSS_REMOVED_FIELDS = {"aug_crop": False, "view_consist": 0.0, "rec_one_sided": False, "seg_labels": "nearest"}
#: preset values removed likewise (``split_frame = "parts"``: the pseudo-labels made in each cloud's parts-signed
#: frame, lower S on all three eyeglasses seeds)
REMOVED_VALUES = {"split_frame": ("parts",)}
#: the last commit with :data:`REMOVED_FIELDS` and :data:`REMOVED_VALUES`
REMOVED_AFTER = "bd34536"
#: the same for fields added to the preset's LossConfig
LOSS_ADDED_FIELDS = {"template": 0.0}
#: the same for fields added to the preset's EncoderConfig
ENCODER_ADDED_FIELDS = {"frame": "regressed", "residual_deg": 0.0}


def _run_identity(preset: TrainConfig, card: dict) -> dict:
    return {"preset": dataclasses.asdict(preset), "dataset_hash": card["dataset_hash"], "category": card["category"],
            "part_names": card["part_names"], "joint_type": card["joint_type"], "joint_parts": card["joint_parts"]}


def _training_identity(identity: dict) -> dict:
    """``identity`` without the preset's inference-only fields (what decides whether a checkpoint fits)."""
    preset = {k: v for k, v in identity.get("preset", {}).items()
              if k not in INFERENCE_FIELDS and not (k in ADDED_FIELDS and v == ADDED_FIELDS[k])
              and not (k in REMOVED_FIELDS and v == REMOVED_FIELDS[k])}
    if isinstance(preset.get("losses"), dict):
        preset["losses"] = {k: v for k, v in preset["losses"].items()
                            if not (k in LOSS_ADDED_FIELDS and v == LOSS_ADDED_FIELDS[k])
                            and not (k in LOSS_REMOVED_FIELDS and v == LOSS_REMOVED_FIELDS[k])}
    if isinstance(preset.get("encoder"), dict):
        preset["encoder"] = {k: v for k, v in preset["encoder"].items()
                             if not (k in ENCODER_ADDED_FIELDS and v == ENCODER_ADDED_FIELDS[k])}
    return {**identity, "preset": preset}


def _identity_hash(obj: dict) -> str:
    return hashlib.sha256(json.dumps(_training_identity(obj), sort_keys=True, default=str).encode()).hexdigest()


def _drop_removed(fields: dict, removed: dict, name, prefix: str = "") -> dict:
    """``fields`` without the :data:`REMOVED_FIELDS`-style entries ``removed`` (name -> off value) at their off value.

    Raises:
        ConfigError: one of them is set to another value (the run needs the commit that still reads it)."""
    fields = dict(fields)
    for k, off in removed.items():
        v = fields.pop(k, off)
        if v != off:
            raise ConfigError(f"this run (preset {name!r}) was trained with {prefix}{k}={v!r}, a switch removed after "
                              f"{REMOVED_AFTER} (its val result did not earn it a place; docs/canonical_ladder.md): "
                              f"read or resume it with scapo at {REMOVED_AFTER}")
    return fields


def preset_from_dict(d: dict) -> TrainConfig:
    """The :class:`TrainConfig` of a run's stored preset (``run.json``, a checkpoint's identity).

    Raises:
        ConfigError: the run was trained with a switch or setting this code no longer has (:data:`REMOVED_FIELDS`,
            :data:`LOSS_REMOVED_FIELDS`, :data:`REMOVED_VALUES`)."""
    for k, gone in REMOVED_VALUES.items():
        if d.get(k) in gone:
            raise ConfigError(f"this run (preset {d.get('name')!r}) was trained with {k}={d[k]!r}, a setting removed "
                              f"after {REMOVED_AFTER} (its val result did not earn it a place; docs/canonical_ladder.md"
                              f"): read or resume it with scapo at {REMOVED_AFTER}")
    d = _drop_removed(d, REMOVED_FIELDS, d.get("name"))
    d["encoder"] = EncoderConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["encoder"].items()})
    loss = _drop_removed(d["losses"], LOSS_REMOVED_FIELDS, d.get("name"), "losses.")
    loss["disabled"] = tuple(loss.get("disabled", ()))
    d["losses"] = LossConfig(**loss)
    d["refine"] = refine_from_dict(d.get("refine"))  # runs from before the refinement existed: off
    return TrainConfig(**d)


class ScapoJob:
    """SCAPO's training job for the engine (:func:`scapo.engine.lifecycle.train` sets the run up): the network for
    the dataset's category, initialised from ``preset.seed``; stage 1 trains the encoder and decoder on the stage-1
    terms; stage 2 starts from the template initialisation (:meth:`_init_template`) and trains everything on both
    stages' terms (:func:`loss_terms`).

    Args:
        preset: the resolved :class:`~scapo.models.presets.TrainConfig`. data: dataset folder (its training split,
            points only unless ``preset.supervision`` names labels). run: the run folder (``branch.json`` is written
            there). device: the process's device. ctx: the data-parallel context (rank 0 writes files).
    """

    def __init__(self, preset: TrainConfig, data: str | Path, run: str | Path, device: torch.device, ctx):
        self.preset = preset
        self.data = Path(data)
        self.run = Path(run)
        self.device = device
        self.dist = ctx
        self.card = load(self.data, "train").card
        self.mcfg = model_config(self.card, self.preset)
        self._template_record: dict[str, np.ndarray] = {}  # template_split.npz (see _save_template_record)
        with torch.random.fork_rng(devices=[]):  # the caller's global RNG is left as it was
            torch.manual_seed(self.preset.seed)  # parameter initialisation is part of the run's identity
            self.model = SCAPOModel(self.mcfg).to(self.device)

    def job(self) -> TrainJob:
        """The engine's :class:`~scapo.engine.TrainJob`: both stages, their epochs and learning rates from the
        preset."""
        pc = self.preset
        data = TrainingClouds(self.data, pc.train_points, pc.supervision)
        if pc.split_labels:
            self._load_split_labels(data)
        view = ("template",) if pc.losses.template > 0 else ()  # logged only where on (older logs' columns)
        stages = [Stage(index=1, epochs=pc.stage1_epochs, lr=pc.lr_stage1, params=lambda: self._params(1),
                        losses=lambda batch, progress: self._losses(1, batch), terms=STAGE1_TERMS + view),
                  Stage(index=2, epochs=pc.stage2_epochs, lr=pc.lr_stage2, params=lambda: self._params(2),
                        losses=lambda batch, progress: self._losses(2, batch), terms=STAGE2_TERMS + view,
                        on_start=lambda: self._init_template(data))]
        cfg = FitConfig(batch_size=pc.batch_size, weight_decay=pc.weight_decay, min_lr=pc.min_lr,
                        grad_clip=pc.grad_clip, max_steps_per_epoch=pc.max_steps_per_epoch, seed=pc.seed,
                        order="shuffle", compile=pc.compile)
        mcfg = dataclasses.asdict(self.mcfg)
        return TrainJob(model=self.model, data=data, stages=stages, config=cfg,
                        desc=f"train scapo {self.card['category']} ({pc.name})",
                        load_state=self.model.load_checkpoint_state, extras=lambda done: {"model_config": mcfg})

    def _losses(self, stage: int, batch: dict) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        pc = self.preset
        sup = {k: v for k, v in batch.items() if k not in ("points", "frame_target")}  # labels
        X, scale = SCAPOModel.normalize(batch["points"])
        return loss_terms(self.model, X, stage, pc.losses, sup, scale, pc.sup_weight,
                          frame=batch.get("frame_target") if pc.stage2_frame == "parts" else None)

    def _params(self, stage: int):
        if stage == 1:
            extra = [self.model.template_s1] if self.mcfg.stage1_template else []
            return [*self.model.encoder.parameters(), *self.model.decoder.parameters(), *extra]
        return list(self.model.parameters())

    @torch.no_grad()
    def _init_template(self, data: TrainingClouds) -> torch.Tensor | None:
        """Initial state of stage 2 from up to 64 training clouds canonicalised by the stage-1 encoder.

        With ``part_init`` (default): ``Y_base`` is a farthest-point sample of the medoid canonical
        cloud (one instance in one articulation state), and the keypoint and joint heads start from
        the most rigid part split (:meth:`_init_parts`). Without it: ``Y_base`` is a farthest-point
        sample of the union of the canonical clouds and the heads keep their fixed initialisation.
        With ``branch_flip``, the branch correction is fitted first (:meth:`_init_branch`) and the
        canonical clouds are taken in the corrected frames. Returns the template's segmentation labels
        ``(M,)`` int64 (-1 background) with ``label_init`` and a medoid template, else None.
        """
        from scapo.models import part_init
        from scapo.ops.sampling import farthest_point_indices

        g = torch.Generator().manual_seed(self.preset.seed)
        idx = torch.randperm(len(data), generator=g)[: min(len(data), 64)]
        if self.preset.branch_flip:
            self._init_branch(data)
        X, _ = SCAPOModel.normalize(data.clouds[idx].to(self.device))
        self.model.eval()
        enc = self.model.frame(X)
        R = apply_branch(enc.R, self.model.branch, self.model.branch_flip)
        self.model.train()
        clouds = ((X - enc.t[:, None]) @ R).cpu()
        sub = clouds[:, :: max(1, clouds.shape[1] // 128)]
        M = self.mcfg.template_points
        rng = np.random.default_rng(self.preset.seed)
        medoid = None
        if self.preset.part_init and len(clouds) >= 2 and clouds.shape[1] >= M:
            medoid = part_init.medoid(sub)
            S = clouds[medoid].numpy()
        else:
            S = clouds.reshape(-1, 3).numpy()
        fps = farthest_point_indices(S, M, rng)
        self.model.y_base.copy_(torch.from_numpy(S[fps]).to(self.model.y_base))
        # where the template came from (a diagnosis reads the true labels of its points; training never does)
        self._template_record = {} if medoid is None else {"sample": np.int64(idx[medoid]),
                                                           "points": np.asarray(fps, dtype=np.int64)}
        labels = None
        part_label = data.extra.get("part_label")
        if part_label is None:
            part_label = self._init_labels(data)
        if self.preset.label_init and part_label is not None:  # the template's points keep their labels
            lab = part_label[idx].long()
            labels = (lab[medoid][torch.from_numpy(np.asarray(fps))] if medoid is not None else None,
                      clouds.reshape(-1, 3), lab.reshape(-1))
        if self.preset.part_init and len(clouds) >= 2:
            sub_labels = None
            if self.preset.label_init and part_label is not None:
                sub_labels = part_label[idx].long()[:, :: max(1, clouds.shape[1] // 128)]
            split = self._init_parts(sub, clouds.reshape(-1, 3), self.model.y_base.detach().cpu(), labels,
                                     sub_labels)
            if self._template_record:
                self._template_record["labels"] = split.numpy().astype(np.int64)
            if self.preset.split_labels:
                self._label_training_clouds(data, split, idx, max(1, clouds.shape[1] // 128))
        if self._template_record and self.dist.is_main:
            self._save_template_record()
        return labels[0] if labels is not None else None

    TEMPLATE_SPLIT = "template_split.npz"

    def _save_template_record(self) -> None:
        """Write ``template_split.npz`` to the run folder: the training sample stage 2's template was drawn from
        (``sample``, int64, an index into the training split), its points' indices in that cloud (``points (M,)``
        int64), the split stage 2 starts from (``labels (M,)`` int64) and, with ``split_frame = "refit"``, the split
        fitted again (``labels_refit (M,)``). Not read by training or prediction:
        ``bench/diagnostics/pseudo_label_confusion.py``
        scores the template's split against the true labels of those points (a diagnosis of the split)."""
        import io

        from scapo.files import atomic_write_bytes

        buf = io.BytesIO()
        np.savez(buf, **self._template_record)
        atomic_write_bytes(self.run / self.TEMPLATE_SPLIT, buf.getvalue())

    SPLIT_LABELS = "split_labels.npy"

    @torch.no_grad()
    def _label_training_clouds(self, data: TrainingClouds, template_labels: torch.Tensor,
                               idx: torch.Tensor | None = None, step: int = 1) -> None:
        """``TrainConfig.split_labels``: every training cloud, in its (branch-corrected) stage-1 frame, labelled by
        the template split stage 2 starts from, ``template_labels (M,)`` int64 (:meth:`_init_parts`'s;
        :func:`scapo.models.part_init.label_clouds`); the labels ``(M, N)``
        int64 become the clouds' ``part_label`` (so batches carry them and stage 2 adds ``sup_seg``) and are saved to
        ``split_labels.npy`` in the run folder for a resume.

        ``split_frame = "refit"`` (with ``stage2_frame = "parts"``): once the target frames are found, the starting
        split is fitted again (:meth:`_init_parts`, keypoint and joint heads included) on the clouds ``idx (64,)``
        (every ``step``-th point) that :meth:`_init_template` fitted it on, now canonicalised by their target frames,
        every cloud is labelled by it in its target frame, and the targets are read again from those labels."""
        from scapo.models import part_init

        template = self.model.y_base.detach().cpu()
        canon, frames = [], []
        self.model.eval()
        for k in range(0, len(data), 64):
            X, _ = SCAPOModel.normalize(data.clouds[k:k + 64].to(self.device))
            enc = self.model.frame(X)
            R = apply_branch(enc.R, self.model.branch, self.model.branch_flip)
            canon.append(((X - enc.t[:, None]) @ R).cpu())
            frames.append(R.cpu())
        self.model.train()
        canon = torch.cat(canon)
        def label(split: torch.Tensor, clouds: torch.Tensor) -> torch.Tensor:
            return part_init.label_clouds(template, split, clouds, self.mcfg.num_parts)

        labels = label(template_labels, canon)
        if self.preset.stage2_frame == "parts":
            frames = torch.cat(frames)
            targets, pair, tE = self._frame_targets(template, template_labels, canon, frames, labels)
            if self.preset.split_frame == "refit" and tE is not None and idx is not None:
                has = (targets.flatten(1).abs().sum(-1) > 0)[:, None, None]
                turned = torch.where(has, targets, frames)  # each cloud's target frame where it has one
                canon = torch.bmm(canon, frames.transpose(1, 2) @ turned)  # (X - t) F = S R^T F
                sub = canon[idx][:, ::step]
                template_labels = self._init_parts(sub, canon[idx].reshape(-1, 3), template)
                before, labels = labels, label(template_labels, canon)
                if self._template_record:
                    self._template_record["labels_refit"] = template_labels.numpy().astype(np.int64)
                if self.dist.is_main:
                    write_json(self.run / "split_refit.json",
                               {"template_part_points": torch.bincount(template_labels, minlength=self.mcfg.num_parts
                                                                       ).tolist(),
                                "labels_changed": round(float((labels != before).double().mean()), 4)})
                targets, pair, tE = self._frame_targets(template, template_labels, canon, turned, labels)
                frames = turned  # canon is now in these frames (for axis_init='sweep' below)
            data.tensors["frame_target"] = targets
            if self.preset.axis_init == "sweep" and tE is not None:
                self._sweep_axes(canon, frames, targets, labels)
            if self.preset.stage2_frame == "parts" and tE is not None:  # stage 2 and prediction in that frame
                self.model.parts_frame.copy_(tE.to(self.model.parts_frame))
                self.model.parts_pair.copy_(torch.tensor(pair).to(self.model.parts_pair))
                self.model.parts_plane.fill_(int(self.preset.parts_axes == "plane"))
            if self.dist.is_main:
                np.save(self.run / self.FRAME_TARGETS, targets.numpy().astype(np.float64), allow_pickle=False)
        data.tensors["part_label"] = labels
        if self.dist.is_main:
            np.save(self.run / self.SPLIT_LABELS, labels.numpy().astype(np.int64), allow_pickle=False)

    FRAME_TARGETS = "frame_targets.npy"

    @torch.no_grad()
    def _sweep_axes(self, canon: torch.Tensor, frames: torch.Tensor, targets: torch.Tensor,
                    labels: torch.Tensor) -> None:
        """``TrainConfig.axis_init = "sweep"``: each revolute joint's starting axis (the joint head's bias) becomes the
        direction its child's length sweeps about (:func:`scapo.ops.sweep.sweep_axis`) over the training clouds in
        their target frames: ``canon (B, N, 3)`` (stage-1 canonical clouds) turned from their ``frames (B, 3, 3)``
        into their ``targets (B, 3, 3)`` (all zeros: the cloud is skipped), its child's points those its
        pseudo-labels ``labels (B, N)`` give (at least :data:`scapo.ops.sweep.MIN_POINTS`), signed as the axis it
        replaces, and with ``axis_fixed`` held there. A joint with fewer than :data:`scapo.ops.sweep.MIN_VIEWS` such
        clouds keeps its axis. What was found goes to ``axis_sweep.json`` in the run folder."""
        from scapo.ops.sweep import MIN_VIEWS, child_directions, sweep_axis

        has = targets.flatten(1).abs().sum(-1) > 0
        turned = torch.bmm(canon[has], frames[has].transpose(1, 2) @ targets[has]).double().numpy()
        lab = labels[has].numpy()
        eye = np.tile(np.eye(3), (len(turned), 1, 1))
        jb = self.model.joints.joint_bias()
        found = []
        for j, ((_, child), kind) in enumerate(zip(self.mcfg.joint_parts, self.mcfg.joint_types)):
            u = child_directions(turned, lab, eye, child) if kind == 0 else np.zeros((0, 3))
            if len(u) < MIN_VIEWS:
                found.append({"joint": j, "views": int(len(u)), "mode": "kept"})
                continue
            axis, info = sweep_axis(u)
            old = jb[j, 3:6].detach().double().cpu().numpy()
            axis = axis if float(axis @ old) >= 0 else -axis
            cos = float(abs(axis @ old) / max(np.linalg.norm(old), 1e-12))
            jb[j, 3:6] = torch.from_numpy(axis).to(jb)
            if self.preset.axis_fixed:
                self.model.joints.freeze_axis(j)
            found.append({"joint": j, **info, "axis": [round(float(x), 4) for x in axis],
                          "turned_from_deg": round(float(np.degrees(np.arccos(min(cos, 1.0)))), 2),
                          "fixed": bool(self.preset.axis_fixed)})
        if self.dist.is_main:
            write_json(self.run / "axis_sweep.json", {"joints": found})

    def _frame_targets(self, template: torch.Tensor, template_labels: torch.Tensor, canon: torch.Tensor,
                       frames: torch.Tensor, labels: torch.Tensor
                       ) -> tuple[torch.Tensor, tuple[int, int] | None, torch.Tensor | None]:
        """``TrainConfig.stage2_frame = "parts"``: per training cloud the frame ``R_i E_i E_Y^T``
        ``(B, 3, 3)`` float32
        (canonical -> camera; all zeros where the cloud's or the template's signed axes are not found), from its
        stage-1 frame ``frames (B, 3, 3)``, its base's axes signed by its other parts in that frame ``E_i``
        (:func:`scapo.ops.signed_axes.parts_signed_axes` of ``canon (B, N, 3)`` under ``labels (B, N)``, base = slot
        0, the signed ranks chosen over the clouds) and the template's ``E_Y`` (``template (M, 3)``,
        ``template_labels (M,)``): the frame in which the cloud's signed base axes are the template's; also the signed
        ranks and ``E_Y (3, 3)`` (None when not found). What was found
        goes to ``frame_target.json`` in the run folder (the ranks, how many clouds have a target, and the share whose
        target is within 15 / beyond 90 deg of its stage-1 frame)."""
        pts, lab = canon.double().numpy(), labels.numpy()
        out, tpl = torch.zeros(len(pts), 3, 3), None
        pair, E, ok, tE = _signed_frames(template, template_labels, pts, lab, axes=self.preset.parts_axes)
        if tE is not None:
            tpl = torch.from_numpy(tE).float()
            T = frames.double().numpy() @ E @ tE.T
            out[torch.from_numpy(ok)] = torch.from_numpy(T[ok]).float()
        has = out.flatten(1).abs().sum(-1) > 0
        cos = ((out * frames).sum((-2, -1)) - 1.0) / 2.0
        ang = torch.rad2deg(torch.arccos(cos.clamp(-1.0, 1.0)))[has]
        if self.dist.is_main:
            write_json(self.run / "frame_target.json",
                       {"signed_ranks": None if pair is None else list(pair), "clouds": int(len(pts)),
                        "with_target": int(has.sum()),
                        "within_15_deg": round(float((ang <= 15).double().mean()), 4) if len(ang) else None,
                        "beyond_90_deg": round(float((ang > 90).double().mean()), 4) if len(ang) else None})
        return out, pair, tpl

    def _load_split_labels(self, data: TrainingClouds) -> None:
        """On a resume inside stage 2, the pseudo-labels :meth:`_label_training_clouds` saved (nothing before it ran),
        and with ``stage2_frame = "parts"`` the target frames.

        Raises:
            DatasetError: a file is unreadable or does not match the training clouds."""
        self._load_frame_targets(data)
        path = self.run / self.SPLIT_LABELS
        if not path.is_file():
            return
        try:
            labels = np.load(path, allow_pickle=False)  # plain integers: no code runs from the file
        except (OSError, ValueError) as e:
            raise DatasetError(f"{path}: unreadable ({e}); delete the run folder and train again") from None
        if labels.shape != tuple(data.clouds.shape[:2]) or labels.dtype.kind not in "iu" or \
                (labels.size and (labels.min() < 0 or labels.max() >= self.mcfg.num_parts)):
            raise DatasetError(f"{path}: pseudo-labels of shape {labels.shape} do not match the "
                               f"{tuple(data.clouds.shape[:2])} training clouds of {self.mcfg.num_parts} parts; delete "
                               "the run folder and train again")
        data.tensors["part_label"] = torch.from_numpy(labels.astype(np.int64))

    def _load_frame_targets(self, data: TrainingClouds) -> None:
        path = self.run / self.FRAME_TARGETS
        if self.preset.stage2_frame != "parts" or not path.is_file():
            return
        try:
            T = np.load(path, allow_pickle=False)  # plain numbers: no code runs from the file
        except (OSError, ValueError) as e:
            raise DatasetError(f"{path}: unreadable ({e}); delete the run folder and train again") from None
        if T.shape != (len(data), 3, 3) or T.dtype.kind != "f" or not np.isfinite(T).all():
            raise DatasetError(f"{path}: target frames of shape {T.shape} do not match the {len(data)} training "
                               "clouds (or are not finite); delete the run folder and train again")
        data.tensors["frame_target"] = torch.from_numpy(T.astype(np.float32))

    def _init_labels(self, data: TrainingClouds) -> torch.Tensor | None:
        """``part_label (M, N)`` of the training clouds for ``label_init`` without segmentation supervision (a
        diagnosis: the labels place the initial split only, no loss reads them), read from the dataset here so that no
        batch holds them; None without ``label_init``.

        Raises:
            DatasetError: the training split's labels do not match its clouds."""
        if not self.preset.label_init:
            return None
        labels = torch.from_numpy(load(self.data, "train").arrays(["part_label"])["part_label"])
        if labels.shape[0] != len(data):
            raise DatasetError(f"{self.data}: the training split's labels do not match its clouds")
        return labels

    @torch.no_grad()
    def _init_branch(self, data: TrainingClouds, views: int = 512, points: int = 128) -> None:
        """Fit the stage-2 branch correction (:func:`scapo.models.branch.fit_branch`) on the stage-1
        frames of up to ``views`` training clouds (evenly spaced) and store it in the model's buffers;
        what was found goes to ``branch.json`` in the run folder."""
        from scapo.models.branch import fit_branch

        idx = torch.linspace(0, len(data) - 1, min(views, len(data))).round().long()
        n = data.clouds.shape[1]
        sel = torch.linspace(0, n - 1, min(points, n)).round().long()
        self.model.eval()
        Rs, Ss = [], []
        for k in range(0, len(idx), 64):
            X, _ = SCAPOModel.normalize(data.clouds[idx[k:k + 64]].to(self.device))
            enc = self.model.frame(X)
            Rs.append(enc.R.cpu())
            Ss.append(((X - enc.t[:, None]) @ enc.R).cpu()[:, sel])
        self.model.train()
        branch, flip, info = fit_branch(torch.cat(Rs), torch.cat(Ss), seed=self.preset.seed)
        self.model.branch.copy_(branch.to(self.model.branch))
        self.model.branch_flip.copy_(flip.to(self.model.branch_flip))
        if self.dist.is_main:
            write_json(self.run / "branch.json",
                       {**info, "views": len(idx), "branch": branch.tolist(), "flip": flip.tolist()})

    @torch.no_grad()
    def _init_parts(self, clouds: torch.Tensor, union: torch.Tensor, template: torch.Tensor,
                    labels: tuple | None = None, cloud_labels: torch.Tensor | None = None) -> torch.Tensor:
        """Keypoint and joint heads start from the most rigid split (:mod:`scapo.models.part_init`) of
        the canonical ``clouds (B, n, 3)``, candidates drawn from their ``union (U, 3)``: keypoints at
        the part centroids of ``template (M, 3)`` under that split; each joint's pivot at the boundary
        between its two parts of the template, its axis from the parts' relative motions across the
        clouds (:func:`~scapo.models.part_init.estimate_axes`; the boundary's direction if too few
        pairs move).

        ``labels`` (``TrainConfig.label_init``, segmentation labels allowed): ``(template_labels (M,) or
        None, points (U', 3), point_labels (U',))`` int64, -1 for background. Each part's keypoint is then
        the centroid of its labelled template points (at least 8), else of its labelled points of all the
        canonical clouds, else the unlabeled split's keypoint (a part no cloud shows).

        ``TrainConfig.axis_init`` "turn": each revolute axis is the direction the child's principal axes turn about
        across the clouds (:func:`~scapo.models.part_init.estimate_axes_turn`), the clouds split by nearest keypoint,
        or by ``cloud_labels (B, n)`` int64 when given (``label_init``: the labels' split, a diagnosis).

        ``TrainConfig.split_init`` "fit": the split is :meth:`_fit_split`'s choice, and the pivots and axes are read
        from it. Returns the template's split stage 2 starts from, ``(M,)`` int64 (the fitted one, or the template by
        nearest keypoint)."""
        from scapo.models import part_init

        g = torch.Generator().manual_seed(self.preset.seed)
        pool = union[torch.randperm(len(union), generator=g)[:1024]]
        K, _ = part_init.initial_split(clouds, pool, self.mcfg.num_parts, seed=self.preset.seed)
        K = part_init.part_centroids(template, K)
        tpl_split = fit_split = None
        if self.preset.split_init in ("fit", "fitted") and labels is None:
            tpl_split, fit_split, K = self._fit_split(clouds, template, K)
        if labels is not None:
            K = labelled_centroids(K, template, *labels)
        kb = self.model.keypoints.net[-1].bias.view(self.mcfg.num_parts, -1)
        kb[:, :3] = K.to(kb)
        axes = part_init.estimate_axes(clouds, K, self.mcfg.joint_types, self.mcfg.joint_parts, generator=g,
                                       labels=fit_split)
        if self.preset.axis_init in ("turn", "sweep"):  # "sweep": turn first, the sweep once the target frames exist
            split = cloud_labels if cloud_labels is not None else fit_split if fit_split is not None else \
                part_init.nearest_keypoint(clouds, K.expand(len(clouds), *K.shape))
            axes = part_init.estimate_axes_turn(clouds, split, self.mcfg.joint_types, self.mcfg.joint_parts, axes)
        jb = self.model.joints.joint_bias()
        for j, (parent, child) in enumerate(self.mcfg.joint_parts):
            pivot, axis = part_init.boundary_joint(template, K, parent, child, labels=tpl_split)
            jb[j, :3] = pivot.to(jb)
            jb[j, 3:6] = (axis if axes[j] is None else axes[j]).to(jb)
        return tpl_split if tpl_split is not None else part_init.nearest_keypoint(template, K)

    @torch.no_grad()
    def _fit_split(self, clouds: torch.Tensor, template: torch.Tensor, K: torch.Tensor
                   ) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
        """``TrainConfig.split_init = "fit"``: :func:`~scapo.models.part_init.choose_split` between the keypoint
        split ``K (P, 3)`` of ``template (M, 3)`` and template splits fitted to the canonical ``clouds (B, n, 3)``
        (``"fitted"``: among the fitted splits only). A
        fitted split wins -> (its template labels ``(M,)``, its cloud labels ``(B, n)``, keypoints at its parts'
        template centroids ``(P, 3)``), the base first; the keypoint split wins -> ``(None, None, K)``. What was found
        goes to ``split_init.json`` in the run folder."""
        from scapo.models import part_init

        found = part_init.choose_split(clouds, template, K, seed=self.preset.seed,
                                      keypoint_split=self.preset.split_init != "fitted",
                                      overseg=self.preset.split_overseg)
        out: tuple = (None, None, K)
        if found["source"] == "fit":
            perm, C = part_init.base_first_labels(template, found["template_labels"], self.mcfg.num_parts)
            out = (perm[found["template_labels"]], perm[found["cloud_labels"]], C.to(K))
        if self.dist.is_main:
            write_json(self.run / "split_init.json",
                       {"source": found["source"], "chosen": found["chosen"], "scores": found["scores"],
                        "template_part_points": torch.bincount(found["template_labels"],
                                                               minlength=self.mcfg.num_parts).tolist()})
        return out


def _signed_frames(template: torch.Tensor, template_labels: torch.Tensor, pts: np.ndarray, lab: np.ndarray,
                   min_points: int = 8, axes: str = "pca") -> tuple:
    """The base axes signed by the other parts (:mod:`scapo.ops.signed_axes`, base = slot 0) of the stage-1-frame
    clouds ``pts (B, N, 3)`` float64 under ``lab (B, N)`` and of ``template (M, 3)`` under ``template_labels (M,)``,
    with the two signed ranks chosen over the clouds: ``(pair, E (B, 3, 3), ok (B,) bool, E_Y (3, 3))``; ``pair``
    and ``E_Y`` None (``ok`` all False) when no cloud has enough points of the base and of the other parts, or the
    template's axes are not found (``stage2_frame = "parts"``).
    ``axes``: how the base's directions are found (``TrainConfig.parts_axes``)."""
    from scapo.ops import signed_axes

    none = (None, np.tile(np.eye(3), (len(pts), 1, 1)), np.zeros(len(pts), dtype=bool), None)
    try:
        pair = signed_axes.choose_signed_pair(pts, lab, 0, min_points=min_points, axes=axes)
    except ValueError:
        return none
    E, ok = signed_axes.parts_signed_axes(pts, lab, pair, 0, min_points=min_points, axes=axes)
    tE, tok = signed_axes.parts_signed_axes(template.double().numpy()[None], template_labels.numpy()[None], pair, 0,
                                            min_points, axes)
    return (pair, E, ok, tE[0]) if tok[0] else (pair, E, ok, None)


def _stored_preset(ident: dict) -> TrainConfig | None:
    """The preset a SCAPO run was started with, from its ``run.json`` (None for another method's run)."""
    if ident.get("method", "scapo") != "scapo":
        return None
    try:
        return preset_from_dict(ident["preset"])
    except (ValueError, KeyError, TypeError):
        return None


def _check(preset: TrainConfig, card: dict, clouds: int) -> None:
    """SCAPO's preset against the data, before anything is written: stage 2's template is farthest-point sampled from
    one canonical training cloud (``part_init``) or from the union of up to 64 (:meth:`ScapoJob._init_template`).

    Raises:
        ConfigError: more template points than that cloud or union has; ``split_overseg`` clusters fewer than the
            category's parts."""
    from scapo.errors import ConfigError

    parts = len(card.get("part_names", ()))
    if preset.split_overseg and preset.split_overseg < parts:
        raise ConfigError(f"split_overseg {preset.split_overseg} clusters cannot be grouped into the {parts} parts of "
                          f"{card.get('category', 'this category')}; set split_overseg to at least {parts} (or 0: off)")

    have = preset.train_points * (1 if preset.part_init else min(64, clouds))
    if preset.stage2_epochs > 0 and preset.template_points > have:
        raise ConfigError(f"template_points {preset.template_points} exceeds the {have} points stage 2 samples its "
                          f"template from ({'one' if preset.part_init else min(64, clouds)} training cloud(s) of "
                          f"{preset.train_points} points); lower template_points")


#: SCAPO's description for the engine's run lifecycle (:mod:`scapo.engine.lifecycle`).
SCAPO_RUN = RunSpec(method="scapo", preset=get_preset, stored_preset=_stored_preset, identity=_run_identity,
                    job=lambda pc, data, run, device, ctx: ScapoJob(pc, data, run, device, ctx).job(),
                    compare=_training_identity, check=_check)


class Trainer:
    """SCAPO's training from Python, keeping the network: ``Trainer(data, run, preset).train()`` trains (or resumes)
    through the engine's run lifecycle exactly as :func:`train` does, and afterwards ``.model`` is the trained
    :class:`~scapo.models.scapo_model.SCAPOModel` and ``.job`` its :class:`ScapoJob` (both None when the run
    was already finished: the engine builds nothing for it).

    Args:
        data, run, preset, progress, device: as :func:`train` (``preset`` None: the run's own, else ``cpu``).
    """

    def __init__(self, data: str | Path, run: str | Path, preset: TrainConfig | str | None = None,
                 progress: bool = True, device: str | None = None):
        self.data, self.run, self.preset, self.progress, self.device = Path(data), Path(run), preset, progress, device
        self.job: ScapoJob | None = None

    @property
    def model(self) -> SCAPOModel | None:
        return None if self.job is None else self.job.model

    def _make(self, pc, data, run, device, ctx) -> TrainJob:
        self.job = ScapoJob(pc, data, run, device, ctx)
        return self.job.job()

    def train(self) -> Path:
        """Train or resume; returns the checkpoint path. Raises as :func:`scapo.engine.lifecycle.train`."""
        return lifecycle.train(dataclasses.replace(SCAPO_RUN, job=self._make), self.data, self.run, self.preset,
                               device=self.device, progress=self.progress)


def train(data: str | Path, run: str | Path, preset: str | TrainConfig | None = None, progress: bool = True,
          device: str | None = None, seed: int | None = None, overrides: dict | None = None) -> Path:
    """Train (or resume) SCAPO with the engine's run lifecycle (:func:`scapo.engine.lifecycle.train`, which says how
    ``preset`` (None: the run's own, else ``cpu``), ``overrides`` and ``seed`` are resolved); returns the
    checkpoint path. ``seed`` is part of the run's identity, so each seed needs its own run folder.

    Raises:
        As :func:`scapo.engine.lifecycle.train`.
    """
    return lifecycle.train(SCAPO_RUN, data, run, preset, seed=seed, overrides=overrides, device=device,
                           progress=progress)


__all__ = ["SCAPO_RUN", "ScapoJob", "Trainer", "TrainingClouds", "model_config", "preset_from_dict", "train"]
