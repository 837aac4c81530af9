"""Whole experiments behind ``scapo bench``: regenerate the paper's tables with our methods.

Datasets and predictions are cached under a work folder (generation resumes, predictions are
recomputed when missing), and the tables go to the output folder with provenance.
"""

from __future__ import annotations

from pathlib import Path

from scapo.data import generate, load, make_config
from scapo.eval import Predictions, evaluate
from scapo.eval.tables import write_table1
from scapo.files import check_output_dir
from scapo.methods import METHODS, describe, run_method, train_method
from scapo.provenance import provenance


def dataset_dir(work: Path, category: str, instances: int, views: int, seed: int) -> Path:
    return Path(work) / f"{category}_i{instances}_v{views}_s{seed}"


def run_table1(methods, categories, instances: int, views: int, seed: int = 0, work_dir: Path = Path("bench_work"),
               out_dir: Path | None = None, workers: int = 1, cache_dir: Path | None = None, name: str = "table1",
               preset: str = "cpu", seeds=(0,), protocol: str = "scapo"):
    """Generate one dataset per category (``seed`` draws the data), run every method, evaluate under
    ``protocol``, and write Table 1. Trained methods are trained once per training seed in ``seeds``;
    their cells are mean +- std over those seeds. Resumable per cell: a finished run or predictions file
    of the same dataset is reused."""
    from scapo.errors import ConfigError
    from scapo.eval.protocols import get_protocol

    for m in methods:  # unknown names and presets are refused before any dataset is rendered
        entry = METHODS.get(m)
        if entry.trained and preset not in entry.presets:
            raise ConfigError(f"method {m!r} has no preset {preset!r}; its presets: {', '.join(entry.presets)}")
    for cat in categories:
        make_config(cat, instances, views, seed)
    protocol = get_protocol(protocol).name
    seeds = [int(s) for s in seeds] or [0]
    if out_dir is not None:
        check_output_dir(out_dir, "table folder")
    check_output_dir(work_dir, "bench work folder")
    results, hashes = [], {}
    for cat in categories:
        data = dataset_dir(work_dir, cat, instances, views, seed)
        generate(make_config(cat, instances, views, seed), data, workers=workers, cache_dir=cache_dir)
        hashes[cat] = load(data, "test").dataset_hash[:16]
        for m in methods:
            for s in (seeds if METHODS.get(m).trained else [None]):
                pred_path = data / (f"predictions_{m}.npz" if s is None else f"predictions_{m}_{preset}_s{s}.npz")
                preds = None
                if pred_path.is_file():
                    preds = Predictions.load(pred_path)
                    if preds.dataset_hash != load(data, "test").dataset_hash:
                        preds = None
                if preds is None:
                    opts = {}
                    if METHODS.get(m).trained:
                        opts = {"run": data / f"run_{m}_{preset}_s{s}"}
                        train_method(m, data, opts["run"], preset, progress=True, seed=s)
                    preds = run_method(m, data, pred_path, progress=True, **opts)
                res = evaluate(data, preds, protocol=protocol)
                print(f"{m:8s} {cat:11s} seed {s} " + " ".join(f"{k}={res.summary[k]:.3f}"
                                                               for k in ("S", "D", "C", "R", "t")))
                results.append(res)
    if out_dir is not None:
        prov = provenance(preset=f"data: instances={instances} views={views} seed={seed}; scapo: {preset}",
                          datasets=hashes, methods=",".join(methods), protocol=protocol, training_seeds=seeds)
        for p in write_table1(results, out_dir, prov, name=name, describe=describe):
            print(f"wrote {p}")
    return results


#: Criteria of :func:`choose_on_val`: name -> function of an evaluation summary (lower is better).
CRITERIA = {
    "D+R": lambda s: s["D"] + s["R"],
    "R": lambda s: s["R"],
    "D": lambda s: s["D"],
    "R_median": lambda s: s["R_median"],
    "-S": lambda s: -s["S"],
}


def choose_on_val(data: str | Path, candidates: dict[str, list[Path]], criterion: str = "D+R",
                  protocol: str = "scapo") -> tuple[str, list[dict]]:
    """Choose among ``candidates`` (value -> predictions files, one per training seed) on the val split.

    Each candidate's score is the criterion (:data:`CRITERIA`, lower is better) of its val summary,
    averaged over its files (seeds). The test split is never read.

    Returns:
        (the chosen value, one row per candidate: value, score, per-seed scores and val means).

    Raises:
        ConfigError: an unknown criterion or no candidates. DatasetError: no val split.
    """
    from scapo.errors import ConfigError

    if criterion not in CRITERIA:
        raise ConfigError(f"unknown criterion {criterion!r}; known: {', '.join(CRITERIA)}")
    if not candidates:
        raise ConfigError("no candidates to choose from")
    rows = []
    for value, files in candidates.items():
        if not files:
            raise ConfigError(f"candidate {value!r} has no predictions files")
        summaries = [evaluate(data, f, protocol=protocol, split="val").summary for f in files]
        scores = [float(CRITERIA[criterion](s)) for s in summaries]
        rows.append({"value": value, "score": sum(scores) / len(scores), "scores": scores,
                     "files": [str(f) for f in files],
                     **{f"val_{k}": sum(s[k] for s in summaries) / len(summaries) for k in ("S", "D", "R", "C", "t")}})
    best = min(rows, key=lambda r: r["score"])
    return best["value"], rows
