"""Evaluation: metrics (:mod:`scapo.eval.metrics`), predictions format, alignment, evaluator, tables."""

from scapo.eval.evaluator import EvalResult, evaluate
from scapo.eval.predictions import Predictions

__all__ = ["EvalResult", "Predictions", "evaluate"]
