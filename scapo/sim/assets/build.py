"""Build procedural instances to disk, with a content-keyed cache.

An instance is identified by ``(category, seed, instance_id)``. Its files live in
``<cache>/<category>/g<GENERATOR_VERSION>-<template digest>/seed<seed>/<instance_id:05d>/`` and are
byte-identical for the same key, on any machine. Builds are atomic: the directory appears only
when complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scapo.errors import AssetError
from scapo.sim.assets.categories import CATEGORIES
from scapo.sim.assets.design import ArticulatedDesign, finalize, write_asset
from scapo.sim.assets.templates import ParamSampler, load_template

#: Bump when generator code changes the output for an existing (category, seed, instance_id).
GENERATOR_VERSION = 1


def default_cache_dir() -> Path:
    """``$SCAPO_CACHE/assets`` or ``~/.cache/scapo/assets``."""
    root = os.environ.get("SCAPO_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "scapo")
    return Path(root) / "assets"


def list_categories() -> list[str]:
    """Names of the procedural categories, in SPEC order."""
    return CATEGORIES.names()


def instance_rng(category: str, seed: int, instance_id: int) -> np.random.Generator:
    """The random generator that draws the design of one instance (independent of other instances)."""
    return np.random.default_rng([int(seed), int(instance_id), zlib.crc32(category.encode())])


def design_instance(category: str, instance_id: int, seed: int) -> ArticulatedDesign:
    """Draw and finalize the design of one instance (no files written).

    Raises:
        UnknownNameError: for an unknown category (lists the known ones).
    """
    gen = CATEGORIES.get(category)
    tpl = load_template(category)
    return finalize(gen(ParamSampler(tpl, instance_rng(category, seed, instance_id))))


@dataclass(frozen=True)
class AssetRecord:
    """A built instance on disk.

    Attributes:
        category, seed, instance_id: identity. directory: folder with ``model.urdf``,
        ``meshes/`` and ``asset.json``. urdf: path of ``model.urdf``. bbox_diag: rest-state
        bounding-box diagonal (m). digest: sha256 over the instance's files.
    """

    category: str
    seed: int
    instance_id: int
    directory: Path
    urdf: Path
    bbox_diag: float
    digest: str

    def metadata(self) -> dict:
        """The parsed ``asset.json``."""
        return json.loads((self.directory / "asset.json").read_text())


def _digest(directory: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in directory.rglob("*") if p.is_file()):
        h.update(f.relative_to(directory).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def instance_dir(category: str, instance_id: int, seed: int, cache_dir: Path | None = None) -> Path:
    """Cache folder of one instance (it may not exist yet)."""
    tpl = load_template(category)
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return root / category / f"g{GENERATOR_VERSION}-{tpl.digest[:12]}" / f"seed{seed}" / f"{instance_id:05d}"


def build_instance(category: str, instance_id: int, seed: int, cache_dir: Path | None = None) -> AssetRecord:
    """Build one instance into the cache (or reuse it) and return its record.

    Raises:
        UnknownNameError: unknown category. AssetError: the cached folder is incomplete.
    """
    CATEGORIES.get(category)
    out = instance_dir(category, instance_id, seed, cache_dir)
    if not (out / "asset.json").is_file():
        design = design_instance(category, instance_id, seed)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp", dir=out.parent))
        try:
            extra = {"seed": int(seed), "instance_id": int(instance_id), "generator_version": GENERATOR_VERSION,
                     "template_digest": load_template(category).digest}
            write_asset(design, tmp, extra)
            try:
                os.rename(tmp, out)
            except OSError:
                if not (out / "asset.json").is_file():  # not a concurrent build of the same instance
                    raise
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
    try:
        meta = json.loads((out / "asset.json").read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise AssetError(f"cached asset {out} is unreadable ({e}); delete the folder to rebuild it") from e
    return AssetRecord(category, int(seed), int(instance_id), out, out / "model.urdf", float(meta["bbox_diag"]),
                       _digest(out))


def build_category(
    category: str, instances: int, seed: int, cache_dir: Path | None = None, progress: bool = False
) -> list[AssetRecord]:
    """Build instances ``0 .. instances-1`` of ``category``; returns their records in order."""
    ids = range(int(instances))
    if progress:
        from tqdm import tqdm

        ids = tqdm(ids, desc=f"assets {category}", unit="inst")
    return [build_instance(category, i, seed, cache_dir) for i in ids]
