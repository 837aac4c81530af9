"""Small text-table writers (Markdown, LaTeX) shared by result writers."""

from __future__ import annotations

from collections.abc import Sequence


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]], align: Sequence[str] | None = None) -> str:
    """GitHub-flavoured Markdown table; ``align`` per column is "l", "r" or "c"."""
    align = align or ["l"] * len(header)
    marks = {"l": ":--", "r": "--:", "c": ":-:"}
    lines = ["| " + " | ".join(str(h) for h in header) + " |",
             "|" + "|".join(marks[a] for a in align) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def latex_escape(text: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#")):
        text = text.replace(a, b)
    return text


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
    from pathlib import Path

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
