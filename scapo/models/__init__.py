"""The SCAPO model (built from :mod:`scapo.nn`): the two-stage network, presets, training and inference.

``scapo.models.load(run_dir).predict(points)`` runs a trained model on ``(B, N, 3)`` float32
camera-frame points (metres) on CPU or CUDA.
"""

from scapo.models.scapo_model import ModelConfig, SCAPOModel

__all__ = ["ModelConfig", "SCAPOModel", "load"]


def load(run, device: str | None = None, refine_steps: int | None = None):
    """Load a trained SCAPO run (folder written by ``scapo train``); returns a :class:`~scapo.models.predict.Predictor`
    (``refine_steps`` overrides the run's test-time refinement, see :mod:`scapo.models.refine`). A run of any method
    loads with :func:`scapo.methods.load`.

    Raises:
        ConfigError: a run of another method (names it and :func:`scapo.methods.load`). Otherwise as
        :meth:`Predictor.load <scapo.models.predict.Predictor.load>`.
    """
    from scapo.engine.runs import read_run_json
    from scapo.errors import ConfigError
    from scapo.models.predict import Predictor

    ident = read_run_json(run) or {}
    if ident.get("method", "scapo") != "scapo":
        raise ConfigError(f"{run} is a run of method {ident['method']!r}, not SCAPO; load it with "
                          f"scapo.methods.load({str(run)!r})")

    return Predictor.load(run, device=device, refine_steps=refine_steps)
