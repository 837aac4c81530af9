"""The ``scapo`` console script: one entry point, one sub-command per job.

Run ``scapo <command> --help`` for the options of each command. Each group of commands is a module of this
package with its parsers beside its handlers (:mod:`scapo.cli.data`, :mod:`scapo.cli.train_predict`,
:mod:`scapo.cli.view`, :mod:`scapo.cli.bench`); this one builds the parser and turns errors into one line. Heavy
modules are imported inside the commands so that ``scapo --help`` is instant.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

from scapo.cli import bench, data, train_predict, view
from scapo.errors import ScapoError
from scapo.provenance import git_commit


# ------------------------------------------------------------------------------ parser
def _every_command_takes_no_progress(parser: argparse.ArgumentParser) -> None:
    """Give every (sub)command a ``--no-progress`` flag (commands without bars of their own accept it too)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                if any(isinstance(a, argparse._SubParsersAction) for a in sp._actions):
                    _every_command_takes_no_progress(sp)
                elif not any("--no-progress" in a.option_strings for a in sp._actions):
                    sp.add_argument("--no-progress", action="store_true", help="no progress bars")


@contextlib.contextmanager
def _scapo_warnings(command: str):
    """Inside the block, a :class:`~scapo.errors.ScapoWarning` prints as one line ``scapo COMMAND: warning: ...``
    (each message once); other warnings as Python shows them."""
    import warnings

    from scapo.errors import ScapoWarning

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ScapoWarning):
            print(f"scapo {command}: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("default", ScapoWarning)
        warnings.showwarning = show
        yield


def _version_text() -> str:
    from scapo.provenance import git_commit, package_version

    return f"scapo {package_version()} ({git_commit()})"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scapo", description="Articulated-object data generation, baselines and "
                                "benchmark (SCAPO, CVPR 2026).")
    p.add_argument("--version", action="version", version=_version_text())
    sub = p.add_subparsers(dest="command", required=True)
    for group in (data, train_predict, view, bench):  # each group's parsers beside its handlers
        group.add_parsers(sub)
    _every_command_takes_no_progress(p)
    return p


#: What an interrupted command leaves behind, by command.
_INTERRUPTED = {
    "generate": "finished shards are kept; rerun the same command to resume",
    "train": "the last finished epoch is kept in the run's checkpoint.pt; rerun the same command to resume",
    "bench": "finished datasets, runs and predictions in the work folder are kept; rerun to resume",
    "demo": "what finished is kept in the output folder; rerun the same command to resume",
    "assets": "finished instances are kept in the asset cache",
}


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns its exit status (0 ok, 2 a user error, 3 a bug, 130 interrupted).

    Every error raised on purpose (:class:`~scapo.errors.ScapoError`) is printed as one line
    ``scapo <command>: error: <what is wrong and what to do>``; an operating-system error (disk full,
    permission) as one line naming the file. Anything else is a bug in scapo: one line says so
    (``SCAPO_DEBUG=1`` shows the traceback).
    """
    args = build_parser().parse_args(argv)
    git_commit()  # the commit of the code this process loads, recorded in provenance however long it runs
    env_before = os.environ.get("TQDM_DISABLE")
    if getattr(args, "no_progress", False):  # every tqdm bar, ours and the libraries', stays off
        os.environ["TQDM_DISABLE"] = "1"
    try:
        with _scapo_warnings(args.command):
            return int(args.func(args) or 0)
    except ScapoError as e:
        print(f"scapo {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        left = _INTERRUPTED.get(args.command, "nothing was written")
        print(f"scapo {args.command}: interrupted ({left})", file=sys.stderr)
        return 130
    except OSError as e:
        if os.environ.get("SCAPO_DEBUG"):
            raise
        where = f": {e.filename}" if e.filename else ""
        print(f"scapo {args.command}: error: {e.strerror or e}{where}", file=sys.stderr)
        return 2
    except Exception as e:  # noqa: BLE001 - the last line of defence: a bug, said as such, not a traceback
        if os.environ.get("SCAPO_DEBUG"):
            raise
        print(f"scapo {args.command}: internal error ({type(e).__name__}: {e}); this is a bug in scapo: please report "
              "it with the command line (SCAPO_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 3
    finally:
        if env_before is None:
            os.environ.pop("TQDM_DISABLE", None)
        else:
            os.environ["TQDM_DISABLE"] = env_before


def console(argv: list[str] | None = None) -> int:
    """The ``scapo`` console script (and ``python -m scapo.cli``): :func:`main`, then Ctrl-C ignored while the
    interpreter shuts down. The command's work is done and written by then; a Ctrl-C that came while torch's exit
    hooks ran once printed their traceback."""
    import signal

    code = main(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(console())
