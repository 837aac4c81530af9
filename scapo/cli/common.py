"""What the ``scapo`` command groups share: argument types and the asset-cache option."""

from __future__ import annotations

import argparse
from pathlib import Path


def _items(text: str) -> list[str]:
    items = [x.strip() for x in str(text).split(",") if x.strip()]
    if not items:  # an empty list would silently mean "all" where the option has a default
        raise argparse.ArgumentTypeError(f"{text!r} names nothing; give at least one value (a comma-separated list)")
    return items


def ints(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]`` (an argparse type: its errors are argparse's usage errors, exit 2)."""
    return [int(x) for x in _items(text)]


def floats(text: str) -> list[float]:
    """``"5,15"`` -> ``[5.0, 15.0]``."""
    return [float(x) for x in _items(text)]


def names(text: str) -> list[str]:
    """``"scapo, npcs"`` -> ``["scapo", "npcs"]``; an empty list is refused."""
    return _items(text)


def add_cache(sp) -> None:
    """The ``--cache`` option of the commands that build assets."""
    sp.add_argument("--cache", type=Path, default=None, help="asset cache folder (default ~/.cache/scapo/assets "
                    "or $SCAPO_CACHE/assets)")
