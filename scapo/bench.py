"""Whole experiments behind ``scapo bench``: regenerate the paper's tables with our methods.

Datasets and predictions are cached under a work folder (generation resumes, predictions are
recomputed when missing), and the tables go to the output folder with provenance.
"""

from __future__ import annotations

from pathlib import Path

from scapo.baselines import run_method
from scapo.data import generate, load, make_config
from scapo.eval import Predictions, evaluate
from scapo.eval.tables import write_table1
from scapo.files import check_output_dir
from scapo.models.train import train
from scapo.provenance import provenance


def dataset_dir(work: Path, category: str, instances: int, views: int, seed: int) -> Path:
    return Path(work) / f"{category}_i{instances}_v{views}_s{seed}"


def run_table1(methods, categories, instances: int, views: int, seed: int = 0, work_dir: Path = Path("bench_work"),
               out_dir: Path | None = None, workers: int = 1, cache_dir: Path | None = None, name: str = "table1",
               preset: str = "cpu"):
    """Generate one dataset per category, run every method, evaluate, and write Table 1."""
    from scapo.baselines import METHODS
    from scapo.models.presets import PRESETS

    for m in methods:  # unknown names are refused before any dataset is rendered
        METHODS.get(m)
    for cat in categories:
        make_config(cat, instances, views, seed)
    if "scapo" in methods:
        PRESETS.get(preset)
    if out_dir is not None:
        check_output_dir(out_dir, "table folder")
    check_output_dir(work_dir, "bench work folder")
    results, hashes = [], {}
    for cat in categories:
        data = dataset_dir(work_dir, cat, instances, views, seed)
        generate(make_config(cat, instances, views, seed), data, workers=workers, cache_dir=cache_dir)
        hashes[cat] = load(data, "test").dataset_hash[:16]
        for m in methods:
            pred_path = data / f"predictions_{m}.npz"
            preds = None
            if pred_path.is_file():
                preds = Predictions.load(pred_path)
                if preds.dataset_hash != load(data, "test").dataset_hash:
                    preds = None
            if preds is None:
                opts = {}
                if m == "scapo":
                    opts = {"run": data / f"run_scapo_{preset}"}
                    train(data, opts["run"], preset, progress=True)
                preds = run_method(m, data, pred_path, progress=True, **opts)
            res = evaluate(data, preds)
            print(f"{m:8s} {cat:11s} " + " ".join(f"{k}={res.summary[k]:.3f}" for k in ("S", "D", "C", "R", "t")))
            results.append(res)
    if out_dir is not None:
        prov = provenance(preset=f"data: instances={instances} views={views} seed={seed}; scapo: {preset}",
                          datasets=hashes, methods=",".join(methods))
        for p in write_table1(results, out_dir, prov, name=name):
            print(f"wrote {p}")
    return results
