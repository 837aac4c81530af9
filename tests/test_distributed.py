"""Data-parallel training (scapo.nn.engine) on CPU with the gloo backend: two processes under torchrun train,
checkpoint once per epoch, and a run resumes under another world size; batch statistics are global."""

import json
import os
import subprocess
import sys

import pandas as pd
import pytest
import torch

pytestmark = pytest.mark.slow


def _bn_worker(rank, world, init_file, x, out):
    import torch.distributed as dist

    from scapo.nn.vn import VNBatchNorm

    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world)
    try:
        bn = VNBatchNorm(4)
        bn.train()
        half = x.shape[0] // world
        mine = x[rank * half:(rank + 1) * half].clone().requires_grad_(True)
        y = bn(mine)
        y.sum().backward()
        torch.save({"y": y.detach(), "running_mean": bn.bn.running_mean.clone()}, f"{out}.{rank}")
        dist.barrier()  # no rank leaves while the other still communicates
    finally:
        dist.destroy_process_group()


def test_vn_batch_norm_uses_the_global_batch_across_ranks(tmp_path):
    from scapo.nn.vn import VNBatchNorm

    torch.manual_seed(0)
    x = torch.randn(6, 4, 3, 5) * torch.linspace(0.5, 2.0, 6)[:, None, None, None]
    ref = VNBatchNorm(4)
    ref.train()
    y_ref = ref(x).detach()
    torch.multiprocessing.spawn(_bn_worker, args=(2, str(tmp_path / "init"), x, str(tmp_path / "o")), nprocs=2)
    for r in range(2):
        got = torch.load(f"{tmp_path / 'o'}.{r}")
        torch.testing.assert_close(got["y"], y_ref[r * 3:(r + 1) * 3], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(got["running_mean"], ref.bn.running_mean, atol=1e-6, rtol=1e-6)


def _torchrun(*args, nproc=2, timeout=900):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}",
                           "-m", "scapo.cli", *args], capture_output=True, text=True, timeout=timeout, env=env)


# SCAPO only: its two stages and the pseudo-labels between them are the most the engine does under torchrun; the
# engine (sampler, gradient averaging, checkpoints) is one for every trained method, and a one-stage method's resume
# is tested in one process (tests/test_methods.py). The OP-Align-style case was dropped for the suite's time (13 s).
@pytest.mark.parametrize("method", ["scapo"])
def test_two_process_gloo_run_trains_checkpoints_and_resumes_under_another_world_size(method, small_laptop_data,
                                                                                     tmp_path):
    laptop_data = small_laptop_data  # the ranks' split search and pseudo-labels pass over every training cloud
    run = tmp_path / "run"
    r = _torchrun("train", "--method", method, "--data", str(laptop_data), "--preset", "test", "--out", str(run),
                  "--no-progress")
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.count("trained:") == 1  # rank 0 speaks for the run
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    assert state["done"] and state["world_size"] == 2
    assert not [p.name for p in run.iterdir() if p.name.startswith(".") and p.name != ".scapo.lock"]  # no temp files
    log = pd.read_csv(run / "log.csv")
    assert not log.duplicated(["stage", "epoch", "step"]).any()  # one writer
    assert json.loads((run / "timing.json").read_text())["world_size"] == 2
    # resume the last epoch of that run in one process (as if interrupted there): it continues and finishes
    if method == "scapo":
        state.update(done=False, stage=2, epoch=0)
    else:
        state.update(done=False, epoch=state["epoch"] - 1)
    torch.save(state, run / "checkpoint.pt")
    from scapo.methods import train_method

    threads, rng = torch.get_num_threads(), torch.random.get_rng_state()
    train_method(method, laptop_data, run, None, progress=False)
    after = torch.load(run / "checkpoint.pt", weights_only=False)
    assert after["done"] and after["world_size"] == 1
    # training left the caller's process as it found it: thread count and global RNG
    assert torch.get_num_threads() == threads and torch.equal(torch.random.get_rng_state(), rng)
