"""Timing a network the same way for every method (``scapo bench perf --what model``): medians over repeated
calls after a warm-up, on partial-view-like synthetic clouds (speed does not depend on what the points show)."""

from __future__ import annotations

import functools
import time

import numpy as np


def box_clouds(batch: int, n: int, seed: int = 0) -> np.ndarray:
    """Partial-view-like test clouds: points on three faces of random boxes, 1-2 m from the camera."""
    rng = np.random.default_rng(seed)
    out = np.empty((batch, n, 3), dtype=np.float32)
    for b in range(batch):
        ext = rng.uniform(0.1, 0.4, 3)
        face = rng.integers(0, 3, n)
        p = rng.uniform(-0.5, 0.5, (n, 3)) * ext
        p[np.arange(n), face] = -0.5 * ext[face]
        out[b] = p + [0.0, 0.0, rng.uniform(1.0, 2.0)]
    return out


def median_seconds(fn, iters: int, cuda: bool, warm_up: bool = True) -> float:
    """Median wall time (s) of ``iters`` calls of ``fn()`` after one warm-up call (CUDA synchronised); without
    ``warm_up``, of ``max(iters, 1)`` calls, the first included (e.g. a compiling first call)."""
    import torch

    times = []
    start = 1 if warm_up else 0
    for i in range(max(iters, 1 - start) + start):
        if cuda:
            torch.cuda.synchronize()
        t = time.perf_counter()
        fn()
        if cuda:
            torch.cuda.synchronize()
        if i >= start:
            times.append(time.perf_counter() - t)
    return float(np.median(times))


def step_seconds(step, net, compile_: bool, iters: int, cuda: bool) -> dict:
    """The median seconds of one training ``step()`` of ``net`` (``{"step_s"}``); with ``compile_``, of the step
    with ``net``'s parts compiled (:func:`scapo.engine.loop.compile_network`), beside the eager step's measured first
    in the same run (``eager_s``) and the first compiled step's seconds beyond a compiled step's (``compile_s``, a
    one-time cost); ``net`` is left eager."""
    from scapo.engine.loop import compile_network, uncompile_network

    if not compile_:
        return {"step_s": median_seconds(step, iters, cuda)}
    eager = median_seconds(step, iters, cuda)
    parts = compile_network(net)
    try:
        first = median_seconds(step, 0, cuda, warm_up=False)
        sec = median_seconds(step, iters, cuda)
    finally:
        uncompile_network(parts)
    return {"step_s": sec, "eager_s": eager, "compile_s": max(first - sec, 0.0)}


def inference_speed(fn, device, num_points: int, iters: int) -> dict:
    """``fn(points (B, N, 3))`` timed on box clouds on ``device``: ms per cloud and clouds/s at batch 1,
    clouds/s at batch 32 (medians over ``iters`` calls after a warm-up)."""
    import torch

    out = {}
    for batch in (1, 32):
        pts = torch.from_numpy(box_clouds(batch, num_points, seed=1)).to(device)
        med = median_seconds(functools.partial(fn, pts), iters, device.type == "cuda")
        if batch == 1:
            out["infer_ms_per_cloud_b1"] = round(1000 * med, 2)
            out["infer_clouds_per_s_b1"] = round(1 / med, 2)
        else:
            out["infer_clouds_per_s_b32"] = round(batch / med, 2)
    return out
