"""The SCAPO model (built from :mod:`scapo.nn`): the two-stage network, presets, training and inference.

``scapo.models.load(run_dir).predict(points)`` runs a trained model on ``(B, N, 3)`` float32
camera-frame points (metres) on CPU or CUDA.
"""

from scapo.models.scapo_model import ModelConfig, SCAPOModel

__all__ = ["ModelConfig", "SCAPOModel", "load"]


def load(run, device: str | None = None, refine_steps: int | None = None):
    """Load a trained run (folder written by ``scapo train``); returns a :class:`~scapo.models.predict.Predictor`
    (``refine_steps`` overrides the run's test-time refinement, see :mod:`scapo.models.refine`)."""
    from scapo.models.predict import Predictor

    return Predictor.load(run, device=device, refine_steps=refine_steps)
