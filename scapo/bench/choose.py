"""Choices on the validation split (``scapo bench choose``): an option value, averaged over seeds."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from scapo.eval import evaluate

#: Criteria of :func:`choose_on_val`: name -> function of an evaluation summary (lower is better).
CRITERIA = {
    "D+R": lambda s: s["D"] + s["R"],
    "R": lambda s: s["R"],
    "D": lambda s: s["D"],
    "R_median": lambda s: s["R_median"],
    "-S": lambda s: -s["S"],
}


def choose_on_val(data: str | Path | Sequence[str | Path], candidates: dict[str, list],
                  criterion: str = "D+R", protocol: str = "scapo") -> tuple[str, list[dict]]:
    """Choose among ``candidates`` (value -> predictions files, one per training seed) on the val split.

    Each candidate's score is the criterion (:data:`CRITERIA`, lower is better) of its val summary,
    averaged over its files (seeds). With several datasets (``data`` a list, e.g. the categories of a
    table, so that one preset setting is chosen for all of them), ``candidates`` maps each value to one
    list of files per dataset, in ``data``'s order, and the score is the mean over datasets of the
    per-dataset (seed-averaged) scores, each dataset weighing the same. The test split is never read.

    Returns:
        (the chosen value, one row per candidate: value, score, per-seed scores and val means; with
        several datasets also ``per_dataset``, the same per dataset).

    Raises:
        ConfigError: an unknown criterion, no candidates, a candidate without files (for some dataset),
            or a candidate whose file lists do not match the datasets. DatasetError: no val split.
    """
    from scapo.errors import ConfigError

    if criterion not in CRITERIA:
        raise ConfigError(f"unknown criterion {criterion!r}; known: {', '.join(CRITERIA)}")
    if not candidates:
        raise ConfigError("no candidates to choose from")
    several = not isinstance(data, (str, Path))
    datasets = [Path(d) for d in data] if several else [Path(data)]
    if not datasets:
        raise ConfigError("no dataset to choose on")
    rows = []
    for value, files in candidates.items():
        per_data = list(files) if several else [files]
        if len(per_data) != len(datasets):
            raise ConfigError(f"candidate {value!r} has file lists for {len(per_data)} datasets, expected "
                              f"{len(datasets)} (one per dataset)")
        parts = []
        for d, fs in zip(datasets, per_data):
            if not fs:
                raise ConfigError(f"candidate {value!r} has no predictions files for {d}")
            summaries = [evaluate(d, f, protocol=protocol, split="val").summary for f in fs]
            scores = [float(CRITERIA[criterion](s)) for s in summaries]
            parts.append({"dataset": str(d), "score": sum(scores) / len(scores), "scores": scores,
                          "files": [str(f) for f in fs],
                          **{f"val_{k}": sum(s[k] for s in summaries) / len(summaries)
                             for k in ("S", "D", "R", "C", "t")}})
        if not several:
            row = {k: v for k, v in parts[0].items() if k != "dataset"}
        else:
            row = {"score": sum(p["score"] for p in parts) / len(parts),
                   "scores": [x for p in parts for x in p["scores"]], "files": [f for p in parts for f in p["files"]],
                   **{k: sum(p[k] for p in parts) / len(parts) for k in parts[0] if k.startswith("val_")},
                   "per_dataset": parts}
        rows.append({"value": value, **row})
    best = min(rows, key=lambda r: r["score"])
    return best["value"], rows
