"""Build procedural instances to disk, with a content-keyed cache.

An instance is identified by ``(category, seed, instance_id)``. Its files live in
``<cache>/<category>/g<GENERATOR_VERSION>-<template digest>/seed<seed>/<instance_id:05d>/`` and are
byte-identical for the same key, on any machine. Builds are atomic: the directory appears only
when complete (it is built in a hidden ``.<id>.tmp-<pid>-*`` folder, removed by a later build if the
process died).

The cache is not trusted blindly: each instance folder records the sha256 of its files
(``files.sha256``), and every reuse recomputes it. A folder whose files were changed, removed or
truncated since it was built is rebuilt (the build is deterministic), with a warning. A folder of
an older scapo without the record is checked once against a fresh build.
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

from scapo.errors import AssetError, ConfigError
from scapo.files import atomic_write_text, clean_stale_temps
from scapo.sim.assets.categories import CATEGORIES
from scapo.sim.assets.design import ArticulatedDesign, finalize, write_asset
from scapo.sim.assets.templates import ParamSampler, load_template

#: Bump when generator code changes the output for an existing (category, seed, instance_id).
GENERATOR_VERSION = 3


def default_cache_dir() -> Path:
    """``$SCAPO_CACHE/assets`` or ``~/.cache/scapo/assets``."""
    root = os.environ.get("SCAPO_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "scapo")
    return Path(root) / "assets"


def list_categories() -> list[str]:
    """Names of the procedural categories, in SPEC order."""
    return CATEGORIES.names()


def instance_rng(category: str, seed: int, instance_id: int) -> np.random.Generator:
    """The random generator that draws the design of one instance (independent of other instances).

    Raises:
        ConfigError: a negative seed or instance id.
    """
    if int(seed) < 0 or int(instance_id) < 0:
        raise ConfigError(f"seed and instance id must be >= 0, got {seed} and {instance_id}")
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


#: File in each instance folder holding the sha256 of the folder's other files (not part of the digest).
DIGEST_FILE = "files.sha256"


def _digest(directory: Path) -> str:
    """sha256 over the relative paths and bytes of the files of an instance folder (``DIGEST_FILE`` excluded)."""
    h = hashlib.sha256()
    for f in sorted(p for p in directory.rglob("*") if p.is_file() and p.name != DIGEST_FILE):
        h.update(f.relative_to(directory).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def instance_dir(category: str, instance_id: int, seed: int, cache_dir: Path | None = None) -> Path:
    """Cache folder of one instance (it may not exist yet)."""
    tpl = load_template(category)
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return root / category / f"g{GENERATOR_VERSION}-{tpl.digest[:12]}" / f"seed{seed}" / f"{instance_id:05d}"


def _cache_error(root: Path, e: OSError) -> AssetError:
    return AssetError(f"the asset cache {root} cannot be written ({e.strerror or e}); point SCAPO_CACHE (or "
                      "--cache) at a writable folder")


def _build_into_temp(category: str, instance_id: int, seed: int, parent: Path, name: str) -> Path:
    """Write the instance into a fresh hidden folder beside its cache folder; returns that folder."""
    design = design_instance(category, instance_id, seed)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.tmp-{os.getpid()}-", dir=parent))
    try:
        extra = {"seed": int(seed), "instance_id": int(instance_id), "generator_version": GENERATOR_VERSION,
                 "template_digest": load_template(category).digest}
        write_asset(design, tmp, extra)
        atomic_write_text(tmp / DIGEST_FILE, _digest(tmp) + "\n")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


def _recorded_digest(folder: Path) -> str | None:
    try:
        return (folder / DIGEST_FILE).read_text().strip() or None
    except OSError:
        return None


def build_instance(category: str, instance_id: int, seed: int, cache_dir: Path | None = None) -> AssetRecord:
    """Build one instance into the cache (or reuse it, after checking its files) and return its record.

    Raises:
        UnknownNameError: unknown category.
        AssetError: the cache folder cannot be created or written (names it and what to do).
    """
    CATEGORIES.get(category)
    out = instance_dir(category, instance_id, seed, cache_dir)
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    for parent in [root, *root.parents]:
        if parent.exists() and not parent.is_dir():
            raise AssetError(f"the asset cache {root} cannot be used: {parent} is a file; point SCAPO_CACHE (or "
                             "--cache) at a folder")
    digest = None  # of the folder as it is returned, when already computed
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temps(out.parent)  # folders of builds whose process died
        if (out / "asset.json").is_file():
            recorded = _recorded_digest(out)
            actual = digest = _digest(out)
            if recorded is None:  # a cache folder of an older scapo: compare with a fresh build once
                tmp = _build_into_temp(category, instance_id, seed, out.parent, out.name)
                fresh = _digest(tmp)
                if fresh == actual:
                    shutil.rmtree(tmp, ignore_errors=True)
                    atomic_write_text(out / DIGEST_FILE, actual + "\n")
                else:
                    _replace(out, tmp, "differs from a fresh build")
                    digest = fresh
            elif recorded != actual:
                tmp = _build_into_temp(category, instance_id, seed, out.parent, out.name)
                _replace(out, tmp, "was modified after it was built (its files no longer match files.sha256)")
                digest = None
        else:
            tmp = _build_into_temp(category, instance_id, seed, out.parent, out.name)
            try:
                os.rename(tmp, out)
            except OSError:
                shutil.rmtree(tmp, ignore_errors=True)
                if not (out / "asset.json").is_file():  # not a concurrent build of the same instance
                    raise
    except OSError as e:
        raise _cache_error(root, e) from e
    try:
        meta = json.loads((out / "asset.json").read_text())
        bbox_diag = float(meta["bbox_diag"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise AssetError(f"cached asset {out} is unreadable ({e}); delete the folder to rebuild it") from e
    return AssetRecord(category, int(seed), int(instance_id), out, out / "model.urdf", bbox_diag,
                       digest or _digest(out))


def _replace(out: Path, fresh: Path, why: str) -> None:
    """Swap a damaged cache folder ``out`` for the freshly built ``fresh`` (a :class:`~scapo.errors.ScapoWarning`)."""
    import warnings

    from scapo.errors import ScapoWarning

    warnings.warn(f"cached asset {out} {why}; rebuilt it", ScapoWarning, stacklevel=2)
    old = out.with_name(f".{out.name}.tmp-{os.getpid()}-old")
    os.rename(out, old)
    os.rename(fresh, out)
    shutil.rmtree(old, ignore_errors=True)


def build_category(
    category: str, instances: int, seed: int, cache_dir: Path | None = None, progress: bool = False
) -> list[AssetRecord]:
    """Build instances ``0 .. instances-1`` of ``category``; returns their records in order.

    Raises:
        ConfigError: ``instances < 1``. Otherwise as :func:`build_instance`.
    """
    if int(instances) < 1:
        raise ConfigError(f"the number of instances must be >= 1, got {instances}")
    if not progress:
        return [build_instance(category, i, seed, cache_dir) for i in range(int(instances))]
    from scapo.report import progress_bar

    with progress_bar(range(int(instances)), desc=f"assets {category}", unit="inst") as ids:
        return [build_instance(category, i, seed, cache_dir) for i in ids]
