"""Choices on the validation split (``scapo bench choose``): an option value, averaged over seeds."""

from __future__ import annotations

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
