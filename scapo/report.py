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


def progress_bar(*args, **kwargs):
    """A ``tqdm`` progress bar (same arguments) that draws only where its output is a terminal: ``disable=None``,
    tqdm's own check of the stream, unless the caller sets ``disable`` or ``TQDM_DISABLE`` is set (``--no-progress``);
    in a log file or a pipe it writes nothing, not a carriage-return line per update."""
    import os

    from tqdm import tqdm

    if "disable" not in kwargs:  # tqdm reads TQDM_DISABLE when it is imported, which may be before --no-progress
        kwargs["disable"] = True if os.environ.get("TQDM_DISABLE", "").lower() in ("1", "true") else None
    return tqdm(*args, **kwargs)
