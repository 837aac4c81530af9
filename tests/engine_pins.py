"""The engine's pinned losses (``tests/data/engine_pins.json``): the verdict that test_engine.py applies, and the
command that pins a new CPU.

A pin set is the ``log.csv`` rows of every trained method's ``test`` preset (and ``test/sj``) trained on
``tests/data/pin_laptop`` with two torch threads, on one CPU. Float rounding differs between CPU kinds (another
vector width or FMA use in torch's kernels and in numpy), and a rounding difference can flip a discrete choice
(SCAPO's stage-2 initialisation picks a part order), so one CPU's pins do not hold on another. The verdict:

- bit-level (rtol 1e-6) against some pinned CPU's rows: passes; this is the regression check on every pinned CPU;
- the running CPU is pinned (its :func:`cpu_id` is recorded with a set) but no set is reproduced: fails;
- an unpinned CPU: each run's first stage against some pinned CPU to rtol :data:`FIRST_STAGE_RTOL` (no discrete
  choice is made before stage 2; measured here: at most 1.0e-4 relative between two CPU kinds), and every later
  row's (stage, epoch, step) and finiteness. It passes with a warning that says how to pin the CPU.

Pin a CPU (from a clean checkout, so that ``pinned_at`` names a commit; it refuses a CPU whose first stages are
outside the tolerance, which would be a change of the losses, not of the rounding)::

    .venv/bin/python tests/engine_pins.py --add "AMD EPYC 7B13 (Milan), 2 cores"

Re-pin a run whose losses changed by design (its other CPUs' rows are dropped: they cannot be trained here, and
such a CPU then passes by the unpinned-CPU tolerance)::

    .venv/bin/python tests/engine_pins.py --add "this CPU in words" --repin op-align:test --why "the change, commit"
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"
PINS_FILE = DATA / "engine_pins.json"
BIT_RTOL = 1e-6
FIRST_STAGE_RTOL = 1e-3


def cpu_id() -> str:
    """The running CPU as ``vendor family F model M stepping S; avx512f yes|no``, from ``/proc/cpuinfo`` (what
    decides the kernels torch and numpy dispatch to); ``unknown`` where that file is not readable."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown"
    info: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            break  # the first processor's block
        k, _, v = line.partition(":")
        info[k.strip()] = v.strip()
    flags = set(info.get("flags", "").split())
    return (f"{info.get('vendor_id', '?')} family {info.get('cpu family', '?')} model {info.get('model', '?')} "
            f"stepping {info.get('stepping', '?')}; avx512f {'yes' if 'avx512f' in flags else 'no'}")


def load_pins(path: Path = PINS_FILE) -> dict:
    return json.loads(Path(path).read_text())


def pin_sets(pins: dict) -> list[dict]:
    """Every CPU's set as ``{"cpu": description, "cpu_id": id or None, "runs": {key: {"header", "rows"}}}``."""
    first = {"cpu": pins.get("cpu", "first"), "cpu_id": pins.get("cpu_id"), "runs": pins["runs"]}
    return [first] + [{"cpu": o["cpu"], "cpu_id": o.get("cpu_id"), "runs": o["runs"]}
                      for o in pins.get("other_cpus", [])]


def pinned_keys(pins: dict) -> list[str]:
    return sorted(set().union(*(s["runs"] for s in pin_sets(pins))))


def _floats(values: list[str]) -> np.ndarray:
    return np.array([float(v) if v else np.nan for v in values])


def mismatch(rows: list[list[str]], pin: dict, rtol: float = BIT_RTOL, first_stage_only: bool = False) -> str:
    """'' when ``rows`` (a log.csv with its header) equal the pinned rows, else what differs first.

    Every row's (stage, epoch, step) must be the pinned one. With ``first_stage_only`` the losses of the rows of
    the first row's stage are compared to ``rtol`` and those of later stages must only be finite (where the pin's
    are); otherwise every row's losses are compared to ``rtol`` (atol 1e-9)."""
    if rows[0] != pin["header"] or len(rows) - 1 != len(pin["rows"]):
        return f"header or row count differs ({len(rows) - 1} rows, pinned {len(pin['rows'])})"
    first = pin["rows"][0][0] if pin["rows"] else None
    for got, want in zip(rows[1:], pin["rows"]):
        if got[:3] != want[:3]:  # stage, epoch, step
            return f"row {want[:3]} is {got[:3]}"
        g, w = _floats(got[3:]), _floats(want[3:])
        if first_stage_only and want[0] != first:
            bad = [rows[0][3 + i] for i in range(len(w)) if math.isfinite(w[i]) and not math.isfinite(g[i])]
            if bad:
                return f"row {want[:3]}: {', '.join(bad)} not finite"
            continue
        try:
            np.testing.assert_allclose(g, w, rtol=rtol, atol=1e-9, err_msg=f"row {want[:3]}")
        except AssertionError as e:
            return str(e)
    return ""


def verdict(rows: list[list[str]], key: str, pins: dict, cpu: str) -> tuple[bool, str]:
    """Whether a run's ``log.csv`` rows pass the pins of ``key`` on the CPU ``cpu`` (:func:`cpu_id`), and a
    message: empty on a bit-level match, a warning on a pass by the unpinned-CPU tolerance, else what failed."""
    sets = [s for s in pin_sets(pins) if key in s["runs"]]
    exact = {s["cpu"]: mismatch(rows, s["runs"][key]) for s in sets}
    if any(not w for w in exact.values()):
        return True, ""
    report = "\n".join(f"- {cpu_name}: {w}" for cpu_name, w in exact.items())
    mine = [s["cpu"] for s in sets if s["cpu_id"] == cpu]
    if mine:
        return False, f"this CPU ({cpu}) is pinned as {mine[0]!r} but no pinned CPU's losses are reproduced:\n" + report
    loose = {s["cpu"]: mismatch(rows, s["runs"][key], FIRST_STAGE_RTOL, first_stage_only=True) for s in sets}
    near = [c for c, w in loose.items() if not w]
    if near:
        return True, (f"{key}: this CPU ({cpu}) is not pinned; its first stage is within {FIRST_STAGE_RTOL:g} of "
                      f"{near[0]!r} and its later rows are complete and finite (pin it: python tests/engine_pins.py "
                      f"--add DESCRIPTION)")
    return False, (f"{key}: no pinned CPU's losses are reproduced, not even the first stage to {FIRST_STAGE_RTOL:g} "
                   "(a change of the losses, not of the rounding):\n" + "\n".join(
                       f"- {c}: {w}" for c, w in loose.items()))


def train_log(key: str, out: Path) -> list[list[str]]:
    """Train ``key`` (``method:preset``) on ``tests/data/pin_laptop`` into ``out`` with two torch threads (as every
    pin was taken) and return its ``log.csv`` rows, header first."""
    import os
    import warnings

    import torch

    from scapo.methods import train_method

    method, preset = key.split(":")
    threads, omp = torch.get_num_threads(), os.environ.get("OMP_NUM_THREADS")
    torch.set_num_threads(2)
    os.environ["OMP_NUM_THREADS"] = "2"  # training's own thread count (conftest gives xdist workers one)
    try:
        with warnings.catch_warnings():  # pin_laptop is small by design (4 training instances): say it once here
            warnings.filterwarnings("ignore", message=".*holds only 4 instance")
            train_method(method, DATA / "pin_laptop", Path(out), preset, progress=False)
    finally:
        torch.set_num_threads(threads)
        if omp is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = omp
    with open(Path(out) / "log.csv", newline="") as f:
        return list(csv.reader(f))


def _commit() -> str:
    root = Path(__file__).resolve().parent.parent
    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    if git("status", "--porcelain", "--untracked-files=no"):
        raise SystemExit("scapo: the checkout has uncommitted changes; pin from a clean checkout so that the pins "
                         "name the commit that made them")
    return git("rev-parse", "--short", "HEAD")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Pin the engine's test-preset losses of this CPU "
                                 "(tests/data/engine_pins.json).")
    ap.add_argument("--add", metavar="DESCRIPTION", required=True, help="the CPU in words (model, cores)")
    ap.add_argument("--repin", metavar="KEY", action="append", default=[],
                    help="a run whose losses changed by design (e.g. op-align:test): its pins of every CPU are "
                         "replaced by this CPU's; repeatable; needs --why")
    ap.add_argument("--why", default="", help="with --repin: the change, with its commit")
    a = ap.parse_args(argv)
    pins, cpu = load_pins(), cpu_id()
    if a.repin:
        return _repin(pins, cpu, a.add, a.repin, a.why)
    if any(s["cpu_id"] == cpu for s in pin_sets(pins)):
        print(f"scapo: this CPU ({cpu}) is pinned already; remove its set from {PINS_FILE} to pin it again",
              file=sys.stderr)
        return 2
    commit = _commit()
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key in pinned_keys(pins):
            rows = train_log(key, Path(tmp) / key.replace(":", "_").replace("/", "_"))
            ok, msg = verdict(rows, key, pins, cpu)
            if not ok:
                print(f"scapo: not pinned: {msg}", file=sys.stderr)
                return 1
            runs[key] = {"header": rows[0], "rows": rows[1:]}
            print(f"{key}: {len(rows) - 1} rows, " + (f"first stage within {FIRST_STAGE_RTOL:g} of a pinned CPU's"
                                                       if msg else "as a pinned CPU's"))
    pins.setdefault("other_cpus", []).append({
        "cpu": a.add, "cpu_id": cpu,
        "pinned_at": f"{commit}, today's engine on this CPU (its rounding reproduces no earlier CPU's pins; the "
                     f"first stages agree with them to {FIRST_STAGE_RTOL:g})",
        "runs": runs})
    text = json.dumps(pins, indent=1) + "\n"
    tmp_path = PINS_FILE.with_suffix(".json.tmp")
    tmp_path.write_text(text)
    tmp_path.replace(PINS_FILE)
    print(f"pinned {len(runs)} runs of this CPU in {PINS_FILE}")
    return 0


def _repin(pins: dict, cpu: str, description: str, keys: list[str], why: str) -> int:
    """Replace the pins of ``keys`` (losses changed by design) on every CPU by this CPU's: the other CPUs' rows of
    those keys are dropped (they cannot be trained here; such a CPU then passes by the unpinned-CPU tolerance)."""
    unknown = [k for k in keys if k not in pinned_keys(pins)]
    if unknown or not why:
        print(f"scapo: --repin needs pinned keys ({', '.join(pinned_keys(pins))}) and --why; got {keys}, {why!r}",
              file=sys.stderr)
        return 2
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for key in keys:
            rows = train_log(key, Path(tmp) / key.replace(":", "_").replace("/", "_"))
            runs[key] = {"header": rows[0], "rows": rows[1:], "repinned": why}
    for s in [pins, *pins.get("other_cpus", [])]:
        for key in keys:
            s["runs"].pop(key, None)
    mine = next((o for o in pins.setdefault("other_cpus", []) if o.get("cpu_id") == cpu), None)
    if mine is None:
        mine = {"cpu": description, "cpu_id": cpu, "pinned_at": f"{_commit()}: the repinned runs only", "runs": {}}
        pins["other_cpus"].append(mine)
    mine["runs"].update(runs)
    tmp_path = PINS_FILE.with_suffix(".json.tmp")
    tmp_path.write_text(json.dumps(pins, indent=1) + "\n")
    tmp_path.replace(PINS_FILE)
    print(f"repinned {', '.join(keys)} on this CPU ({cpu}) in {PINS_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
