"""Data-parallel training for the engine (:mod:`scapo.engine.loop`): the process group ``torchrun`` starts,
gradient averaging, and the process settings a run needs without leaking them into the caller's process.

Data parallelism (PyTorch distributed, the process group that ``torchrun`` describes in its environment:
``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``/``MASTER_PORT``):

- every rank holds the whole model; each epoch, a :class:`~torch.utils.data.distributed.DistributedSampler`
  seeded by the run's seed and the epoch gives each rank its own share of the training clouds;
- after each backward pass the gradients are averaged over the ranks (:meth:`DistContext.average_gradients`:
  what ``DistributedDataParallel`` does, done explicitly because SCAPO's losses call several sub-networks
  outside a single ``forward``), so all ranks take the same optimiser step and stay identical;
- batch statistics are synchronised: the vector-neuron batch norm (:class:`scapo.nn.vn.VNBatchNorm`) takes
  its mean and variance over the global batch through :func:`scapo.nn.sync.sync_batch_stats` (differentiable
  all-reduce; torch's ``SyncBatchNorm`` refuses CPU tensors, and the gloo backend is how this is tested on CPU);
- batch-coupled losses (SCAPO's cross-instance alignment and consensus terms, OP-Align-style's balance term)
  are computed over each rank's local batch: with world size W and per-rank batch B the gradient is the
  average over ranks of those local-batch losses, the same as one process stepping on W batches of B (not
  one batch of W x B), so a preset's ``batch_size`` is the per-rank batch;
- only rank 0 writes (checkpoints, logs, plots, ``run.json``); the others wait at barriers. A checkpoint holds
  the model, optimiser and schedule, which are the same on every rank, and the epoch; the data order depends
  only on (seed, epoch, world size), so a run resumes under another world size (from the next epoch, with that
  world size's split of the data).

With one process (no ``torchrun``) nothing of this is active and training is exactly as before.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from scapo.errors import ConfigError


@dataclass
class DistContext:
    """This process's place in a data-parallel run (world size 1 without ``torchrun``).

    Attributes:
        rank, world: this process's rank and the number of processes. local_rank: its rank on this machine
        (the CUDA device it uses). started: whether this context initialised the process group (and so
        destroys it in :meth:`close`).
    """

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    started: bool = False

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that writes files."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1

    def device(self, requested: torch.device) -> torch.device:
        """The device of this rank: ``cuda:<local_rank>`` for a CUDA run, else ``requested``."""
        if requested.type == "cuda" and self.active:
            return torch.device("cuda", self.local_rank)
        return requested

    def barrier(self) -> None:
        if self.active:
            dist.barrier()

    def average_gradients(self, params) -> None:
        """Average the gradients of ``params`` over the ranks (in place); a no-op with one process."""
        if not self.active:
            return
        grads = [p.grad for p in params if p.grad is not None]
        if not grads:
            return
        flat = torch.cat([g.reshape(-1) for g in grads])
        dist.all_reduce(flat)
        flat /= self.world
        k = 0
        for g in grads:
            n = g.numel()
            g.copy_(flat[k:k + n].view_as(g))
            k += n

    def close(self) -> None:
        """Leave the process group this context started (after every rank has arrived here)."""
        if self.started and dist.is_initialized():
            try:
                dist.barrier()
            finally:
                dist.destroy_process_group()
            self.started = False


def dist_context(device_type: str = "cpu") -> DistContext:
    """The data-parallel context of this process, initialising the process group when ``torchrun``
    started it (``WORLD_SIZE`` > 1): backend ``nccl`` for CUDA runs, ``gloo`` otherwise.

    Raises:
        ConfigError: an inconsistent ``torchrun`` environment (a rank outside the world).
    """
    world = int(os.environ.get("WORLD_SIZE", "1") or 1)
    if world <= 1:
        return DistContext()
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", str(rank)))
    if not 0 <= rank < world:
        raise ConfigError(f"torchrun environment: RANK {rank} outside WORLD_SIZE {world}")
    started = False
    if not dist.is_initialized():
        backend = "nccl" if device_type == "cuda" and torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend=backend)
        started = True
    return DistContext(rank, world, local, started)


@contextlib.contextmanager
def run_settings(threads: int):
    """Use ``threads`` torch threads and a private copy of the global RNG inside the block; restore both
    after, so that training leaves the caller's process as it found it."""
    before = torch.get_num_threads()
    torch.set_num_threads(max(1, int(threads)))
    try:
        with torch.random.fork_rng(devices=[]):
            yield
    finally:
        torch.set_num_threads(before)


def per_rank_threads(usable: int, ctx: DistContext) -> int:
    """Torch threads for one rank: the usable cores shared evenly among the ranks on this machine."""
    local_world = int(os.environ.get("LOCAL_WORLD_SIZE", str(ctx.world))) if ctx.active else 1
    return max(1, usable // max(1, local_world))
