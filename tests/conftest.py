"""Shared fixtures: an isolated asset cache, one renderer per session, a small laptop dataset."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

_CACHE = tempfile.mkdtemp(prefix="scapo-test-cache-")
os.environ["SCAPO_CACHE"] = _CACHE

if os.environ.get("PYTEST_XDIST_WORKER"):  # one torch thread per pytest-xdist worker (scripts/test.sh runs two)
    import torch

    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def cache_dir() -> Path:
    return Path(_CACHE) / "assets"


@pytest.fixture(scope="session")
def renderer():
    from scapo.sim.render import Renderer

    r = Renderer()
    yield r
    r.close()


@pytest.fixture(scope="session")
def laptop_data(tmp_path_factory) -> Path:
    """8 laptop instances x 6 views (2 test instances, no val split; val splits are tested in test_data.py)."""
    from scapo.data import generate, make_config

    out = tmp_path_factory.mktemp("data") / "laptop"
    generate(make_config("laptop", 8, 6, seed=3, test_fraction=0.25, shard_size=16, val_fraction=0.0), out,
             progress=False)
    return out


# The longest self-contained integration tests start first, so that two pytest-xdist workers finish together
# (in collection order they came last and left one worker idle for their length).
_FIRST = ("test_ray.py::", "test_distributed.py::", "test_the_gpu_script_runs", "test_the_wheel_in_a_fresh_venv",
          "test_viewer.py::")


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda it: not any(k in it.nodeid for k in _FIRST))  # stable: the rest keep their order
