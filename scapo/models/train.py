"""``scapo train``: two-stage self-supervised training of SCAPO on unlabeled clouds, resumable.

Only the ``points`` of the training split are used (no labels, poses or joints), except in the
semi-supervised setting of the paper's Table 2 (``TrainConfig.supervision``, presets ``.../sj``), where
the segmentation and / or joint labels it names are used too (:mod:`scapo.losses.supervised`). A run folder
holds ``run.json`` (preset, dataset, model structure), ``checkpoint.pt`` (written atomically after
every epoch, with optimiser, schedule and RNG state so that a resumed run gives the same result),
``log.csv`` (one row per iteration) and ``losses.png``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from scapo.data.config import dict_diff
from scapo.data.dataset import load
from scapo.errors import ConfigError, DatasetError, TrainingError
from scapo.files import (
    FolderLock,
    atomic_savefig,
    atomic_write_bytes,
    atomic_write_text,
    check_output_dir,
    clean_stale_temps,
    write_json,
)
from scapo.losses import LossConfig, stage1_terms, stage2_terms, weighted_total
from scapo.models.branch import apply_branch
from scapo.models.presets import TrainConfig, get_preset
from scapo.models.refine import RefineConfig
from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.nn.encoder import EncoderConfig
from scapo.nn.engine import dist_context, per_rank_threads, run_settings
from scapo.provenance import usable_cores


def loss_terms(model: SCAPOModel, X: torch.Tensor, stage: int, losses, sup: dict | None = None,
               scale: torch.Tensor | None = None, sup_weight: float = 1.0) -> tuple[dict[str, torch.Tensor],
                                                                                   torch.Tensor]:
    """One forward pass of a training step on normalised clouds ``X (B, N, 3)``: the unweighted loss
    terms of ``stage`` (1: stage-1 terms; 2: stage-1 and stage-2 terms) and their weighted total
    under ``losses`` (a :class:`~scapo.losses.LossConfig`).

    ``sup``: in the semi-supervised setting (:mod:`scapo.losses.supervised`), the batch's labels:
    ``part_label (B, N)`` and / or ``joint_axis``, ``joint_pivot (B, J, 3)`` (camera frame, metres;
    ``scale (B,)`` is the normalisation of ``X``); stage 2 then adds ``sup_seg`` (NLL of the skinning
    weights) and ``sup_joint`` (the camera-frame joints), weighted by ``sup_weight``."""
    out = model(X, stage=stage)
    terms = stage1_terms(model, X, out, losses, align=stage == 1 or losses.align_in_stage2)
    if stage == 2:
        terms.update(stage2_terms(model, X, out, losses))
    total = weighted_total(terms, losses, stage)
    if stage == 2 and sup:
        from scapo.losses.supervised import joint_loss, seg_nll

        extra = {}
        if "part_label" in sup:
            extra["sup_seg"] = seg_nll(out["w"], sup["part_label"])
        if "joint_axis" in sup and model.cfg.joint_types:
            R, t = out["R"], out["enc"].t
            axis = out["axis_x"] @ R.transpose(1, 2)
            pivot = out["pivot_x"] @ R.transpose(1, 2) + t[:, None]
            extra["sup_joint"] = joint_loss(axis, pivot, sup["joint_axis"].to(X), sup["joint_pivot"].to(X)
                                            / scale[:, None, None], model.cfg.joint_types)
        terms.update(extra)
        total = total + sup_weight * sum(extra.values())
    return terms, total


class TrainingClouds(Dataset):
    """The training split's point clouds, each a random subset of ``points`` points; without labels
    (the paper's setting), or, with ``supervision`` (:mod:`scapo.losses.supervised`), as dicts that also
    hold the labels it allows (the subset's ``part_label``, the sample's ``joint_axis`` / ``joint_pivot``)."""

    def __init__(self, data: str | Path, points: int, supervision: str = ""):
        from scapo.losses.supervised import supervised_fields

        ds = load(data, "train")
        if len(ds) == 0:
            raise DatasetError(f"{data}: the training split is empty")
        fields = supervised_fields(supervision)
        arrays = ds.arrays(["points", *fields])
        self.clouds = torch.from_numpy(arrays["points"]).float()
        self.extra = {k: torch.from_numpy(arrays[k]) for k in fields}
        self.points = min(points, self.clouds.shape[1])

    def __len__(self) -> int:
        return len(self.clouds)

    def __getitem__(self, i: int):
        idx = torch.randperm(self.clouds.shape[1])[: self.points]
        if not self.extra:
            return self.clouds[i, idx]
        return {"points": self.clouds[i, idx], **{k: (v[i, idx] if k == "part_label" else v[i].float())
                                                  for k, v in self.extra.items()}}


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
                       template_points=preset.template_points, gamma=preset.gamma, root_motion=preset.root_motion)


def resolve_device(name: str) -> torch.device:
    """``"auto"`` (CUDA when available, else CPU), ``"cpu"``, ``"cuda"`` or ``"cuda:N"`` -> a usable device.

    Raises:
        ConfigError: an unknown device name, or a CUDA device this machine or torch build does not have.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown device {name!r}; use cpu, cuda, cuda:N or auto") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            why = "this torch build has no CUDA" if torch.version.cuda is None else "no CUDA GPU is visible"
            raise ConfigError(f"device {name!r} requested, but {why} (torch {torch.__version__}); use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device {name!r} requested, but only {torch.cuda.device_count()} CUDA device(s) exist")
    elif dev.type != "cpu":
        raise ConfigError(f"device {name!r} is not supported; use cpu, cuda, cuda:N or auto")
    return dev


#: preset fields that only affect inference; a checkpoint is not refused when they differ
INFERENCE_FIELDS = ("refine",)
#: preset fields added after runs were trained, with the value those runs had: at that value a field is
#: left out of the identity, so older runs keep their identity (and their checkpoints stay valid)
ADDED_FIELDS = {"branch_flip": False, "supervision": "", "sup_weight": 1.0, "label_init": False}
#: the same for fields added to the preset's LossConfig
LOSS_ADDED_FIELDS = {"seg_labels": "nearest"}


def _run_identity(preset: TrainConfig, card: dict) -> dict:
    return {"preset": dataclasses.asdict(preset), "dataset_hash": card["dataset_hash"], "category": card["category"],
            "part_names": card["part_names"], "joint_type": card["joint_type"], "joint_parts": card["joint_parts"]}


def _training_identity(identity: dict) -> dict:
    """``identity`` without the preset's inference-only fields (what decides whether a checkpoint fits)."""
    preset = {k: v for k, v in identity.get("preset", {}).items()
              if k not in INFERENCE_FIELDS and not (k in ADDED_FIELDS and v == ADDED_FIELDS[k])}
    if isinstance(preset.get("losses"), dict):
        preset["losses"] = {k: v for k, v in preset["losses"].items()
                            if not (k in LOSS_ADDED_FIELDS and v == LOSS_ADDED_FIELDS[k])}
    return {**identity, "preset": preset}


def _identity_hash(obj: dict) -> str:
    return hashlib.sha256(json.dumps(_training_identity(obj), sort_keys=True, default=str).encode()).hexdigest()


def preset_from_dict(d: dict) -> TrainConfig:
    d = dict(d)
    d["encoder"] = EncoderConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["encoder"].items()})
    loss = dict(d["losses"])
    loss["disabled"] = tuple(loss.get("disabled", ()))
    d["losses"] = LossConfig(**loss)
    d["refine"] = RefineConfig(**d.get("refine", {}))  # runs from before the refinement existed: off
    return TrainConfig(**d)


class Trainer:
    """Trains SCAPO on ``data`` into the run folder ``run`` (resuming from its checkpoint).

    Args:
        data: dataset folder (its training split is used, points only).
        run: run folder. preset: a :class:`TrainConfig` or a preset name.
        progress: show a progress bar. device: overrides the preset's device.

    Raises:
        TrainingError: the run folder holds a checkpoint of another preset or dataset, a loss
            becomes NaN/inf (named), or the checkpoint is unreadable.
        UnknownNameError: unknown preset name.
    """

    def __init__(self, data: str | Path, run: str | Path, preset: TrainConfig | str = "cpu", progress: bool = True,
                 device: str | None = None):
        self.data = Path(data)
        self.run = Path(run)
        self.preset = get_preset(preset) if isinstance(preset, str) else preset
        self.progress = progress
        train = load(self.data, "train")
        self.card = train.card
        self.identity = _run_identity(self.preset, self.card)
        requested = resolve_device(device or self.preset.device)
        self.dist = dist_context(requested.type)  # data-parallel under torchrun (scapo.nn.engine); else world 1
        self.device = self.dist.device(requested)
        self.mcfg = model_config(self.card, self.preset)
        with torch.random.fork_rng(devices=[]):  # the caller's global RNG is left as it was
            torch.manual_seed(self.preset.seed)  # parameter initialisation is part of the run's identity
            self.model = SCAPOModel(self.mcfg).to(self.device)

    # ------------------------------------------------------------------ checkpoints
    def _ckpt_path(self) -> Path:
        return self.run / "checkpoint.pt"

    def _save(self, state: dict) -> None:
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(self._ckpt_path(), buf.getvalue())

    def _load_checkpoint(self) -> dict | None:
        path = self._ckpt_path()
        if not path.is_file():
            return None
        try:
            state = torch.load(path, map_location=self.device, weights_only=False)
        except Exception as e:  # noqa: BLE001 - torch raises many kinds for a broken file
            raise TrainingError(f"checkpoint {path} cannot be read ({e}); delete it to start over") from e
        if state.get("identity_hash") != _identity_hash(self.identity):
            old = state.get("identity", {})
            changed = dict_diff(_training_identity(old)["preset"], _training_identity(self.identity)["preset"])
            what = f" (preset fields that differ: {', '.join(changed)})" if changed else ""
            raise TrainingError(
                f"{path} was trained with preset {old.get('preset', {}).get('name')!r} on the {old.get('category')!r} "
                f"dataset {str(old.get('dataset_hash'))[:12]}..., not with preset {self.preset.name!r} on "
                f"{self.card['category']!r} dataset {self.card['dataset_hash'][:12]}...{what}; "
                "use another --out folder")
        return state

    def _check_run_folder(self) -> None:
        """Refuse a ``run`` that is a file, or a non-empty folder that holds no scapo run."""
        if self.run.exists() and not self.run.is_dir():
            raise ConfigError(f"--out {self.run} is an existing file; give a folder for the run")
        if self.run.is_dir() and not ((self.run / "checkpoint.pt").exists() or (self.run / "run.json").exists()):
            foreign = sorted(p.name for p in self.run.iterdir() if p.name != FolderLock.NAME)
            if foreign:
                raise ConfigError(f"--out {self.run} is a non-empty folder without a scapo run (holds "
                                  f"{', '.join(foreign[:4])}{', ...' if len(foreign) > 4 else ''}); give a new or "
                                  "empty folder")

    def _check_unstarted_run(self) -> None:
        """A run folder without a checkpoint but with ``run.json`` must be this run (refuse before writing)."""
        try:
            old = json.loads((self.run / "run.json").read_text())
        except (OSError, ValueError):
            return  # no run.json, or one truncated before any epoch finished: nothing to protect
        if isinstance(old, dict) and _identity_hash(old) != _identity_hash(json.loads(json.dumps(
                self.identity, default=str))):
            old_preset = old.get("preset", {}).get("name") if isinstance(old.get("preset"), dict) else None
            raise TrainingError(f"{self.run} holds a run started with preset {old_preset!r} on the "
                                f"{old.get('category')!r} dataset {str(old.get('dataset_hash'))[:12]}..., not with "
                                f"preset {self.preset.name!r} on {self.card['category']!r} dataset "
                                f"{self.card['dataset_hash'][:12]}...; use another --out folder")

    # ------------------------------------------------------------------ training
    def train(self) -> Path:
        """Run (or resume) both stages; returns the checkpoint path.

        Everything is checked before anything is written: the run folder (a file, a foreign non-empty
        folder, or not writable), another process training into it, and a checkpoint or ``run.json`` of
        another preset or dataset.

        Raises:
            ConfigError, OutputError: unusable run folder. TrainingError: see the class docstring.
        """
        self._check_run_folder()
        main = self.dist.is_main
        if main:
            check_output_dir(self.run, "run folder")
        try:
            with FolderLock(self.run, "train") if main else contextlib.nullcontext():
                if main:
                    clean_stale_temps(self.run, any_pid=True)
                self.dist.barrier()  # the other ranks start once rank 0 holds the folder
                with run_settings(per_rank_threads(usable_cores(), self.dist)):
                    return self._train_locked()
        finally:
            self.dist.close()

    def _train_locked(self) -> Path:
        pc = self.preset
        state = self._load_checkpoint()
        if state is None:
            self._check_unstarted_run()
        elif state.get("done"):
            return self._ckpt_path()
        if self.dist.is_main:
            write_json(self.run / "run.json", json.loads(json.dumps(self.identity, default=str)))
        data = TrainingClouds(self.data, pc.train_points, pc.supervision)
        share = len(data) // self.dist.world  # the clouds each rank sees per epoch
        steps_per_epoch = share // pc.batch_size if share >= pc.batch_size else 1
        if pc.max_steps_per_epoch:
            steps_per_epoch = min(steps_per_epoch, pc.max_steps_per_epoch)
        start_stage, start_epoch = 1, 0
        if state is not None:
            self.model.load_checkpoint_state(state["model"])
            start_stage, start_epoch = state["stage"], state["epoch"]
        if self.dist.is_main:  # only rank 0 touches the log
            truncate_log(self.run / "log.csv", start_stage, start_epoch)
        total = steps_per_epoch * (pc.stage1_epochs + pc.stage2_epochs)
        done_steps = steps_per_epoch * (start_epoch if start_stage == 1 else pc.stage1_epochs + start_epoch)
        bar = None
        if self.progress and self.dist.is_main:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=done_steps, desc=f"train {self.card['category']} ({pc.name})", unit="it",
                       dynamic_ncols=True)
        log_path = self.run / "log.csv"
        t0 = time.perf_counter()
        before = float(state.get("seconds", 0.0)) if state is not None else 0.0  # training time of earlier sessions
        try:
            for stage in (1, 2):
                if stage < start_stage:
                    continue
                epochs = pc.stage1_epochs if stage == 1 else pc.stage2_epochs
                if epochs == 0:
                    continue
                opt = torch.optim.Adam(self._params(stage), lr=pc.lr_stage1 if stage == 1 else pc.lr_stage2,
                                       weight_decay=pc.weight_decay)
                sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, epochs * steps_per_epoch),
                                                                   eta_min=pc.min_lr)
                first = start_epoch if stage == start_stage else 0
                if state is not None and stage == start_stage and "optimizer" in state and first > 0:
                    opt.load_state_dict(state["optimizer"])
                    sched.load_state_dict(state["scheduler"])
                if stage == 2 and first == 0:
                    self._init_template(data)
                for epoch in range(first, epochs):
                    self._epoch(stage, epoch, data, opt, sched, steps_per_epoch, log_path, bar)
                    done = stage == 2 and epoch == epochs - 1 or (stage == 1 and pc.stage2_epochs == 0
                                                                 and epoch == epochs - 1)
                    nxt = (stage, epoch + 1) if epoch + 1 < epochs else (stage + 1, 0)
                    if self.dist.is_main:  # every rank holds the same model, optimiser and schedule
                        self._save({"model": self.model.state_dict(), "optimizer": opt.state_dict(),
                                    "scheduler": sched.state_dict(), "stage": nxt[0], "epoch": nxt[1], "done": done,
                                    "identity": self.identity, "identity_hash": _identity_hash(self.identity),
                                    "model_config": dataclasses.asdict(self.mcfg), "world_size": self.dist.world,
                                    "seconds": before + time.perf_counter() - t0})
                        plot_losses(log_path, self.run / "losses.png")
                    self.dist.barrier()
        finally:
            if bar is not None:
                bar.close()
        # the training time over every session that trained this run (resumes included)
        if self.dist.is_main:
            atomic_write_text(self.run / "timing.json",
                              json.dumps({"seconds": round(before + time.perf_counter() - t0, 1),
                                          "device": str(self.device), "world_size": self.dist.world}) + "\n")
        return self._ckpt_path()

    def _params(self, stage: int):
        if stage == 1:
            return [*self.model.encoder.parameters(), *self.model.decoder.parameters()]
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
        enc = self.model.encoder(X)
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
        labels = None
        if self.preset.label_init and "part_label" in data.extra:  # the template's points keep their labels
            lab = data.extra["part_label"][idx].long()
            labels = (lab[medoid][torch.from_numpy(np.asarray(fps))] if medoid is not None else None,
                      clouds.reshape(-1, 3), lab.reshape(-1))
        if self.preset.part_init and len(clouds) >= 2:
            self._init_parts(sub, clouds.reshape(-1, 3), self.model.y_base.detach().cpu(), labels)
        return labels[0] if labels is not None else None

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
            enc = self.model.encoder(X)
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
                    labels: tuple | None = None) -> None:
        """Keypoint and joint heads start from the most rigid split (:mod:`scapo.models.part_init`) of
        the canonical ``clouds (B, n, 3)``, candidates drawn from their ``union (U, 3)``: keypoints at
        the part centroids of ``template (M, 3)`` under that split; each joint's pivot at the boundary
        between its two parts of the template, its axis from the parts' relative motions across the
        clouds (:func:`~scapo.models.part_init.estimate_axes`; the boundary's direction if too few
        pairs move).

        ``labels`` (``TrainConfig.label_init``, segmentation labels allowed): ``(template_labels (M,) or
        None, points (U', 3), point_labels (U',))`` int64, -1 for background. Each part's keypoint is then
        the centroid of its labelled template points (at least 8), else of its labelled points of all the
        canonical clouds, else the unlabeled split's keypoint (a part no cloud shows)."""
        from scapo.models import part_init

        g = torch.Generator().manual_seed(self.preset.seed)
        pool = union[torch.randperm(len(union), generator=g)[:1024]]
        K, _ = part_init.initial_split(clouds, pool, self.mcfg.num_parts, seed=self.preset.seed)
        K = part_init.part_centroids(template, K)
        if labels is not None:
            K = labelled_centroids(K, template, *labels)
        kb = self.model.keypoints.net[-1].bias.view(self.mcfg.num_parts, -1)
        kb[:, :3] = K.to(kb)
        axes = part_init.estimate_axes(clouds, K, self.mcfg.joint_types, self.mcfg.joint_parts, generator=g)
        jb = self.model.joints.joint_bias()
        for j, (parent, child) in enumerate(self.mcfg.joint_parts):
            pivot, axis = part_init.boundary_joint(template, K, parent, child)
            jb[j, :3] = pivot.to(jb)
            jb[j, 3:6] = (axis if axes[j] is None else axes[j]).to(jb)

    def _epoch(self, stage, epoch, data, opt, sched, steps, log_path, bar) -> None:
        pc = self.preset
        seed = pc.seed * 1_000_003 + stage * 10_007 + epoch
        rank_seed = seed + 7_919 * self.dist.rank  # augmentations and point subsets differ between ranks
        torch.manual_seed(rank_seed)
        np.random.seed(rank_seed % (2 ** 32))  # noqa: NPY002 - any legacy-numpy randomness in a run is seeded too
        if self.dist.active:  # each rank its share of the clouds, in an order fixed by (seed, epoch, world size)
            from torch.utils.data.distributed import DistributedSampler

            sampler = DistributedSampler(data, num_replicas=self.dist.world, rank=self.dist.rank, shuffle=True,
                                         seed=seed, drop_last=True)
            loader = DataLoader(data, batch_size=pc.batch_size, sampler=sampler,
                                drop_last=len(data) // self.dist.world >= pc.batch_size)
        else:
            loader = DataLoader(data, batch_size=pc.batch_size, shuffle=True, drop_last=len(data) >= pc.batch_size,
                                generator=torch.Generator().manual_seed(seed))
        self.model.train()
        new_file = not log_path.is_file()
        with open(log_path, "a", newline="") if self.dist.is_main else contextlib.nullcontext() as f:
            writer = None
            for step, batch in enumerate(loader):
                if step >= steps:
                    break
                sup = None
                if isinstance(batch, dict):  # semi-supervised: the labels come along
                    sup = {k: v.to(self.device) for k, v in batch.items() if k != "points"}
                    batch = batch["points"]
                X, scale = SCAPOModel.normalize(batch.to(self.device))
                terms, total = loss_terms(self.model, X, stage, pc.losses, sup, scale, pc.sup_weight)
                for name, value in terms.items():
                    if not torch.isfinite(value):
                        raise TrainingError(f"loss {name!r} became {float(value.detach())} at stage {stage}, "
                                            f"epoch {epoch}, step {step}; training stopped (last good checkpoint kept)")
                opt.zero_grad(set_to_none=True)
                total.backward()
                self.dist.average_gradients(self.model.parameters())
                if pc.grad_clip:
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), pc.grad_clip)
                opt.step()
                sched.step()
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(stage=stage, loss=f"{float(total.detach()):.4f}")
                if f is None:  # ranks other than 0 write nothing; the log holds rank 0's losses
                    continue
                row = {"stage": stage, "epoch": epoch, "step": step, "lr": sched.get_last_lr()[0],
                       "total": float(total.detach()), **{k: float(v.detach()) for k, v in terms.items()}}
                if writer is None:
                    fields = ["stage", "epoch", "step", "lr", "total", "rec", "ortho", "aug_consist", "can_consist",
                              "align", "consensus", "cycle", "recon", "kp_seg", "seg", "shape_var", "dir_align",
                              "joint_prox", "joint_boundary", "sup_seg", "sup_joint"]
                    if not new_file:  # a resumed run keeps its log's columns (written by the scapo it started with)
                        with open(log_path, newline="") as g:
                            fields = next(csv.reader(g), None) or fields
                    writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
                    if new_file:
                        writer.writeheader()
                writer.writerow(row)


def truncate_log(log_csv: Path, stage: int, epoch: int) -> None:
    """Keep only the rows of ``log.csv`` from before ``(stage, epoch)``, where a resumed run restarts
    (an interrupted epoch's rows are written again); a torn last line is dropped."""
    if not log_csv.is_file():
        return
    with open(log_csv, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        log_csv.unlink()
        return
    header, kept = rows[0], []
    try:
        si, ei = header.index("stage"), header.index("epoch")
    except ValueError:
        log_csv.unlink()
        return
    for r in rows[1:]:
        try:
            if len(r) == len(header) and (int(r[si]), int(r[ei])) < (stage, epoch):
                kept.append(r)
        except ValueError:
            continue
    if not kept:
        log_csv.unlink()
        return
    buf = io.StringIO()
    csv.writer(buf).writerows([header, *kept])
    atomic_write_text(log_csv, buf.getvalue())


def plot_losses(log_csv: Path, png: Path) -> None:
    """Loss curves (log scale, one panel per stage) from ``log.csv``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    df = pd.read_csv(log_csv)
    if df.empty:
        return
    stages = sorted(df["stage"].unique())
    fig, axes = plt.subplots(1, len(stages), figsize=(6 * len(stages), 4), squeeze=False)
    for ax, st in zip(axes[0], stages):
        d = df[df["stage"] == st].reset_index(drop=True)
        for col in d.columns[4:]:
            v = d[col]
            if v.notna().any() and (v.abs() > 0).any():
                ax.plot(v.abs().rolling(5, min_periods=1).mean(), label=col, lw=1)
        ax.set_yscale("log")
        ax.set_title(f"stage {st}")
        ax.set_xlabel("iteration")
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    atomic_savefig(fig, png, dpi=90)
    plt.close(fig)


def run_preset(run: str | Path) -> TrainConfig | None:
    """The preset a run folder was started with (from its ``run.json``), or None when there is none."""
    try:
        ident = json.loads((Path(run) / "run.json").read_text())
        return preset_from_dict(ident["preset"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def train(data: str | Path, run: str | Path, preset: str | TrainConfig | None = None, progress: bool = True,
          device: str | None = None, seed: int | None = None) -> Path:
    """Train (or resume) SCAPO; see :class:`Trainer`.

    ``preset=None`` resumes an existing run with its own preset (from ``run.json``) and starts a new
    run with the ``cpu`` preset. ``seed`` replaces the preset's training seed (parameter
    initialisation, batches, augmentations); it is part of the run's identity, so each seed needs its
    own run folder.

    Raises:
        ConfigError: a negative seed. Otherwise as :class:`Trainer`.
    """
    if preset is None:
        preset = run_preset(run) or "cpu"
    if seed is not None:
        if int(seed) < 0:
            raise ConfigError(f"seed must be >= 0, got {seed}")
        preset = dataclasses.replace(get_preset(preset) if isinstance(preset, str) else preset, seed=int(seed))
    return Trainer(data, run, preset, progress, device).train()


def run_is_current(run: str | Path, data: str | Path, preset: str, seed: int | None = None) -> bool:
    """Whether the run folder ``run`` was started as ``train(data, run, preset, seed=seed)`` would start
    it now: its ``run.json`` has the training identity (preset fields other than the inference-only
    ones, dataset, category structure) of the registered ``preset`` today. False for a folder without
    a readable ``run.json`` and for a run of a preset whose training fields have changed since (its
    results are stale). Raises UnknownNameError for an unknown preset."""
    try:
        old = json.loads((Path(run) / "run.json").read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(old, dict):
        return False
    cfg = get_preset(preset)
    if seed is not None:
        cfg = dataclasses.replace(cfg, seed=int(seed))
    card = load(data, "train").card
    return _identity_hash(old) == _identity_hash(json.loads(json.dumps(_run_identity(cfg, card), default=str)))


__all__ = ["Trainer", "TrainingClouds", "model_config", "plot_losses", "preset_from_dict", "run_is_current",
           "run_preset", "train"]
