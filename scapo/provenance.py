"""Provenance of results: git commit, machine, library versions (recorded with every table)."""

from __future__ import annotations

import os
import platform
import subprocess
import time
from functools import lru_cache
from pathlib import Path


def package_version() -> str:
    """The installed scapo's version (package metadata; ``scapo.__version__`` for a source tree never installed)."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("scapo")
    except (ImportError, PackageNotFoundError, ValueError):
        from scapo import __version__

        return __version__


@lru_cache(maxsize=1)
def git_commit() -> str:
    """``<sha>`` of the source checkout, ``<sha>-dirty`` with uncommitted changes (``<sha>-unverified`` when git could
    not say, e.g. timed out on a loaded machine; ``unknown`` when it ran and could not name the commit), or, for an
    installed package that is not a git checkout (a wheel) or where git is not installed, ``v<version>`` (the
    released code it names; not dirty); for a copy of a checkout without its ``.git`` (e.g. sent to a GPU machine),
    ``<sha>-copy`` where ``SCAPO_SOURCE_COMMIT`` states the commit it was copied from (40 hex digits; the caller
    vouches for it).

    Taken once per process, at the first call; every ``scapo`` command calls it as it starts (:func:`scapo.cli.
    main.main`), so a long bench records the commit of the code it loaded, not the state of the checkout
    hours later when a cell finishes (edits made meanwhile do not run in it).
    """
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():  # an installed copy (perhaps in a venv inside some other repository)
        stated = os.environ.get("SCAPO_SOURCE_COMMIT", "").strip().lower()
        if len(stated) == 40 and all(ch in "0123456789abcdef" for ch in stated):
            return f"{stated}-copy"  # a copy of a checkout without its .git (a remote machine): the caller states it
        return f"v{package_version()}"
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=120, check=True).stdout.strip()
    except OSError:  # no git here: the package's own version names the code
        return f"v{package_version()}"
    except subprocess.SubprocessError:
        return "unknown"  # git ran and could not tell (timed out, a damaged .git): never a version
    try:
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=120, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return f"{sha}-unverified"  # whether the tree had changes is not known (git status failed or timed out)
    return f"{sha}-dirty" if dirty else sha


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask, e.g. under ``taskset`` or a batch
    scheduler; the machine's count where the mask is unknown); at least 1. Training uses this many
    torch threads, so two jobs pinned to different cores do not oversubscribe them."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def training_threads() -> int:
    """Torch threads for training: :func:`usable_cores`, at most ``OMP_NUM_THREADS`` where that is set to a
    positive integer (the usual way to give a job fewer threads than its cores, e.g. two jobs sharing a
    machine's cores; an unset, empty or malformed value is ignored). At least 1.

    More threads than the cores a job really gets (two 2-thread trainings on 2 cores) make OpenMP's threads wait
    on each other, which costs far more than the second thread gains.
    """
    cores = usable_cores()
    try:
        cap = int(os.environ.get("OMP_NUM_THREADS", "").strip())
    except ValueError:
        return cores
    return max(1, min(cores, cap)) if cap >= 1 else cores


@lru_cache(maxsize=1)
def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


@lru_cache(maxsize=1)
def cpu_kind() -> str:
    """The kind of CPU, finer than its marketing name: ``"AMD EPYC, family 25 model 17, avx512"`` (vendor's model
    name, ``/proc/cpuinfo``'s family and model, and whether it has AVX-512 or AVX2). Machines sold under one name
    differ in these (AMD EPYC of family 25 model 1 without AVX-512, model 17 with it), so a core-second is only
    compared between cells whose kind is the same (the compute ledger, :mod:`scapo.engine.ledger`, records it)."""
    fields = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() in ("cpu family", "model", "flags") and key.strip() not in fields:
                fields[key.strip()] = value.strip()
            if line.strip() == "" and fields:
                break
    except OSError:
        pass
    flags = set(fields.get("flags", "").split())
    vector = "avx512" if "avx512f" in flags else "avx2" if "avx2" in flags else "no avx2" if flags else ""
    parts = [cpu_name()]
    if "cpu family" in fields or "model" in fields:
        parts.append(f"family {fields.get('cpu family', '?')} model {fields.get('model', '?')}")
    if vector:
        parts.append(vector)
    return ", ".join(parts) if len(parts) > 1 else f"{platform.machine()} {cpu_name()}"


def device_description(torch_device: str | None = None) -> str:
    """Short description such as ``"cpu: 2 cores, Intel(R) ..."`` or ``"cuda: NVIDIA H100 ..."``."""
    if torch_device and torch_device.startswith("cuda"):
        import torch

        return f"cuda: {torch.cuda.get_device_name(torch.device(torch_device))}"
    return f"cpu: {os.cpu_count()} cores, {cpu_name()}"


def render_device() -> str:
    """The Vulkan device SAPIEN renders on (first line of its device summary), or the error."""
    try:
        import sapien

        summary = sapien.render.get_device_summary()
        for line in summary.splitlines():
            if line.strip().startswith("GPU:") or line.strip().startswith("CPU:"):
                return line.strip()
        return summary.strip().splitlines()[0] if summary.strip() else "unknown"
    except Exception as e:  # noqa: BLE001 - reported, not hidden
        return f"none ({e})"


def provenance(**extra) -> dict:
    """Dict with commit, time, host, device, versions, plus ``extra`` (e.g. preset, dataset hash)."""
    import numpy
    import torch

    try:
        import sapien

        sapien_version = sapien.__version__
    except ImportError:
        sapien_version = "not installed"
    from scapo import __version__

    return {
        "commit": git_commit(),
        "scapo_version": __version__,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "host": platform.node(),
        "device": device_description(extra.pop("torch_device", None)),
        "cpu_kind": cpu_kind(),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "torch": torch.__version__,
        "sapien": sapien_version,
        **extra,
    }
