"""Inference with a trained SCAPO run: the Python API and the ``scapo`` method of the registry."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from scapo.baselines.base import METHODS
from scapo.data.dataset import ArticulationDataset
from scapo.errors import TrainingError
from scapo.eval.predictions import Predictions
from scapo.models.encoder import EncoderConfig
from scapo.models.presets import PRESETS
from scapo.models.refine import RefineConfig
from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.models.train import preset_from_dict, resolve_device


def _model_config(d: dict) -> ModelConfig:
    enc = EncoderConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["encoder"].items()})
    return ModelConfig(num_parts=d["num_parts"], joint_types=tuple(d["joint_types"]),
                       joint_parts=tuple(tuple(p) for p in d["joint_parts"]), encoder=enc,
                       template_points=d["template_points"], gamma=d["gamma"], joint_widths=tuple(d["joint_widths"]),
                       head_width=d["head_width"], root_motion=d.get("root_motion", False))


class Predictor:
    """A trained SCAPO model ready for inference (``scapo.models.load(run)``)."""

    def __init__(self, model: SCAPOModel, identity: dict, device: torch.device, refine: RefineConfig | None = None):
        self.model = model.to(device).eval()
        self.identity = identity
        self.device = device
        self.refine = refine if refine is not None else RefineConfig()

    @classmethod
    def load(cls, run: str | Path, device: str | None = None, refine_steps: int | None = None) -> Predictor:
        """Load ``run/checkpoint.pt``.

        The test-time refinement (:mod:`scapo.models.refine`) follows the current definition of the
        run's preset (``TrainConfig.refine``; it is an inference setting, not part of the run), or the
        settings stored with the run when its preset is not a registered one; ``refine_steps``
        overrides its number of steps (0 turns it off).

        Raises:
            TrainingError: missing, unreadable or unfinished checkpoint.
            ValueError: negative ``refine_steps``.
        """
        path = Path(run) / "checkpoint.pt"
        if not path.is_file():
            raise TrainingError(f"{run} holds no checkpoint.pt; train first with 'scapo train --out {run}'")
        dev = resolve_device(device or "auto")
        try:
            state = torch.load(path, map_location=dev, weights_only=False)
            model = SCAPOModel(_model_config(state["model_config"]))
            model.load_state_dict(state["model"])
        except (KeyError, RuntimeError, OSError, EOFError) as e:
            raise TrainingError(f"checkpoint {path} cannot be loaded ({type(e).__name__}: {e})") from e
        if not state.get("done"):
            raise TrainingError(f"{path} is from an unfinished run (stage {state.get('stage')}, epoch "
                                f"{state.get('epoch')}); resume it with 'scapo train' first")
        stored = state["identity"]["preset"]
        # an inference setting follows the preset's current definition when the preset is registered
        registered = stored.get("name") in PRESETS.names()
        refine = (PRESETS.get(stored["name"]) if registered else preset_from_dict(stored)).refine
        if refine_steps is not None:
            refine = dataclasses.replace(refine, steps=int(refine_steps))
        return cls(model, state["identity"], dev, refine)

    def predict(self, points, batch_size: int = 32) -> dict[str, np.ndarray]:
        """Predict for ``points (B, N, 3)`` float32 camera-frame metres (numpy or torch).

        With refinement on (``self.refine.steps > 0``) each batch is also fitted to its points
        (:mod:`scapo.models.refine`); a view's result does not depend on the other views of its batch.

        Returns numpy arrays (float32 / int64): ``T_cam_obj (B,4,4)``, ``part_label (B,N)``,
        ``weights (B,N,P)``, ``part_pose (B,P,4,4)``, ``joint_axis (B,J,3)``, ``joint_pivot (B,J,3)``,
        ``joint_state (B,J)``, ``canonical_shape (B,N,3)``, ``template (B,M,3)``.

        Raises:
            ValueError: points not of shape (B, N, 3) or not finite.
        """
        pts = torch.as_tensor(np.asarray(points) if not torch.is_tensor(points) else points).float()
        if pts.dim() != 3 or pts.shape[-1] != 3:
            raise ValueError(f"points must have shape (B, N, 3), got {tuple(pts.shape)}")
        if not torch.isfinite(pts).all():
            raise ValueError("points contain NaN or inf")
        outs = []
        for k in range(0, len(pts), batch_size):
            o = self.model.predict(pts[k:k + batch_size].to(self.device), self.refine)
            outs.append({n: v.cpu().numpy() for n, v in o.items()})
        return {n: np.concatenate([o[n] for o in outs]) for n in outs[0]}


class SCAPOMethod:
    """SCAPO in the method registry: trains into ``run`` with ``preset`` if that run is not finished."""

    name = "scapo"
    needs_alignment = True
    supervision = {"pose": False, "segmentation": False, "joint": False}

    def __init__(self, run: str | Path | None = None, preset: str = "cpu", device: str | None = None,
                 progress: bool = False, batch_size: int = 32, refine_steps: int | None = None,
                 label: str = "scapo"):
        if run is None:
            raise TrainingError("the scapo method needs a run folder (option run=...)")
        self.run, self.preset, self.device, self.progress, self.batch_size = Path(run), preset, device, progress, \
            batch_size
        self.refine_steps = refine_steps
        self.label = str(label)
        self.predictor: Predictor | None = None

    def fit(self, train: ArticulationDataset) -> None:
        """Finish (or start) training into ``run``; an unfinished run resumes with its own preset."""
        from scapo.models.train import Trainer

        ck = self.run / "checkpoint.pt"
        state = torch.load(ck, map_location="cpu", weights_only=False) if ck.is_file() else None
        if state is None or not state.get("done"):
            preset = self.preset
            if state is not None and "identity" in state:
                preset = preset_from_dict(state["identity"]["preset"])
            Trainer(train.root, self.run, preset, self.progress, self.device).train()
        self.predictor = Predictor.load(self.run, self.device, self.refine_steps)
        if self.predictor.identity["dataset_hash"] != train.dataset_hash:
            # a model trained on another dataset of the same category is allowed; note it
            self.trained_on = self.predictor.identity["dataset_hash"]

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        a = dataset.arrays(["points"])
        t0 = time.perf_counter()
        o = self.predictor.predict(a["points"], self.batch_size)
        seconds = time.perf_counter() - t0
        M = len(a["points"])
        mc = self.predictor.model.cfg
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
                  "refine_steps": self.predictor.refine.steps,
                  "predict_ms_per_cloud": round(1000 * seconds / max(M, 1), 2)},
        )


@METHODS.register("scapo")
def make_scapo(**options) -> SCAPOMethod:
    """SCAPO (ours); options: run (folder), preset, device, progress, batch_size, refine_steps (test-time
    refinement steps; default: the run's preset), label (the method name written into the predictions,
    e.g. ``scapo-no-refine`` for a second row of the same run)."""
    return SCAPOMethod(**options)


