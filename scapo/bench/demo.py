"""``scapo demo``: the whole pipeline on a few laptops, in minutes on 2 CPU cores.

Builds procedural laptop instances, renders a small train/test dataset with SAPIEN, runs the ICP
baseline, trains SCAPO briefly (the ``demo`` preset: a few minutes, far from converged), evaluates
both, prints Table 1 (with the paper's laptop numbers beside ours) and writes the table files and
figures (ground truth vs. predictions) under the output folder. Rerunning resumes what finished; when the output
folder was rendered from older assets (scapo was upgraded since), the demo moves that version's files into
``<out>/older-<time>/`` and starts afresh (:func:`retire_stale_outputs`).
"""

from __future__ import annotations

import time
from pathlib import Path


def _step(msg: str, t0: float | None = None) -> None:
    """Print a step's heading, with the seconds since ``t0`` (the demo's start) where given."""
    at = f"  [{time.perf_counter() - t0:.0f} s]" if t0 is not None else ""
    print(f"\n== {msg}{at}", flush=True)


#: What a demo run writes into its output folder (glob patterns), all of it derived from ``data``.
DEMO_OUTPUTS = ("data", "run_scapo_*", "predictions_*.npz", "table1_demo.*", "figure_demo_*.png")


def retire_stale_outputs(out: Path) -> Path | None:
    """Move the demo's outputs in ``out`` (:data:`DEMO_OUTPUTS`) into a new ``out/older-<YYYYmmdd-HHMMSS>/`` folder,
    so that a demo of newer assets starts afresh and nothing already written is lost; returns that folder, or None
    when ``out`` holds none of them.

    Raises:
        OutputError: a file cannot be moved (the message names it; what was moved stays in the new folder).
    """
    from scapo.errors import OutputError

    found = sorted({p for pat in DEMO_OUTPUTS for p in Path(out).glob(pat)})
    if not found:
        return None
    stamp = time.strftime("older-%Y%m%d-%H%M%S")
    dest, k = Path(out) / stamp, 1
    while dest.exists():  # a second upgrade within the same second
        dest, k = Path(out) / f"{stamp}-{k}", k + 1
    p = dest
    try:
        dest.mkdir()
        for p in found:
            p.rename(dest / p.name)
    except OSError as e:
        raise OutputError(f"cannot move {p} into {dest} ({e.strerror or e}); move or delete it and rerun") from e
    return dest


def run_demo(out: str | Path = "demo_out", instances: int = 24, views: int = 12, seed: int = 0,
             cache_dir: Path | None = None, category: str = "laptop", preset: str = "demo") -> dict:
    """Run the demo; returns a dict with the evaluation summary and the written paths."""
    from scapo.bench.viz import prediction_figure
    from scapo.data import generate, make_config
    from scapo.errors import StaleAssetsError
    from scapo.eval import evaluate
    from scapo.eval.tables import write_table1
    from scapo.files import check_output_dir
    from scapo.methods import METHODS, describe, run_method, train_method
    from scapo.provenance import provenance, render_device
    from scapo.sim.assets import build_category

    t0 = time.perf_counter()
    batch = METHODS.get("scapo").preset(preset).batch_size  # an unknown preset is refused before any work
    from scapo.data.generate import plan
    from scapo.errors import ConfigError

    train = sum(len(t.items) for t in plan(make_config(category, instances, views, seed, test_fraction=0.25))
                if t.split == "train")  # so are bad sizes
    if train < batch:  # the demo trains SCAPO: at least one batch of training clouds
        raise ConfigError(f"--instances {instances} --views {views} give {train} training clouds, fewer than the "
                          f"{preset} preset's batch of {batch}: give more --instances or --views (the default is 24 "
                          "x 12)")
    out = check_output_dir(out, "demo output folder")
    _step(f"render device: {render_device()}")
    _step(f"building {instances} procedural {category} instances (URDF + meshes)", t0)
    recs = build_category(category, instances, seed, cache_dir, progress=True)
    print(f"   e.g. {recs[0].urdf}")
    _step(f"rendering {instances} x {views} partial point clouds with ground truth (SAPIEN)", t0)
    cfg = make_config(category, instances, views, seed, test_fraction=0.25)
    data = out / "data"
    try:
        rep = generate(cfg, data, workers=1, progress=True, cache_dir=cache_dir)
    except StaleAssetsError:
        older = retire_stale_outputs(out)
        print(f"   {out} held a demo of older assets (scapo changed since): its files are now in {older}")
        rep = generate(cfg, data, workers=1, progress=True, cache_dir=cache_dir)
    print(f"   {rep.samples} samples in {data} ({sum(rep.rejections.values())} rejected views)")
    _step("ICP baseline: fit templates on the training split, register the test split", t0)
    pred_path = out / "predictions_icp.npz"
    preds = run_method("icp", data, pred_path, progress=True)
    print(f"   {preds.info['ms_per_cloud_test']:.0f} ms per test cloud -> {pred_path}")
    _step(f"SCAPO: self-supervised training on the training clouds only (preset '{preset}')", t0)
    run = out / f"run_scapo_{preset}"
    scapo_path = out / "predictions_scapo.npz"
    train_method("scapo", data, run, preset, progress=True)
    scapo = run_method("scapo", data, scapo_path, run=run, progress=True)
    ms = scapo.info["ms_per_cloud_test"]
    print(f"   {ms:.0f} ms per test cloud -> {scapo_path}; loss curves in {run}/losses.png")
    _step("evaluating (one evaluator for every method)", t0)
    results = [evaluate(data, preds), evaluate(data, scapo)]
    prov = provenance(preset=f"demo (SCAPO preset {preset})", protocol="scapo",
                      dataset_hash=results[0].info["dataset_hash"], dataset=str(data),
                      config=f"{category} instances={instances} views={views} seed={seed}")
    paths = write_table1(results, out, prov, name="table1_demo", describe=describe)
    print((out / "table1_demo.md").read_text())
    figs = [prediction_figure(data, preds, out / "figure_demo_icp.png", count=4, cache_dir=cache_dir),
            prediction_figure(data, scapo, out / "figure_demo_scapo.png", count=4, cache_dir=cache_dir)]
    _step(f"done in {time.perf_counter() - t0:.0f} s")
    for p in [*paths, *figs]:
        print(f"   {p}")
    return {"summary": {r.method: r.summary for r in results}, "paths": [*paths, *figs]}
