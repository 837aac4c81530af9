"""Shared fixtures: an isolated asset cache, one renderer per session, a small laptop dataset."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

_CACHE = tempfile.mkdtemp(prefix="scapo-test-cache-")
os.environ["SCAPO_CACHE"] = _CACHE

if os.environ.get("PYTEST_XDIST_WORKER"):  # one torch thread per pytest-xdist worker (scripts/test.sh runs two)
    # and in the trainings and commands they start (training takes min(usable cores, OMP_NUM_THREADS) threads;
    # two workers training with two threads each on two cores ran several times slower)
    os.environ["OMP_NUM_THREADS"] = "1"
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


@pytest.fixture(scope="session")
def small_laptop_data(tmp_path_factory) -> Path:
    """5 laptop instances x 3 views (4 training instances: a third of :func:`laptop_data`'s training clouds), for
    trainings whose every epoch or stage passes over all training clouds at full resolution (the
    pseudo-labels, the rigid-split search in processes the small-search fixtures below do not reach)."""
    from scapo.data import generate, make_config

    out = tmp_path_factory.mktemp("data") / "laptop_small"
    generate(make_config("laptop", 5, 3, seed=3, test_fraction=0.2, shard_size=16, val_fraction=0.0), out,
             progress=False)
    return out


@pytest.fixture
def small_part_search(monkeypatch):
    """The trainer's rigid-split search (:func:`scapo.models.part_init.initial_split`) with 8 pairs, 8 plane
    directions and 8 k-means starts instead of 32, 48 and 48: for tests of how the trainer uses the split, not of
    the search, whose result tests/test_part_init.py tests on its own (a sixth of the candidates, a quarter of the
    pairs: the search took ~6 s of such a test's ~10 s)."""
    import functools

    from scapo.models import part_init

    monkeypatch.setattr(part_init, "initial_split",
                        functools.partial(part_init.initial_split, pairs=8, directions=8, starts=8))


@pytest.fixture
def small_split_choice(monkeypatch):
    """The trainer's split choice (:func:`scapo.models.part_init.choose_split`, ``split_init="fit"``) from 4 random
    starts of 2 fitting rounds scored over 32 pairs instead of 24 starts, 8 rounds and 128 pairs: for tests of how
    the trainer uses the chosen split (its files, the pseudo-labels, the frames read from it), not of the choice,
    which tests/test_part_init.py tests on its own (the choice took about half of such a test's time)."""
    import functools

    from scapo.models import part_init

    monkeypatch.setattr(part_init, "choose_split", functools.partial(part_init.choose_split, starts=4, pairs=32,
                                                                         rounds=2))


# The longest self-contained integration tests start first, so that two pytest-xdist workers finish together
# (in collection order they came last and left one worker idle for their length).
_FIRST = ("test_ray.py::", "test_distributed.py::", "test_the_gpu_script_runs", "test_the_wheel_in_a_fresh_venv",
          "test_viewer.py::")


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda it: not any(k in it.nodeid for k in _FIRST))  # stable: the rest keep their order


@pytest.fixture(scope="session")
def trained_test_runs(laptop_data, tmp_path_factory) -> dict[str, Path]:
    """One run of every trained method (its ``test`` preset) on :func:`laptop_data`: method name -> run folder.
    Shared by test_methods.py and test_user_facing.py, which run on one pytest-xdist worker (below); a test that
    changes a run copies it first."""
    from scapo.methods import METHODS, train_method

    root = tmp_path_factory.mktemp("runs")
    runs = {}
    for name in METHODS.names():
        if METHODS.get(name).trained:
            runs[name] = root / name
            train_method(name, laptop_data, runs[name], "test", progress=False)
    return runs


# Modules whose module-scoped fixtures train or render for tens of seconds and serve most of the module's tests
# (test_user_facing's ``runs``, test_methods' ``trained_runs``, test_bench's ``bench``, test_bad_input's ``run`` and
# ``small``, test_train's ``finished_run`` and ``root_motion_run``, test_icp's ``icp_run``): each module runs whole
# on one pytest-xdist worker, so that its fixtures are computed once, not once per worker (CI measured 220 s with
# both workers training them). ``--dist loadgroup`` would do this per test, but xdist 3.8 renames
# ``item._nodeid``, which pytest 9.2 no longer reads, so its groups are silently ignored.
_WHOLE_MODULES = ("tests/test_user_facing.py", "tests/test_methods.py", "tests/test_bench.py",
                  "tests/test_bad_input.py", "tests/test_train.py", "tests/test_icp.py")
#: modules that share a session fixture run together as one unit (``trained_test_runs``)
_SAME_UNIT = {"tests/test_user_facing.py": "tests/test_methods.py"}


def pytest_xdist_make_scheduler(config, log):
    """The default ``load`` scheduling, except that each module of ``_WHOLE_MODULES`` is one unit of work."""
    if config.getvalue("dist") != "load":
        return None  # an explicit --dist: xdist's own scheduler
    from xdist.scheduler import LoadScopeScheduling

    class SharedFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return _SAME_UNIT.get(module, module) if module in _WHOLE_MODULES else nodeid

    return SharedFixtureScheduling(config, log)
