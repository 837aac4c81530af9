"""The run folder every trained method writes (``scapo train --method M --out RUN``), in one place.

::

    RUN/run.json        the run's identity: method, preset fields, dataset hash, category structure
    RUN/checkpoint.pt   model, optimiser, schedule, next (stage, epoch), done, identity, seconds, method extras;
                        written atomically after every epoch
    RUN/log.csv         one row per optimiser step: stage, epoch, step, lr, total, then one column per loss term
    RUN/losses.png      the loss curves (:func:`plot_losses`)
    RUN/timing.json     training seconds over every session that trained the run, device, world size, steps

A run folder belongs to one identity. :class:`RunFolder` refuses, before anything is written, a path that is
a file, a non-empty folder holding no run, and a folder whose ``run.json`` or checkpoint has another identity
(naming the preset fields that differ), so that a result is never mixed from two configurations.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from collections.abc import Callable
from pathlib import Path

import torch

from scapo.data.config import dict_diff
from scapo.errors import ConfigError, TrainingError
from scapo.files import FolderLock, atomic_savefig, atomic_write_bytes, atomic_write_text, write_json

#: runs written before the identity named its method were SCAPO's (``scapo train`` without ``--method``)
UNNAMED_METHOD = "scapo"


def resolve_device(name: str) -> torch.device:
    """``"auto"`` (CUDA when available, else CPU), ``"cpu"``, ``"cuda"`` or ``"cuda:N"`` -> a usable device.

    Raises:
        ConfigError: an unknown device name, or a CUDA device this machine or torch build does not have.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown device {name!r}; use cpu, cuda, cuda:N or auto") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            why = "this torch build has no CUDA" if torch.version.cuda is None else "no CUDA GPU is visible"
            raise ConfigError(f"device {name!r} requested, but {why} (torch {torch.__version__}); use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device {name!r} requested, but only {torch.cuda.device_count()} CUDA device(s) exist")
    elif dev.type != "cpu":
        raise ConfigError(f"device {name!r} is not supported; use cpu, cuda, cuda:N or auto")
    return dev


def read_run_json(run: str | Path) -> dict | None:
    """``run.json`` of a run folder, or None when it has none (or an unreadable or non-object one)."""
    try:
        d = json.loads((Path(run) / "run.json").read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _plain(identity: dict) -> dict:
    """``identity`` as it reads back from JSON (tuples become lists, other objects strings)."""
    return json.loads(json.dumps(identity, default=str))


#: The record of a run that failed before its first checkpoint (:meth:`RunFolder.mark_failed`).
FAILED = "failed.json"


class RunFolder:
    """One run folder and the identity of the run it holds.

    Args:
        path: the folder (created on the first write).
        identity: what makes the run this run (method, preset fields, dataset hash, category structure).
        normalise: ``normalise(identity) -> dict``, the part of an identity that decides whether a checkpoint
            fits (a method leaves out inference-only fields and fields added since older runs were trained, at
            those runs' value, so older runs keep their identity). Default: the identity as it is.

    Raises (from the methods below):
        ConfigError: the path is a file, or a non-empty folder holding no run. TrainingError: a checkpoint
            or ``run.json`` of another identity, or an unreadable checkpoint.
    """

    CHECKPOINT = "checkpoint.pt"

    def __init__(self, path: str | Path, identity: dict, normalise: Callable[[dict], dict] | None = None):
        self.path = Path(path)
        self.identity = _plain(identity)
        self.normalise = normalise or (lambda d: d)

    # ------------------------------------------------------------------ identity
    def hash(self, identity: dict | None = None) -> str:
        """SHA-256 of the normalised ``identity`` (default: this run's), sorted-key JSON."""
        d = self.identity if identity is None else _plain(identity)
        return hashlib.sha256(json.dumps(self.normalise(d), sort_keys=True, default=str).encode()).hexdigest()

    @property
    def checkpoint(self) -> Path:
        return self.path / self.CHECKPOINT

    @property
    def log(self) -> Path:
        return self.path / "log.csv"

    def is_current(self) -> bool:
        """Whether the folder's ``run.json`` has this identity (False without a readable one)."""
        old = read_run_json(self.path)
        return old is not None and self.hash(old) == self.hash()

    def _refuse(self, where: Path, old: dict, started: bool) -> None:
        if self.hash(old) == self.hash():
            return
        new = self.identity
        oldp = old.get("preset") if isinstance(old.get("preset"), dict) else {}
        changed = dict_diff(self.normalise(_plain(old)).get("preset", {}), self.normalise(new).get("preset", {}))
        what = f" (preset fields that differ: {', '.join(changed)})" if changed else ""
        raise TrainingError(
            f"{where} holds a {old.get('method', UNNAMED_METHOD)!r} run {'started' if started else 'trained'} with "
            f"preset {oldp.get('name')!r} on the {old.get('category')!r} dataset "
            f"{str(old.get('dataset_hash'))[:12]}..., "
            f"not a {new.get('method', UNNAMED_METHOD)!r} run with preset {new['preset'].get('name')!r} on "
            f"{new.get('category')!r} dataset {str(new.get('dataset_hash'))[:12]}...{what}; use another --out "
            f"folder, or remove it to start over: rm -r {self.path}")

    # ------------------------------------------------------------------ checks (before anything is written)
    def check_target(self) -> None:
        """Refuse a path that is a file, or a non-empty folder that holds no scapo run.

        Raises:
            ConfigError: naming the path and what it holds.
        """
        if self.path.exists() and not self.path.is_dir():
            raise ConfigError(f"--out {self.path} is an existing file; give a folder for the run")
        if self.path.is_dir() and not (self.checkpoint.exists() or (self.path / "run.json").exists()):
            foreign = sorted(p.name for p in self.path.iterdir() if p.name != FolderLock.NAME)
            if foreign:
                raise ConfigError(f"--out {self.path} is a non-empty folder without a scapo run (holds "
                                  f"{', '.join(foreign[:4])}{', ...' if len(foreign) > 4 else ''}); give a new or "
                                  "empty folder")

    def load_checkpoint(self, device: torch.device | str = "cpu") -> dict | None:
        """The checkpoint's state (tensors on ``device``), or None when there is none; before any checkpoint,
        a ``run.json`` of another identity is refused too.

        Raises:
            TrainingError: unreadable checkpoint (says to delete it), or another identity (names both).
        """
        if not self.checkpoint.is_file():
            old = read_run_json(self.path)
            if old is not None and (self.path / FAILED).is_file():
                # a run that failed before its first checkpoint (a NaN, a full disk) left only its identity and
                # the log of its failure: the corrected run starts over here (nothing trained is lost)
                for name in (FAILED, "log.csv", "losses.png"):
                    (self.path / name).unlink(missing_ok=True)
                return None
            if old is not None:
                self._refuse(self.path, old, started=True)
            return None
        state = read_checkpoint(self.checkpoint, device)
        self._refuse(self.checkpoint, state.get("identity", {}), started=False)
        return state

    # ------------------------------------------------------------------ writes
    def mark_failed(self, error: Exception) -> None:
        """Record that this run failed before its first checkpoint (``failed.json``: the error), so that a corrected
        run of another identity may start over in the folder; an interrupted run (no such record) stays protected."""
        try:
            write_json(self.path / FAILED, {"error": f"{type(error).__name__}: {error}", "identity": self.identity})
        except OSError:  # the disk that failed the run may refuse this too; the run then stays protected
            pass

    def write_identity(self) -> None:
        write_json(self.path / "run.json", self.identity)

    def save(self, state: dict) -> None:
        """Write ``state`` (plus the identity and its hash) atomically as the checkpoint."""
        buf = io.BytesIO()
        torch.save({**state, "identity": self.identity, "identity_hash": self.hash()}, buf)
        atomic_write_bytes(self.checkpoint, buf.getvalue())

    def write_timing(self, seconds: float, device, world_size: int, steps: int | None = None,
                     breakdown: dict | None = None) -> None:
        """``timing.json``: training seconds (every session), device, world size and the optimiser steps of the
        whole schedule (per rank; None when unknown); with ``breakdown``, where the last session's time went
        (``stages``: per stage index its ``steps`` and the seconds inside them ``step_s``, its ``epochs`` and the
        per-epoch checkpoint, loss plot and extras ``epoch_s``, its ``start_s`` (a stage's start, e.g. SCAPO's
        stage-2 initialisation); ``final_s``: the extras after the last epoch; ``other_s``: the rest, so the parts sum
        to ``session_s``, the session's training seconds), for ``scapo bench perf --what train --data``."""
        atomic_write_text(self.path / "timing.json", json.dumps({"seconds": round(seconds, 1), "device": str(device),
                                                                 "world_size": world_size, "steps": steps,
                                                                 **(breakdown or {})}) + "\n")


def load_error_text(e: Exception) -> str:
    """``Type: reason`` of a failed checkpoint load, on one line (torch's unpickling errors run over many lines;
    a file that holds more than tensors and plain data is refused, never run)."""
    if "Weights only load failed" in str(e):
        return f"{type(e).__name__}: it holds more than tensors and plain data; code is never run from a file"
    return f"{type(e).__name__}: {(str(e).strip().splitlines() or [''])[0]}"


def read_checkpoint(path: str | Path, device: torch.device | str = "cpu") -> dict:
    """A checkpoint file's state dict.

    Raises:
        TrainingError: the file cannot be read as a checkpoint (names it and says to delete it).
    """
    try:
        state = torch.load(path, map_location=device, weights_only=True)  # tensors and plain data: no code runs
    except Exception as e:  # noqa: BLE001 - torch raises many kinds for a broken file
        raise TrainingError(f"checkpoint {path} cannot be read ({load_error_text(e)}); delete it to start over") from e
    if not isinstance(state, dict):
        raise TrainingError(f"checkpoint {path} cannot be read (not a scapo checkpoint); delete it to start over")
    return state


def truncate_log(log_csv: Path, stage: int, epoch: int) -> None:
    """Keep only the rows of ``log.csv`` from before ``(stage, epoch)``, where a resumed run restarts
    (an interrupted epoch's rows are written again); a torn last line is dropped."""
    if not log_csv.is_file():
        return
    with open(log_csv, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        log_csv.unlink()
        return
    header, kept = rows[0], []
    try:
        si, ei = header.index("stage"), header.index("epoch")
    except ValueError:
        log_csv.unlink()
        return
    for r in rows[1:]:
        try:
            if len(r) == len(header) and (int(r[si]), int(r[ei])) < (stage, epoch):
                kept.append(r)
        except ValueError:
            continue
    if not kept:
        log_csv.unlink()
        return
    buf = io.StringIO()
    csv.writer(buf).writerows([header, *kept])
    atomic_write_text(log_csv, buf.getvalue())


def plot_losses(log_csv: Path, png: Path) -> None:
    """Loss curves (:func:`loss_figure`) of ``log.csv`` written to ``png``; nothing for a missing or empty log
    (a run that failed at its first step)."""
    import matplotlib.pyplot as plt
    import pandas as pd

    if not log_csv.is_file() or log_csv.stat().st_size == 0:
        return
    df = pd.read_csv(log_csv)
    if df.empty:
        return
    fig = loss_figure(df)
    atomic_savefig(fig, png, dpi=90)
    plt.close(fig)


def loss_figure(df):
    """One panel per stage of a ``log.csv`` table: each loss term (a column after ``lr``) as the moving mean of 5
    steps of its absolute value, log scale, in a colour and line style of its own (``total`` thicker), with
    labelled axes and a legend of the terms drawn. Returns the matplotlib figure.

    Margins are fixed and the log axis's labels are plain numbers on decades with unlabelled minor ticks at 2 and
    5: ``tight_layout``, mathtext labels and nine minor ticks per decade took three quarters of the figure's
    1.3 s of CPU (it is drawn during training: :data:`scapo.engine.loop.PLOT_EVERY_S`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    stages = sorted(df["stage"].unique())
    fig, axes = plt.subplots(1, len(stages), figsize=(6 * len(stages), 4.5), squeeze=False)
    colors = plt.get_cmap("tab10").colors
    styles = ("-", "--", ":", "-.")
    for ax, st in zip(axes[0], stages):
        d = df[df["stage"] == st].reset_index(drop=True)
        k = 0
        for col in d.columns[4:]:
            v = d[col]
            if v.notna().any() and (v.abs() > 0).any():  # a distinct colour and line style per term
                ax.plot(v.abs().rolling(5, min_periods=1).mean(), label=col, color=colors[k % len(colors)],
                        ls=styles[(k // len(colors)) % len(styles)], lw=1.6 if col == "total" else 1.0)
                k += 1
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_title(f"stage {st}")
        ax.set_xlabel("optimiser step in the stage")
        ax.set_ylabel("loss term (unweighted; moving mean of 5 steps)")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=2)
    width = 6 * len(stages)  # inches: room for the y label and tick labels at the left, the last x label at the right
    fig.subplots_adjust(left=0.85 / width, right=1 - 0.3 / width, bottom=0.11, top=0.93, wspace=0.3)
    return fig
