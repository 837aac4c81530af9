"""Overrides of a frozen settings dataclass (a training preset) from the command line and from config files.

``scapo train --preset cpu --set stage1_epochs=40 --set losses.seg=2.0 --config my.toml``: each ``--set KEY=VALUE``
names a field of the preset (a dotted path into nested settings, e.g. ``losses.seg``, ``encoder.k``), and its
text is converted to the field's type; a config file (TOML, or YAML where PyYAML is installed) holds the same
keys as a table (nested tables for nested settings). The file is applied first, ``--set`` after it. The result is
the preset with those fields replaced (its own checks run again), so a run's ``run.json`` records every value it
trained with, and a run started with overrides is refused by the same preset without them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from scapo.errors import ConfigError


def parse_assignments(items: list[str] | None, flag: str = "--set") -> dict[str, str]:
    """``["a=1", "b.c=x"]`` -> ``{"a": "1", "b.c": "x"}``.

    Raises:
        ConfigError: an item without ``=`` or with an empty key; a key given twice."""
    out: dict[str, str] = {}
    for item in items or []:
        key, eq, value = str(item).partition("=")
        key = key.strip()
        if not eq or not key:
            raise ConfigError(f"{flag} {item!r} is not of the form KEY=VALUE (e.g. {flag} stage1_epochs=40)")
        if key in out:
            raise ConfigError(f"{flag} gives {key!r} twice")
        out[key] = value.strip()
    return out


def read_config(path: str | Path) -> dict[str, Any]:
    """The settings in a TOML (``.toml``) or YAML (``.yaml``/``.yml``) file, flattened to dotted keys
    (``[losses] seg = 2.0`` -> ``{"losses.seg": 2.0}``).

    Raises:
        ConfigError: missing or unreadable file, a syntax error (with the parser's message), another suffix, a
            file that is not a table of settings, a setting given twice (a repeated YAML key, or one key spelled
            both dotted and in its table), or YAML without PyYAML installed."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"--config {path}: no such file")
    if not path.is_file():  # a folder, a FIFO, a device (/dev/zero would never end): never read
        kind = "a folder" if path.is_dir() else "not a regular file (a pipe or a device)"
        raise ConfigError(f"--config {path} is {kind}; give a .toml or .yaml file of settings")
    suffix = path.suffix.lower()
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"--config {path} cannot be read ({e})") from None
    if suffix == ".toml":
        import tomllib

        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"--config {path} is not valid TOML ({e})") from None
    elif suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise ConfigError(f"--config {path}: reading YAML needs PyYAML (pip install pyyaml); or write the "
                              "file as TOML") from None
        class UniqueKeys(yaml.SafeLoader):  # plain data only (no tags, no code), and no key given twice
            pass

        def mapping(loader, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                key = loader.construct_object(key_node, deep=deep)
                if key in seen:
                    raise ConfigError(f"--config {path} gives the key {key!r} twice (line "
                                      f"{key_node.start_mark.line + 1}); give each setting once")
                seen.add(key)
            return loader.construct_mapping(node, deep)

        UniqueKeys.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
        try:
            data = yaml.load(text, Loader=UniqueKeys)  # noqa: S506 - a SafeLoader subclass
        except yaml.YAMLError as e:
            raise ConfigError(f"--config {path} is not valid YAML ({e})") from None
    else:
        raise ConfigError(f"--config {path}: give a .toml or .yaml file")
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"--config {path} holds a {type(data).__name__}, not a table of settings")

    flat: dict[str, Any] = {}

    def walk(prefix: str, d: dict) -> None:
        for k, v in d.items():
            key = f"{prefix}{k}"
            if isinstance(v, dict):
                walk(key + ".", v)
            elif key in flat:  # e.g. "losses.seg" and [losses] seg: one setting spelled twice
                raise ConfigError(f"--config {path} gives {key!r} twice (once as a dotted key, once in its table); "
                                  "give each setting once")
            else:
                flat[key] = v

    walk("", data)
    return flat


def _convert(key: str, value: Any, tp: Any, what: str) -> Any:
    """``value`` (text from the command line, or a value from a config file) as the field type ``tp``."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            if len(args) < len(typing.get_args(tp)):
                return None
        tp, origin = args[0], typing.get_origin(args[0])
    name = getattr(tp, "__name__", str(tp))
    bad = ConfigError(f"{what} {key}={value!r} is not a valid {name}")
    if origin is typing.Literal:
        allowed = typing.get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{what} {key}={value!r} must be one of {', '.join(map(repr, allowed))}")
        return value
    if origin in (tuple, list):
        items = value
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                try:
                    items = json.loads(text)
                except ValueError:
                    raise bad from None
            else:
                items = [t for t in (p.strip() for p in text.split(",")) if t]
        if not isinstance(items, (list, tuple)):
            raise bad
        args = typing.get_args(tp)
        inner = args[0] if args else str
        return tuple(_convert(key, v, inner, what) for v in items)
    if tp is bool:
        if isinstance(value, bool):
            return value
        low = str(value).strip().lower()
        if low in ("true", "1", "yes", "on"):
            return True
        if low in ("false", "0", "no", "off"):
            return False
        raise bad
    if tp is int:
        if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
            raise bad
        try:
            return int(value) if not isinstance(value, str) else int(value.strip())
        except (TypeError, ValueError, OverflowError):  # e.g. a TOML date, inf
            raise bad from None
    if tp is float:
        if isinstance(value, bool):
            raise bad
        try:
            return float(value)
        except (TypeError, ValueError, OverflowError):
            raise bad from None
    if tp is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise bad
        return str(value)
    if tp is Path:
        return Path(str(value))
    raise ConfigError(f"{what} {key}: a field of type {name} cannot be set here")


def override(settings: Any, values: Mapping[str, Any], what: str = "preset") -> Any:
    """``settings`` (a frozen dataclass) with the fields ``values`` names replaced; dotted keys reach nested
    dataclasses. Text values are converted to the field's type.

    Raises:
        ConfigError: an unknown field (the message lists the valid ones at that level), a value that does not
            convert (a TOML date for a number), a preset's ``name`` (its identity: ``--preset`` chooses it), or one
            the dataclass's own checks refuse (their message)."""
    if not values:
        return settings
    nested: dict[str, dict[str, Any]] = {}
    direct: dict[str, Any] = {}
    for key, value in values.items():
        head, dot, rest = key.partition(".")
        (nested.setdefault(head, {}).__setitem__(rest, value) if dot else direct.__setitem__(head, value))
    fields = {f.name: f for f in dataclasses.fields(settings)}
    hints = typing.get_type_hints(type(settings))
    changes = {}
    for head in [*direct, *nested]:
        if head not in fields:
            raise ConfigError(f"unknown {what} field {head!r}; valid fields: {', '.join(fields)}")
    if "name" in direct and "preset" in what and "name" in fields:
        raise ConfigError(f"{what}: 'name' is the preset's identity, not a setting (a run trained with one preset's "
                          f"settings would record another's name); give --preset NAME to train that preset")
    for head, value in direct.items():
        if dataclasses.is_dataclass(getattr(settings, head)):
            sub = getattr(settings, head)
            raise ConfigError(f"{what} field {head!r} is a group of settings: set one of its fields, e.g. "
                              f"{head}.{dataclasses.fields(sub)[0].name}=...")
        changes[head] = _convert(head, value, hints[head], what)
    for head, sub_values in nested.items():
        sub = getattr(settings, head)
        if not dataclasses.is_dataclass(sub):
            raise ConfigError(f"{what} field {head!r} has no fields (set it as {head}=VALUE)")
        changes[head] = override(sub, sub_values, f"{what} {head}")
    try:
        return dataclasses.replace(settings, **changes)
    except ConfigError:
        raise  # the dataclass's own check, which names the preset already
    except (ValueError, TypeError) as e:
        raise ConfigError(f"{what}: {e}") from None


def check_settings(obj: Any, *, positive: Sequence[str] = (), non_negative: Sequence[str] = (),
                   minimum: Mapping[str, int] | None = None, positive_tuples: Sequence[str] = ()) -> None:
    """The range checks of a settings dataclass, for its ``__post_init__``: every float field finite (no NaN or
    infinity), the fields in ``positive`` > 0, in ``non_negative`` >= 0, each of ``minimum`` at least its value, and
    each of ``positive_tuples`` a non-empty tuple of positive integers.

    Raises:
        ValueError: naming the first field that fails and its value (:func:`override` turns it into a ConfigError of
            the ``--set`` key)."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"invalid {f.name}: must be a finite number, got {v!r}")
    for name in positive:
        if not getattr(obj, name) > 0:
            raise ValueError(f"invalid {name}: must be > 0, got {getattr(obj, name)!r}")
    for name in non_negative:
        if not getattr(obj, name) >= 0:
            raise ValueError(f"invalid {name}: must be >= 0, got {getattr(obj, name)!r}")
    for name, low in (minimum or {}).items():
        v = getattr(obj, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise ValueError(f"invalid {name}: must be an integer >= {low}, got {v!r}")
    for name in positive_tuples:
        v = getattr(obj, name)
        if not isinstance(v, tuple) or not v or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0
                                                         for x in v):
            raise ValueError(f"invalid {name}: must be a non-empty list of positive integers, got {v!r}")
