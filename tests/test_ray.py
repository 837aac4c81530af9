"""Generation on Ray: byte-identical to a local run for any number of workers, and resumable."""

import importlib.util
import json

import numpy as np
import pytest

from scapo.data import generate, load, make_config, plan

# skipped without Ray; imported in the test, not at collection (1.4 s in each pytest-xdist worker)
pytestmark = [pytest.mark.render, pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="no ray")]


class Interrupt(Exception):
    pass


def _arrays(path):
    return load(path, "all").arrays()


def test_ray_generation_equals_local_and_resumes(tmp_path):
    import ray

    cfg = make_config("scissors", 3, 4, seed=4, shard_size=3, val_fraction=0.0)
    generate(cfg, tmp_path / "local", progress=False)
    from scapo.data.generate import RAY_LOCAL_SYSTEM_CONFIG

    # as generation starts its own (its workers at normal priority: at Ray's niceness 15 they waited behind the
    # other pytest-xdist worker's processes)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
             _system_config=dict(RAY_LOCAL_SYSTEM_CONFIG))
    try:
        # a Ray run on two workers, interrupted (the driver stops after its second shard), resumes on one worker:
        # its shards from both worker counts equal the local run's
        seen = []

        def stop(name):
            seen.append(name)
            if len(seen) == 2:
                raise Interrupt

        with pytest.raises(Interrupt):
            generate(cfg, tmp_path / "ray", workers=2, progress=False, executor="ray", on_shard_done=stop)
        assert not (tmp_path / "ray" / "card.json").exists()
        rep = generate(cfg, tmp_path / "ray", workers=1, progress=False, executor="ray")
        sizes = {t.name: len(t.items) for t in plan(cfg)}
        assert rep.skipped_shards == 2 and rep.rendered == 12 - sizes[seen[0]] - sizes[seen[1]]
    finally:
        ray.shutdown()
    a, b = _arrays(tmp_path / "local"), _arrays(tmp_path / "ray")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    ca = json.loads((tmp_path / "local" / "card.json").read_text())
    cb = json.loads((tmp_path / "ray" / "card.json").read_text())
    assert ca["dataset_hash"] == cb["dataset_hash"] and ca["shards"] == cb["shards"]


def test_a_local_ray_cluster_runs_its_workers_at_normal_priority(monkeypatch):
    """A cluster generation starts itself gets ``worker_niceness`` 0 (Ray's default 15 starved the render actors
    beside any busy process); a cluster given by address is left as configured."""
    import ray

    from scapo.data.generate import _run_ray

    seen = []

    def init(**kw):
        seen.append(kw)
        raise Interrupt

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    for address in (None, "ray://host:10001"):
        with pytest.raises(Interrupt):
            _run_ray((), [], 2, None, None, address)
    assert seen[0]["_system_config"] == {"worker_niceness": 0} and seen[0]["num_cpus"] == 2
    assert seen[1]["address"] == "ray://host:10001" and "_system_config" not in seen[1]
