"""The compute ledger: every core-second a trained method spends before it can predict, by phase.

The tables give every trained method the same budget of charged compute. A training run's ledger
(``timing.json``'s ``ledger``, kept in every checkpoint so that a resumed run adds to it) holds, per phase, the
process's CPU seconds (``cpu_s``: every thread of the process and its finished child processes, :func:`cpu_seconds`,
so one busy core for one second is one core-second) and the wall seconds (``wall_s``), each times the number of
processes training the run; the charged seconds are the CPU seconds on a CPU device, the wall seconds of the
accelerator otherwise (``charged_s``; the budget is then minutes
of that device). The phases:

============================ ===================================================================================
phase                        what
============================ ===================================================================================
``setup``                    loading the training clouds and building the network (every session of the run)
``stage<k>/start``           a stage's one-time start (SCAPO's template split fit and pseudo-labelling)
``stage<k>/steps``           the optimiser steps (loss, backward, Adam)
``stage<k>/epochs``          each epoch's checkpoint, loss plot and checkpoint extras
``final``                    the work after the last epoch (e.g. EAP-style's joint estimation over the training
                             split)
``other``                    the rest of the session (optimiser set-up between stages, closing writers)
============================ ===================================================================================

A cell of a table (:func:`scapo.bench.ladder`, :mod:`scapo.bench.experiments`) plans its steps from the charged
rates measured on the same data (:func:`scapo.bench.perf.training_budget`: the budget less the one-time phases)
and is refused by :func:`check_budget` when its ledger exceeds :data:`OVER_BUDGET` times the budget.

A core-second is a second of one core of the machine's kind of CPU (:func:`scapo.provenance.cpu_kind`, in every
record's provenance and speed file), and a step's CPU time also moves with what else runs on the machine (10-20 %
measured with more busy processes than cores): speeds are measured on the kind that computes the cells with nothing
else busy (:data:`scapo.bench.ladder.MAX_WALL_PER_CPU`), and a table's trained cells share one kind
(:func:`scapo.bench.ladder.check_one_commit`, :func:`scapo.bench.ladder.check_reuse`).
"""

from __future__ import annotations

import time
from contextlib import contextmanager

from scapo.errors import BudgetError

#: A cell whose charged compute exceeds this multiple of its budget is refused (:func:`check_budget`).
OVER_BUDGET = 1.10


def cpu_seconds() -> float:
    """CPU seconds of this process and of its finished child processes (user and system): what a phase charges on a
    CPU. The children count because work a method hands to a subprocess is its work too: ``torch.compile`` runs the C++
    compiler for its kernels as child processes (:func:`scapo.engine.loop.compile_network` keeps inductor's own worker
    pool off, so that every child is one that finishes and is counted)."""
    import resource

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


class Ledger:
    """Charged compute of one training run by phase (see the module docstring).

    Args:
        accelerator: charge wall seconds (a CUDA device) instead of the process's CPU seconds.
        before: an earlier session's :meth:`to_dict` (from the checkpoint): its phases are added to.
        world: processes training the run (``torchrun``): the ledger is kept by rank 0, and every rank does the same
            work, so each phase is charged ``world`` times what rank 0 measures.
    """

    def __init__(self, accelerator: bool = False, before: dict | None = None, world: int = 1):
        self.accelerator = bool(accelerator)
        self.world = max(int(world), 1)
        self.phases: dict[str, dict[str, float]] = {}
        for name, p in ((before or {}).get("phases") or {}).items():
            self.phases[str(name)] = {"cpu_s": float(p.get("cpu_s", 0.0)), "wall_s": float(p.get("wall_s", 0.0))}

    def add(self, name: str, cpu_s: float, wall_s: float) -> None:
        """Add ``cpu_s`` CPU seconds and ``wall_s`` wall seconds of this process (times the world size) to phase
        ``name``."""
        p = self.phases.setdefault(name, {"cpu_s": 0.0, "wall_s": 0.0})
        p["cpu_s"] += max(float(cpu_s), 0.0) * self.world
        p["wall_s"] += max(float(wall_s), 0.0) * self.world

    @contextmanager
    def phase(self, name: str):
        """Charge what the ``with`` block costs to phase ``name``."""
        c, w = cpu_seconds(), time.perf_counter()
        try:
            yield
        finally:
            self.add(name, cpu_seconds() - c, time.perf_counter() - w)

    def charged(self, name: str) -> float:
        """Charged seconds of phase ``name`` (0 for a phase not seen)."""
        p = self.phases.get(name)
        if p is None:
            return 0.0
        return p["wall_s"] if self.accelerator else p["cpu_s"]

    @property
    def total(self) -> float:
        """Charged seconds of every phase."""
        return sum(self.charged(k) for k in self.phases)

    def to_dict(self) -> dict:
        """``{"unit": "core-seconds" | "device-seconds", "charged_s", "phases": {name: {"cpu_s", "wall_s",
        "charged_s"}}}`` (JSON-ready; :class:`Ledger` reads it back as ``before``)."""
        return {"unit": "device-seconds" if self.accelerator else "core-seconds", "charged_s": round(self.total, 3),
                "phases": {k: {"cpu_s": round(v["cpu_s"], 3), "wall_s": round(v["wall_s"], 3),
                               "charged_s": round(self.charged(k), 3)} for k, v in self.phases.items()}}


def one_time_s(ledger: dict) -> float:
    """Charged seconds of a ledger dict's one-time phases: every phase but the steps and the per-epoch overhead
    (``setup``, ``stage<k>/start``, ``final``, ``other``)."""
    return sum(float(p["charged_s"]) for k, p in ledger.get("phases", {}).items()
               if not (k.endswith("/steps") or k.endswith("/epochs")))


def check_budget(ledger: dict, budget_s: float, plan: dict | None = None, what: str = "the cell") -> None:
    """Refuse a run whose charged compute exceeds :data:`OVER_BUDGET` times its budget, naming the phase that overran
    its plan the most (or, without a plan, the largest phase).

    Args:
        ledger: :meth:`Ledger.to_dict` of the run (``timing.json``'s ``ledger``).
        budget_s: the budget in charged seconds.
        plan: phase -> planned charged seconds (from the speed run on the same data), to name the overrun.
        what: the run's name in the message.

    Raises:
        BudgetError: over :data:`OVER_BUDGET` times the budget, with every phase's charged seconds.
    """
    total = float(ledger.get("charged_s", 0.0))
    if total <= OVER_BUDGET * budget_s:
        return
    phases = {k: float(p["charged_s"]) for k, p in ledger.get("phases", {}).items()}
    if plan:
        worst = max(phases, key=lambda k: phases[k] - float(plan.get(k, 0.0)))
        why = f"phase {worst!r} took {phases[worst]:.0f} s against {float(plan.get(worst, 0.0)):.0f} s planned"
    else:
        worst = max(phases, key=phases.get)
        why = f"the largest phase is {worst!r} ({phases[worst]:.0f} s)"
    listing = ", ".join(f"{k} {v:.0f} s" for k, v in sorted(phases.items(), key=lambda kv: -kv[1]))
    raise BudgetError(f"{what} charged {total:.0f} {ledger.get('unit', 'core-seconds')}, more than "
                      f"{100 * OVER_BUDGET:.0f} % of its budget of {budget_s:.0f}: {why} ({listing}); its run is kept. "
                      "Measure the training speed again on this machine as the cells run (delete the speed file), or "
                      "make that phase cheaper")
