"""Method interface and registry shared by baselines and the SCAPO model.

A method is built from a name and options (``METHODS.get(name)(**options)``), fitted on the
training split of a dataset, and asked for :class:`~scapo.eval.predictions.Predictions` on any
split. :func:`run_method` does the whole round trip and writes the predictions file.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from scapo.data.dataset import ArticulationDataset, load
from scapo.eval.predictions import Predictions
from scapo.registry import Registry


class Method(Protocol):
    """What the evaluator needs from a method."""

    name: str
    needs_alignment: bool
    supervision: dict

    def fit(self, train: ArticulationDataset) -> None:
        """Learn from the training split (labels may be used only as ``supervision`` declares)."""

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        """Predictions for every sample of ``dataset`` (rows carry ``dataset.split``)."""


#: name -> factory(**options) -> Method
METHODS: Registry[Callable[..., Method]] = Registry("method")


def list_methods() -> list[str]:
    return METHODS.names()


def run_method(name: str, data: str | Path, out: str | Path | None = None, **options) -> Predictions:
    """Fit method ``name`` on the training split of ``data``, predict the test split (and the
    training split when the method needs canonical-frame alignment), and save to ``out``.

    Raises:
        UnknownNameError: unknown method (lists the known ones).
    """
    factory = METHODS.get(name)
    method = factory(**options)
    train = load(data, "train")
    t0 = time.perf_counter()
    method.fit(train)
    t_fit = time.perf_counter() - t0
    test = load(data, "test")
    t1 = time.perf_counter()
    parts = [method.predict(test)]
    t_pred = time.perf_counter() - t1
    if method.needs_alignment:
        parts.append(method.predict(train))
    preds = Predictions.concatenate(parts)
    preds.dataset_hash = test.dataset_hash
    preds.info = {**preds.info, "fit_seconds": round(t_fit, 3), "predict_seconds_test": round(t_pred, 3),
                  "ms_per_cloud_test": round(1000 * t_pred / max(len(test), 1), 3)}
    if out is not None:
        preds.save(out)
    return preds
