"""Inference with a trained SCAPO run (the Python API; :mod:`scapo.methods.scapo` puts it in the registry)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import torch

from scapo.engine.runs import load_error_text, resolve_device
from scapo.errors import ConfigError, InputError, TrainingError
from scapo.models.refine import RefineConfig, refine_from_dict
from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.nn.encoder import EncoderConfig


def _model_config(d: dict) -> ModelConfig:
    enc = EncoderConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d["encoder"].items()})
    return ModelConfig(num_parts=d["num_parts"], joint_types=tuple(d["joint_types"]),
                       joint_parts=tuple(tuple(p) for p in d["joint_parts"]), encoder=enc,
                       template_points=d["template_points"], gamma=d["gamma"], joint_widths=tuple(d["joint_widths"]),
                       head_width=d["head_width"], root_motion=d.get("root_motion", False),
                       anchors=d.get("anchors", ""), stage1_template=d.get("stage1_template", False))


#: Points per cloud that :meth:`Predictor.predict` accepts: below ``MIN_POINTS`` the encoder's k-nearest-
#: neighbour features (k up to 16) span a large part of the cloud and a part segmentation means little.
MIN_POINTS = 64
#: Larger clouds are farthest-point subsampled to this many points (with a warning): the encoder's
#: pairwise distances grow as N^2 per cloud (1e5 points would need 40 GB).
MAX_POINTS = 4096
#: Bytes of pairwise-distance matrices (B x N x N float32) one inference batch may allocate.
_BATCH_BYTES = 1 << 29


#: the farthest coordinate (metres) a cloud may have: beyond it the units are wrong, and float32 poses break down
MAX_RANGE_M = 1000.0


def check_points(points) -> torch.Tensor:
    """Validate clouds for :meth:`Predictor.predict`; returns them as a float32 CPU tensor ``(B, N, 3)``.

    Args:
        points: ``(B, N, 3)`` camera-frame metres, numpy or torch, any real dtype.

    Raises:
        InputError: not a real-valued (B, N, 3) array (a single (N, 3) cloud is named as such; complex values
            refused), coordinates beyond :data:`MAX_RANGE_M` (a unit error), an empty batch, fewer than
            :data:`MIN_POINTS` points per cloud, NaN/inf coordinates, or a degenerate cloud (all points within
            0.1 mm of their centroid, or on one line); the message names the cloud index.
    """
    kind = (torch.empty(0, dtype=points.dtype).numpy().dtype.kind if torch.is_tensor(points)
            and not points.dtype.is_complex else ("c" if torch.is_tensor(points) else np.asarray(points).dtype.kind))
    if kind not in "fiub":
        raise InputError(f"points must be a real numeric array of shape (B, N, 3) in metres, got "
                         f"{'complex' if kind == 'c' else 'non-numeric'} values")
    try:
        pts = points.detach().to("cpu", torch.float32) if torch.is_tensor(points) else \
            torch.from_numpy(np.asarray(points, dtype=np.float32))
    except (TypeError, ValueError) as e:
        raise InputError(f"points must be a numeric array of shape (B, N, 3) in metres ({e})") from None
    if pts.dim() == 2 and pts.shape[-1] == 3:
        raise InputError(f"points has shape {tuple(pts.shape)}, one cloud; pass a batch of shape (B, N, 3), "
                         "e.g. points[None]")
    if pts.dim() != 3 or pts.shape[-1] != 3:
        raise InputError(f"points must have shape (B, N, 3), got {tuple(pts.shape)}")
    B, N = pts.shape[:2]
    if B == 0:
        raise InputError("points is an empty batch (B = 0); pass at least one cloud")
    if N < MIN_POINTS:
        raise InputError(f"clouds of {N} points are too small: SCAPO needs at least {MIN_POINTS} points per cloud")
    finite = torch.isfinite(pts).all(dim=2)
    if not finite.all():
        bad = torch.nonzero(~finite.all(dim=1)).flatten().tolist()
        raise InputError(f"cloud(s) {bad[:8]}{' ...' if len(bad) > 8 else ''} contain NaN or inf coordinates "
                         f"({int((~finite).sum())} points); remove those points first")
    far = float(pts.abs().max())
    if far > MAX_RANGE_M:
        raise InputError(f"points reach {far:.3g} m from the camera; scapo works in metres and a depth camera sees a "
                         f"few metres (at most {MAX_RANGE_M:g} m here): convert the units")
    c = pts.double() - pts.double().mean(dim=1, keepdim=True)
    ev = torch.linalg.eigvalsh(c.transpose(1, 2) @ c / N).clamp_min(0.0).sqrt()  # (B, 3) ascending, metres
    tiny = torch.nonzero(ev.norm(dim=1) < 1e-4).flatten().tolist()
    if tiny:
        raise InputError(f"cloud(s) {tiny[:8]} are degenerate: all points lie within 0.1 mm of their centroid "
                         "(identical points?)")
    line = torch.nonzero(ev[:, 1] < 1e-3 * ev[:, 2]).flatten().tolist()
    if line:
        raise InputError(f"cloud(s) {line[:8]} are degenerate: all points lie on one line")
    return pts


def stored_refine(stored: dict) -> RefineConfig:
    """The inference settings a run was trained with (``run.json``'s ``preset``, ``stored``: its ``refine``, stored
    at training time; :func:`scapo.models.refine.refine_from_dict` reads old spellings): read back from the run,
    never from the preset's current definition, so that a run predicts as it did when it was made (a prediction
    option, e.g. ``--option stage2_starts=off``, changes it for one prediction).

    Raises:
        ValueError, TypeError: a stored value the settings refuse."""
    return refine_from_dict(stored.get("refine"))


class Predictor:
    """A trained SCAPO model ready for inference (``scapo.models.load(run)``)."""

    def __init__(self, model: SCAPOModel, identity: dict, device: torch.device, refine: RefineConfig | None = None,
                 max_points: int = MAX_POINTS):
        self.model = model.to(device).eval()
        self.identity = identity
        self.device = device
        self.refine = refine if refine is not None else RefineConfig()
        self.max_points = int(max_points)
        self.upright: torch.Tensor | None = None
        """``(2, 3)`` the run's upright prior (:meth:`fit_upright`); None: the upright prior is off."""
        self.upright_support = float("nan")

    def fit_upright(self, points, max_views: int = 512, batch_size: int = 64) -> tuple[np.ndarray, float]:
        """Set the refinement's upright prior (``RefineConfig.upright_deg``) from training clouds
        ``(M, N, 3)`` (camera frame, metres; no labels): :func:`scapo.models.refine.upright_direction`
        of the network's canonical frames of up to ``max_views`` evenly spaced clouds. Returns
        (``(2, 3)`` canonical direction and camera direction, fraction of views near it).

        Raises:
            InputError: see :func:`check_points`.
        """
        from scapo.models.refine import upright_direction

        pts = check_points(points)
        idx = np.linspace(0, len(pts) - 1, min(len(pts), int(max_views))).round().astype(int)
        pts = pts[idx]
        frames = torch.cat([self.model.frames(pts[k:k + batch_size].to(self.device))
                            for k in range(0, len(pts), batch_size)])
        d, support = upright_direction(frames)
        self.upright, self.upright_support = d, support
        return d.cpu().numpy(), support

    @classmethod
    def load(cls, run: str | Path, device: str | None = None, refine_steps: int | None = None,
             refine_margin: float | None = None) -> Predictor:
        """Load ``run/checkpoint.pt``.

        The test-time refinement (:mod:`scapo.models.refine`) follows the settings stored with the run at
        training time (:func:`stored_refine`: the checkpoint's preset, never the preset's current definition);
        ``refine_steps`` overrides its number of steps (0 turns it off), ``refine_margin`` the residual margin of
        its multi-start (:class:`~scapo.models.refine.RefineConfig`; choose it on the val split).

        Raises:
            TrainingError: the run folder does not exist, has no checkpoint, or its checkpoint is
                unreadable (truncated, not a checkpoint) or from an unfinished run.
            ConfigError: negative ``refine_steps``; an unknown or unavailable ``device``.
        """
        run = Path(run)
        path = run / "checkpoint.pt"
        if not run.is_dir():
            what = "it is a file, not a run folder" if run.exists() else "the folder does not exist"
            raise TrainingError(f"{run} holds no checkpoint: {what}; train a run first with 'scapo train --data DATA "
                                f"--out {run}'")
        if not path.is_file():
            raise TrainingError(f"{run} holds no checkpoint.pt (not a trained run); train first with "
                                f"'scapo train --data DATA --out {run}'")
        if refine_steps is not None and int(refine_steps) < 0:
            raise ConfigError(f"refine_steps must be >= 0, got {refine_steps}")
        dev = resolve_device(device or "auto")
        try:
            state = torch.load(path, map_location=dev, weights_only=True)  # tensors and plain data: no code runs
            model = SCAPOModel(_model_config(state["model_config"]))
            model.load_checkpoint_state(state["model"])
            identity, done = state["identity"], state.get("done")
            stored = identity["preset"]
        except Exception as e:  # noqa: BLE001 - torch.load raises many kinds for a damaged file
            raise TrainingError(f"checkpoint {path} cannot be loaded ({load_error_text(e)}); it is damaged or not "
                                f"a scapo checkpoint: retrain with 'scapo train --out {run}' (delete the damaged "
                                "file first)") from None
        if not done:
            raise TrainingError(f"{path} is from an unfinished run (stage {state.get('stage')}, epoch "
                                f"{state.get('epoch')}); resume it with 'scapo train --out {run}' first")
        refine = stored_refine(stored)
        try:
            if refine_steps is not None:
                refine = dataclasses.replace(refine, steps=int(refine_steps))
            if refine_margin is not None:
                refine = dataclasses.replace(refine, margin=float(refine_margin))
        except ValueError as e:
            raise ConfigError(str(e)) from None
        return cls(model, identity, dev, refine)

    def predict(self, points, batch_size: int = 32, progress: bool = False) -> dict[str, np.ndarray]:
        """Predict for ``points (B, N, 3)`` float32 camera-frame metres (numpy or torch).

        Clouds must have at least :data:`MIN_POINTS` points (see :func:`check_points`). Clouds of more
        than ``self.max_points`` points are farthest-point subsampled to that many (a warning says so);
        the per-point outputs (``part_label``, ``weights``, ``canonical_shape``) are then those of each
        input point's nearest subsampled point, so they keep the input's N.

        With refinement on (``self.refine.steps > 0``) each batch is also fitted to its points
        (:mod:`scapo.models.refine`); a view's result does not depend on the other views of its batch.

        Returns numpy arrays (float32 / int64): ``T_cam_obj (B,4,4)``, ``part_label (B,N)``,
        ``weights (B,N,P)``, ``part_pose (B,P,4,4)``, ``joint_axis (B,J,3)``, ``joint_pivot (B,J,3)``,
        ``joint_state (B,J)``, ``canonical_shape (B,N,3)``, ``template (B,M,3)``, ``template_rest (B,M,3)``,
        ``template_label (B,M)`` (:meth:`SCAPOModel.predict <scapo.models.scapo_model.SCAPOModel.predict>`).

        Raises:
            InputError: see :func:`check_points` (also a ``ValueError``).
        """
        pts = check_points(points)
        B, N = pts.shape[:2]
        nearest = None
        if N > self.max_points:
            warnings.warn(f"clouds of {N} points were farthest-point subsampled to {self.max_points} for SCAPO; "
                          "per-point outputs come from each point's nearest subsampled point", stacklevel=2)
            from scipy.spatial import cKDTree

            from scapo.ops.sampling import farthest_point_indices

            rng = np.random.default_rng(0)
            full = pts.numpy()
            idx = np.stack([farthest_point_indices(c, self.max_points, rng) for c in full])
            nearest = np.stack([cKDTree(c[i]).query(c)[1] for c, i in zip(full, idx)])
            pts = torch.from_numpy(np.take_along_axis(full, idx[..., None], axis=1))
        n = pts.shape[1]
        step = max(1, min(int(batch_size), _BATCH_BYTES // (4 * n * n)))
        starts = range(0, B, step)
        if progress:
            from scapo.report import progress_bar

            starts = progress_bar(starts, desc="scapo predict", unit="batch")
        outs = []
        for k in starts:
            o = self.model.predict(pts[k:k + step].to(self.device), self.refine, self.upright)
            outs.append({name: v.cpu().numpy() for name, v in o.items()})
        res = {name: np.concatenate([o[name] for o in outs]) for name in outs[0]}
        if nearest is not None:
            for name in ("part_label", "weights", "canonical_shape"):
                res[name] = np.take_along_axis(res[name], nearest.reshape(B, N, *[1] * (res[name].ndim - 2)), axis=1)
        return res
