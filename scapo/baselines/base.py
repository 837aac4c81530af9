"""Method interface and registry shared by baselines and the SCAPO model.

A method is built from a name and options (``METHODS.get(name)(**options)``), fitted on the
training split of a dataset, and asked for :class:`~scapo.eval.predictions.Predictions` on any
split. :func:`run_method` does the whole round trip and writes the predictions file.
"""

from __future__ import annotations

import dataclasses
import time
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from scapo.data.dataset import ArticulationDataset, load
from scapo.errors import ConfigError, DatasetError
from scapo.eval.predictions import Predictions
from scapo.files import check_output_file
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


def options_class(name: str) -> type:
    """The options dataclass of method ``name`` (the factory's ``options`` attribute)."""
    return METHODS.get(name).options


def _parse_text(method: str, key: str, text: str, tp) -> Any:
    """Convert the command-line text of option ``key`` to the field type ``tp``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if text.strip().lower() in ("none", "null") and len(args) < len(typing.get_args(tp)):
            return None
        tp = args[0]
    bad = ConfigError(f"option {key}={text!r} of method {method!r} is not a valid {getattr(tp, '__name__', tp)}")
    if tp is bool:
        low = text.strip().lower()
        if low in ("true", "1", "yes", "on"):
            return True
        if low in ("false", "0", "no", "off"):
            return False
        raise bad
    if tp in (int, float):
        try:
            return tp(text)
        except ValueError:
            raise bad from None
    if tp is Path:
        return Path(text)
    return text


def validate_options(name: str, options: dict[str, Any]) -> dict[str, Any]:
    """Check ``options`` against method ``name``'s options dataclass; strings are converted to the
    field types (``"30"`` -> 30 for an int field, ``"true"`` -> True for a bool).

    Raises:
        UnknownNameError: unknown method.
        ConfigError: an unknown option (the message lists the valid ones) or a value that does not
            convert to the field's type.
    """
    cls = options_class(name)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    out = {}
    for k, v in options.items():
        if k not in fields:
            raise ConfigError(f"unknown option {k!r} for method {name!r}; valid options: {', '.join(fields)}")
        out[k] = _parse_text(name, k, v, hints[k]) if isinstance(v, str) else v
    return out


def run_method(name: str, data: str | Path, out: str | Path | None = None, **options) -> Predictions:
    """Fit method ``name`` on the training split of ``data``, predict the test split, the val split
    when the dataset has one (so choices can be made on it with the same file), and the training split
    when the method needs canonical-frame alignment, and save to ``out``.

    Options are validated (:func:`validate_options`) and ``out`` is checked to be writable before
    any work; the file is written atomically.

    Raises:
        UnknownNameError: unknown method (lists the known ones).
        ConfigError: unknown or invalid options.
        OutputError: ``out`` cannot be written.
        DatasetError: ``data`` is not a dataset, or its test split is empty.
    """
    factory = METHODS.get(name)
    method = factory(**validate_options(name, options))
    if out is not None:
        check_output_file(out, "predictions file", "predictions.npz")
    train = load(data, "train")
    test = load(data, "test")
    if len(test) == 0:
        raise DatasetError(f"the test split of {data} is empty (generated with --test-fraction "
                           f"{train.card.get('config', {}).get('test_fraction')} and "
                           f"{train.card.get('config', {}).get('instances')} instances); regenerate it with test "
                           "instances")
    t0 = time.perf_counter()
    method.fit(train)
    t_fit = time.perf_counter() - t0
    t1 = time.perf_counter()
    parts = [method.predict(test)]
    t_pred = time.perf_counter() - t1
    if "val" in train.card.get("splits", {}):
        val = load(data, "val")
        if len(val):
            parts.append(method.predict(val))
    if method.needs_alignment:
        parts.append(method.predict(train))
    preds = Predictions.concatenate(parts)
    preds.dataset_hash = test.dataset_hash
    preds.info = {**preds.info, "fit_seconds": round(t_fit, 3), "predict_seconds_test": round(t_pred, 3),
                  "ms_per_cloud_test": round(1000 * t_pred / max(len(test), 1), 3)}
    if out is not None:
        preds.save(out)
    return preds
