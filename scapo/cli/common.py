"""What the ``scapo`` command groups share: argument types and the asset-cache option."""

from __future__ import annotations

from pathlib import Path


def ints(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]`` (an argparse type: a ValueError is argparse's usage error)."""
    return [int(x) for x in text.split(",") if x.strip()]


def floats(text: str) -> list[float]:
    """``"5,15"`` -> ``[5.0, 15.0]``."""
    return [float(x) for x in text.split(",") if x.strip()]


def names(text: str) -> list[str]:
    """``"scapo, npcs"`` -> ``["scapo", "npcs"]``."""
    return [x.strip() for x in text.split(",") if x.strip()]


def add_cache(sp) -> None:
    """The ``--cache`` option of the commands that build assets."""
    sp.add_argument("--cache", type=Path, default=None, help="asset cache folder (default ~/.cache/scapo/assets "
                    "or $SCAPO_CACHE/assets)")
