"""Shared parts of the bench diagnoses (the scripts of ``bench/diagnostics/``; the package never loads them): the
command line of those that read predictions files (``hinge_diagnosis.py``, ``frame_consistency.py``: ``--data DATA
--pred LABEL=FILE ... [--split] --out NAME``) and of the ground-truth ones (``split_init_diagnosis.py``,
``axis_init_diagnosis.py``: ``--data DATA --out NAME [--clouds C] [--seed S]``), and their ``<out>.{md,json}`` writer
with provenance."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


def diagnosis_args(argv, description: str, options: Sequence[tuple[str, dict]] = ()):
    """Parse ``--data DATA --pred LABEL=FILE [--pred ...] [--split val|test] --out NAME``, and a diagnosis's own
    ``options``: ``(flag, argparse keyword arguments)`` pairs, e.g. ``("--rounds", {"type": int, "default": 3})``.

    Returns:
        ``(args, preds)`` with ``preds`` a list of ``(label, "=", path)``, or None after printing a ``scapo:`` message
        to stderr when the dataset folder or a predictions file is missing or a label is empty.
    """
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data", required=True)
    ap.add_argument("--pred", action="append", default=[], help="LABEL=PREDICTIONS.npz (scapo predict output)")
    ap.add_argument("--split", default="val", choices=("val", "test"))
    ap.add_argument("--out", required=True)
    for flag, kwargs in options:
        ap.add_argument(flag, **kwargs)
    a = ap.parse_args(argv)
    preds = [p.partition("=") for p in a.pred]
    bad = [f for f in [a.data] if not Path(f).is_dir()] + [f for _, _, f in preds if not Path(f).is_file()]
    if bad or not preds or any(not label for label, _, _ in preds):
        print(f"scapo: {bad[0] if bad else 'no --pred LABEL=FILE'}: give a dataset folder (--data) and predictions "
              "files (--pred LABEL=FILE.npz)", file=sys.stderr)
        return None
    return a, preds


def ground_truth_args(argv, description: str, clouds: int, min_clouds: int, why: str, clouds_help: str):
    """Parse a ground-truth diagnosis's ``--data DATA --out NAME [--clouds C] [--seed S]`` (no predictions files).

    Args:
        clouds: ``--clouds``'s default. min_clouds: the fewest it accepts, ``why`` saying why in the message.

    Returns:
        The parsed arguments, or None after printing a ``scapo:`` message to stderr when ``--clouds`` is under
        ``min_clouds`` or the dataset folder is missing.
    """
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--clouds", type=int, default=clouds, help=clouds_help)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if a.clouds < min_clouds:
        print(f"scapo: --clouds must be at least {min_clouds} ({why}), got {a.clouds}", file=sys.stderr)
        return None
    if not Path(a.data).is_dir():
        print(f"scapo: {a.data}: not a dataset folder; give one written by scapo generate (--data)", file=sys.stderr)
        return None
    return a


def score_files(args, preds, score) -> tuple[dict, dict] | None:
    """Score every predictions file of a diagnosis: ``score(Predictions) -> row`` (a JSON-serialisable dict) per
    ``(label, "=", path)`` of ``preds``, in order.

    Returns:
        ``(rows, card)``: label -> row, and the card of ``args.data``'s ``args.split``; or None after printing a
        ``scapo:`` message to stderr when a file, the dataset or a score fails with a :class:`~scapo.errors.ScapoError`
        (a corrupt file, predictions of another dataset, an empty split).
    """
    from scapo.data import load
    from scapo.errors import ScapoError
    from scapo.eval.predictions import Predictions

    try:
        rows = {label: score(Predictions.load(f)) for label, _, f in preds}
        return rows, load(args.data, args.split).card
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return None


def write_diagnosis(out, lines: Sequence[str], record: dict, predictions: dict[str, str]) -> list:
    """Write a bench diagnosis: ``<out>.md`` (``lines``) and ``<out>.json`` (``record`` with each predictions file's
    path and the first 16 hex digits of its sha256, and :func:`scapo.provenance.provenance`), each atomically; the
    folder is made if needed.

    Args:
        out: the output path without suffix. lines: the Markdown lines. record: JSON-serialisable fields.
        predictions: label -> predictions file path.

    Returns:
        The two paths written.

    Raises:
        OutputError: a file or the folder cannot be written (naming it).
    """
    import hashlib

    from scapo.errors import OutputError
    from scapo.files import atomic_write_text, write_json
    from scapo.provenance import provenance

    out = Path(out)
    sha = {label: hashlib.sha256(Path(fn).read_bytes()).hexdigest()[:16] for label, fn in predictions.items()}
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot make {out.parent} ({e.strerror}); choose a writable --out") from None
    md, js = out.with_suffix(".md"), out.with_suffix(".json")
    atomic_write_text(md, "\n".join(lines) + "\n")
    write_json(js, {**record, "predictions": {label: {"file": fn, "sha256_16": sha[label]}
                                              for label, fn in predictions.items()}, "provenance": provenance()})
    return [md, js]


def finish_diagnosis(args, preds, lines: list[str], rows: dict, card: dict, command: str) -> int:
    """End a diagnosis's ``main``: add the command line to ``lines``, write ``<args.out>.{md,json}``
    (:func:`write_diagnosis`; the record holds the command, dataset, its hash, the split and ``rows``) and print the
    Markdown. Returns the exit status: 0, or 2 after a ``scapo:`` message when the output cannot be written."""
    from scapo.errors import ScapoError

    lines = [*lines, "", f"Written by `{command}`."]
    try:
        write_diagnosis(args.out, lines, {"command": command, "dataset": str(args.data),
                                          "dataset_hash": card.get("dataset_hash"), "split": args.split,
                                          "rows": rows}, {label: fn for label, _, fn in preds})
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


def run_diagnosis(argv, doc: str, script: str, score, render, options: Sequence[tuple[str, dict]] = (),
                  check=None) -> int:
    """The ``main`` of a diagnosis over predictions files: parse its command line (:func:`diagnosis_args` with its own
    ``options``), ``check(args)`` (a message for a bad option, or None), score every file (``score(args, predictions)
    -> row``, :func:`score_files`), ``render(args, rows, card) -> Markdown lines`` and write them with the command line
    ``python bench/diagnostics/<script> ...`` (:func:`finish_diagnosis`). Returns the exit status: 0, or 2 after a
    ``scapo:`` message (missing inputs, a bad option, a file that cannot be scored or written)."""
    parsed = diagnosis_args(argv, doc.split("\n\n")[0], options)
    if parsed is None:
        return 2
    a, preds = parsed
    problem = check(a) if check is not None else None
    if problem:
        print(f"scapo: {problem}", file=sys.stderr)
        return 2
    scored = score_files(a, preds, lambda p: score(a, p))
    if scored is None:
        return 2
    rows, card = scored
    command = f"python bench/diagnostics/{script} " + " ".join(sys.argv[1:] if argv is None else argv)
    return finish_diagnosis(a, preds, render(a, rows, card), rows, card, command)
