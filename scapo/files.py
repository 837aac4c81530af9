"""Safe file handling shared by every command: atomic writes, checked outputs, folder locks, JSON reads.

Every file scapo writes goes through :func:`atomic_write_bytes` (a hidden temporary file
``.<name>.tmp-<pid>`` in the same folder, fsync, rename), so a file that exists is complete and an
interrupted or killed process never leaves a half-written result under its real name. Temporary
files of processes that no longer run are removed by :func:`clean_stale_temps`.

Outputs are checked *before* long work starts (:func:`check_output_file`, :func:`check_output_dir`):
an output path that is an existing folder (or file), lies below a file, or cannot be written raises
:class:`~scapo.errors.OutputError` naming the path and the reason, so no computation is lost to an
unwritable output.

A folder that one process writes into (a dataset being generated, a training run) is held with
:class:`FolderLock` (``fcntl.flock`` on ``<folder>/.scapo.lock``; the kernel releases it when the
process dies, even by ``kill -9``); a second process is refused with a message naming the first.
"""

from __future__ import annotations

import errno
import fcntl
import io
import json
import os
import re
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from scapo.errors import OutputError

#: Name pattern of scapo's temporary files and folders: ``.<name>.tmp-<pid>[-<suffix>]``.
_TEMP_RE = re.compile(r"^\..+\.tmp-(\d+)(-.*)?$")


def temp_path(path: Path) -> Path:
    """The temporary sibling ``.<name>.tmp-<pid>`` used to write ``path`` atomically."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a hidden temporary file in the same folder, fsync and rename.

    Raises:
        OutputError: the folder cannot be written (names the path and the system's reason); the
            temporary file is removed and an existing ``path`` is left as it was.
    """
    path = Path(path)
    tmp = temp_path(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise OutputError(f"cannot write {path}: {e.strerror or e}") from e


def atomic_write_text(path: str | Path, text: str) -> None:
    """:func:`atomic_write_bytes` of UTF-8 ``text``."""
    atomic_write_bytes(path, text.encode("utf-8"))


def rewrite_block(path: str | Path, start: str, end: str, body: str, what: str, check: bool = False) -> bool:
    """Rewrite (or with ``check`` only compare) the text between the markers ``start`` and ``end`` of the file
    ``path`` with ``body`` (a generated block: the README's headline, the usage page's option reference), atomically;
    returns whether it was current.

    Raises:
        ValueError: the file has no block (its two markers, ``start`` then ``end``; ``what`` names the block)."""
    path = Path(path)
    text = path.read_text()
    if start not in text or end not in text.split(start, 1)[1]:
        raise ValueError(f"{path} has no {what} block: put the lines {start!r} and {end!r} where it goes")
    head, rest = text.split(start, 1)
    old, tail = rest.split(end, 1)
    if old == body:
        return True
    if not check:
        atomic_write_text(path, head + start + body + end + tail)
    return False


def write_json(path: str | Path, obj) -> None:
    """Write ``obj`` as indented, key-sorted JSON, atomically."""
    atomic_write_text(path, json.dumps(obj, indent=1, sort_keys=True, default=str) + "\n")


def atomic_savefig(fig, path: str | Path, **kwargs) -> Path:
    """Save a matplotlib figure atomically (rendered to memory first); returns ``path``. A PNG is written with a
    palette of 256 colours (:func:`palette_png`: about a third of the bytes, the plots' colours kept); its text fields
    (``metadata=``) are kept."""
    path = Path(path)
    buf = io.BytesIO()
    fmt = path.suffix.lstrip(".") or "png"
    fig.savefig(buf, format=fmt, **kwargs)
    data = buf.getvalue()
    atomic_write_bytes(path, palette_png(data) if fmt == "png" else data)
    return path


def palette_png(data: bytes) -> bytes:
    """The PNG ``data`` as a PNG of at most 256 colours (Pillow's median cut, over a white background where it is
    transparent), with its text fields and resolution kept; ``data`` itself where that is not smaller. A figure of
    point clouds and curves keeps its colours (the shaded axis panes included) at about a third of the bytes."""
    from PIL import Image, PngImagePlugin

    with Image.open(io.BytesIO(data)) as im:
        im.load()
        info = PngImagePlugin.PngInfo()
        for k, v in getattr(im, "text", {}).items():
            info.add_text(k, v)
        rgb = im.convert("RGB")
        if im.mode in ("RGBA", "LA") or (im.mode == "P" and "transparency" in im.info):
            rgb = Image.new("RGB", im.size, (255, 255, 255))
            rgb.paste(im.convert("RGBA"), mask=im.convert("RGBA").split()[3])
        out = io.BytesIO()
        kw = {"dpi": im.info["dpi"]} if "dpi" in im.info else {}
        rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(out, "PNG", optimize=True, pnginfo=info, **kw)
    return out.getvalue() if out.tell() < len(data) else data


def read_json(path: str | Path, what: str, error: type[Exception], hint: str = "") -> dict:
    """Read a JSON object from ``path``.

    Args:
        what: how to name the file in messages (e.g. "the dataset card").
        error: the :class:`~scapo.errors.ScapoError` subclass to raise.
        hint: what the user should do, appended to the message.

    Raises:
        error: the file is missing, unreadable, truncated, not JSON, or not a JSON object.
    """
    path = Path(path)
    tail = f"; {hint}" if hint else ""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist{tail}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise error(f"{what} {path} cannot be read ({e}){tail}") from e
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as e:
        state = "is empty" if not text.strip() else f"is not valid JSON (truncated or edited? {e})"
        raise error(f"{what} {path} {state}{tail}") from None
    if not isinstance(obj, dict):
        raise error(f"{what} {path} holds a JSON {type(obj).__name__}, not an object{tail}")
    return obj


def _probe_writable(folder: Path, what: str) -> None:
    probe = folder / f".scapo-write-test.tmp-{os.getpid()}"
    try:
        with open(probe, "wb") as f:
            f.write(b"ok")
    except OSError as e:
        raise OutputError(f"{what} {folder} is not writable ({e.strerror or e}); choose a writable location") from e
    finally:  # also after a full disk, which creates the file and fails the write: never left to count as the user's
        try:
            probe.unlink()
        except OSError:
            pass


def _make_dir(folder: Path, what: str) -> None:
    for parent in [folder, *folder.parents]:
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"{what} {folder} cannot be created: {parent} is a file; choose another path")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{what} {folder} cannot be created ({e.strerror or e}); choose a writable location") \
            from e


#: Files that make a folder a scapo dataset's (its card, journal or config) or a training run's (identity,
#: checkpoint): every other output is refused there, so that it can never replace or mix with them.
DATASET_FILES = ("card.json", "shards.jsonl", "manifest.parquet")
RUN_FOLDER_FILES = ("run.json", "checkpoint.pt")


def owner_of(folder: str | Path) -> str | None:
    """``"dataset"`` or ``"run"`` when ``folder`` is a scapo dataset or training-run folder, else None."""
    folder = Path(folder)
    if any((folder / f).is_file() for f in DATASET_FILES) or ((folder / "config.json").is_file()
                                                              and (folder / "shards").is_dir()):
        return "dataset"
    if any((folder / f).is_file() for f in RUN_FOLDER_FILES):
        return "run"
    return None


def check_output_dir(folder: str | Path, what: str = "output folder", own: str | None = None) -> Path:
    """Create ``folder`` if needed and check that files can be written in it; returns it.

    ``own``: the kind of folder the caller writes (``"dataset"`` for ``scapo generate``, ``"run"`` for training); any
    other caller is refused a dataset or run folder (:func:`owner_of`), whose files its outputs could replace.

    Raises:
        OutputError: ``folder`` (or a parent) is a file, cannot be created, or is not writable
            (read-only mount, permissions); ``folder`` is a dataset or run folder another writer owns.
    """
    folder = Path(folder)
    owner = owner_of(folder) if folder.is_dir() else None
    if owner is not None and owner != own:
        raise OutputError(f"{what} {folder} is a scapo {owner} folder; its files are not for other outputs (they "
                          f"could be replaced): give another folder")
    _make_dir(folder, what)
    _probe_writable(folder, what)
    return folder


#: the image formats a figure may be written as (matplotlib's, without its many others)
FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def check_output_file(path: str | Path, what: str = "output file", example: str = "out.npz",
                      replaceable: Callable[[Path], bool] | None = None) -> Path:
    """Check that ``path`` can be written (creating its folder); returns it. Nothing is written to it.

    A figure (``example`` ends in ``.png``) must end in an image format's suffix. ``replaceable(path)``: whether an
    existing file at ``path`` may be replaced (e.g. it is an earlier result of the same kind); without it any may.

    Raises:
        OutputError: ``path`` is an existing folder, a figure without an image suffix, an existing file that is not
            replaceable (e.g. a dataset's ``card.json``), its folder is a file or cannot be created, or the folder
            is not writable.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{what} {path} is an existing folder; give a file name (e.g. {path / example})")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"folder of the {what} {path} cannot be created: {parent} is a file; choose another path")
    suffix = Path(example).suffix
    if suffix in FIGURE_SUFFIXES and path.suffix.lower() not in FIGURE_SUFFIXES:
        raise OutputError(f"{what} {path} must end in {', '.join(FIGURE_SUFFIXES)} (an image format; e.g. "
                          f"{path.with_suffix(suffix).name})")
    if replaceable is not None and path.is_file() and not replaceable(path):
        raise OutputError(f"{what} {path} exists and is not a {what} (it would be lost); give another file name")
    _make_dir(path.parent, f"folder of the {what}")
    _probe_writable(path.parent, f"folder of the {what}")
    return path


def pid_alive(pid: int) -> bool:
    """Whether a process with ``pid`` runs on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_temps(folder: str | Path, only: str | None = None, any_pid: bool = False) -> list[Path]:
    """Remove scapo temporary files and folders (``.<name>.tmp-<pid>...``) left in ``folder`` by
    processes that no longer run (e.g. after ``kill -9``); returns what was removed.

    Args:
        only: remove only temporaries of this target file name (``.<only>.tmp-<pid>``).
        any_pid: also remove those of running processes (the caller holds the folder's lock).
    """
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    for entry in folder.iterdir():
        m = _TEMP_RE.match(entry.name)
        if not m or (only is not None and not entry.name.startswith(f".{only}.tmp-")):
            continue
        pid = int(m.group(1))
        if pid == os.getpid() or (not any_pid and pid_alive(pid)):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry)
        except OSError:
            pass
    return removed


class FolderLock:
    """Exclusive lock on a folder a process writes into (``<folder>/.scapo.lock``, ``fcntl.flock``).

    Use as a context manager. The kernel releases the lock when the holder exits or is killed.

    Raises:
        OutputError: from ``__enter__`` when another process holds the lock (names it and what to
            do) or the lock file cannot be created.
    """

    NAME = ".scapo.lock"

    def __init__(self, folder: str | Path, command: str):
        self.folder = Path(folder)
        self.command = command
        self._fd: int | None = None

    def __enter__(self) -> FolderLock:
        path = self.folder / self.NAME
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise OutputError(f"cannot create the lock file {path} ({e.strerror or e}); choose a writable "
                              "location") from e
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise OutputError(f"{self.folder} is in use by {holder}; wait for it to finish (or stop it) "
                                  f"before running '{self.command}' on the same folder, or choose another "
                                  "folder") from None
            raise OutputError(f"cannot lock {path} ({e.strerror or e})") from e
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"scapo {self.command} (pid {os.getpid()}, since {time.strftime('%H:%M:%S')})".encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


#: the only globals a data file's pickle may name: numpy arrays, dtypes and scalars (numpy 1.x and 2.x names)
SAFE_PICKLE_GLOBALS = frozenset({
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
})


def load_npz_object(path: str | Path, key: str = "arr_0"):
    """The object stored under ``key`` of an ``.npz`` written with ``np.savez(path, obj)`` (a pickled object array,
    e.g. OP-Align's frame dicts), unpickled without running code from the file: only numpy arrays, dtypes and
    scalars and Python containers and literals may be built (:data:`SAFE_PICKLE_GLOBALS`).

    Raises:
        ValueError: the file is not such an npz, or its pickle names anything else (a payload is never run).
    """
    import pickle
    import zipfile

    import numpy as np

    class _Restricted(pickle.Unpickler):
        def find_class(self, module, name):
            if (module, name) in SAFE_PICKLE_GLOBALS:
                return getattr(__import__(module, fromlist=[name]), name)
            raise ValueError(f"it names {module}.{name}, which a data file may not (only numpy arrays are read)")

    with zipfile.ZipFile(path) as z, z.open(f"{key}.npy") as f:
        version = np.lib.format.read_magic(f)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"npy format version {version} is not read here")
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read(f)
        if dtype.hasobject:
            arr = _Restricted(f).load()
        else:
            arr = np.frombuffer(f.read(), dtype=dtype).reshape(shape, order="F" if fortran else "C")
    return arr.item() if isinstance(arr, np.ndarray) and arr.shape == () else arr


#: The key (JSON) or PNG text field that marks a file as an output scapo wrote, with its kind as the value
#: (``"scapo preview"``, ``"scapo assets symmetry"``): a file is replaced only when it carries the same mark.
OUTPUT_MARK = "scapo_output"


def output_mark(kind: str) -> dict:
    """The mark of an output of ``kind`` (e.g. ``"scapo preview"``): ``{OUTPUT_MARK: kind}``, a JSON object's key or
    (``metadata=`` of :func:`atomic_savefig`) a PNG's text field."""
    return {OUTPUT_MARK: kind}


def is_output(path: str | Path, kind: str) -> bool:
    """Whether the file ``path`` is an output of ``kind`` that scapo wrote (its mark: :func:`output_mark`)."""
    import json

    path = Path(path)
    try:
        if path.suffix.lower() == ".json":
            return json.loads(path.read_text()).get(OUTPUT_MARK) == kind
        if path.suffix.lower() == ".png":
            from PIL import Image

            with Image.open(path) as im:
                return im.text.get(OUTPUT_MARK) == kind
    except Exception:  # noqa: BLE001 - unreadable, not JSON or not a PNG: not ours
        return False
    return False


def check_output_owned_file(path: str | Path, kind: str, what: str, example: str) -> Path:
    """:func:`check_output_file` for an output that replaces only its own kind (:func:`is_output`) and is never written
    into a dataset or run folder (:func:`owner_of`).

    Raises:
        OutputError: as :func:`check_output_file`; the folder is a dataset or run folder; ``path`` exists and is not
            such an output (naming it)."""
    path = Path(path)
    owner = owner_of(path.parent) if path.parent.is_dir() else None
    if owner is not None:
        raise OutputError(f"{what} {path} would be written into a scapo {owner} folder; give a path outside it")
    return check_output_file(path, what, example, replaceable=lambda p: is_output(p, kind))


def check_name(name: str, flag: str = "--name") -> str:
    """``name`` as a file-name stem of an output (``table1``, ``laptop_twin``): no folder separator, no ``..``, not
    hidden, not empty, so that it stays inside its ``--out`` folder.

    Raises:
        ConfigError: naming the flag and what a good name looks like."""
    from scapo.errors import ConfigError

    text = str(name)
    if (not text or text != text.strip() or "/" in text or "\\" in text or text.startswith(".")
            or any(ord(c) < 32 for c in text)):
        raise ConfigError(f"{flag} {name!r} must be a plain file name (letters, digits, '_', '-'; no folders, not "
                          "starting with '.'), e.g. table1")
    return text


def check_own_files(paths, marker: Path, what: str, hint: str) -> None:
    """Refuse to overwrite files scapo did not write: any of ``paths`` or ``marker`` that exists while ``marker`` (the
    JSON that scapo writes with them) is not a scapo table (its mark, :func:`output_mark` ``"scapo table"``, or, as
    tables were written before the mark existed, its ``provenance`` beside its ``results``: a dataset card or a run's
    identity has neither pair).

    Raises:
        OutputError: naming the foreign file and ``hint`` (e.g. another --out or --name)."""
    import json

    try:
        d = json.loads(Path(marker).read_text())
        ours = isinstance(d, dict) and (d.get(OUTPUT_MARK) == "scapo table" or ("provenance" in d and "results" in d))
    except (OSError, ValueError, TypeError):
        ours = False
    foreign = [str(p) for p in (*paths, marker) if Path(p).exists() and not ours]
    if foreign:
        raise OutputError(f"{foreign[0]} exists and was not written by scapo (no {Path(marker).name} of a scapo table "
                          f"beside it); {hint}")
