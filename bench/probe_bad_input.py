"""Probe every ``scapo`` command with bad input, as a new user would, and count the outcomes.

Each case runs ``scapo ARGS`` in a fresh process (timeout 60 s) in a scratch folder and is classified:

- ``clear``: exit 2 with one ``scapo <command>: error: ...`` line and no traceback;
- ``ok``: exit 0 where the input is legitimate after all (the case says so);
- ``traceback``: a Python traceback or "internal error";
- ``hang``: still running at the timeout;
- ``silent``: exit 0 where an error was due;
- ``lost``: a file that existed before the command changed or vanished (checked for the cases that name one).

Usage: ``.venv/bin/python bench/probe_bad_input.py [--out results/probe_bad_input.md]``; it builds its own small
dataset and runs (a few minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def sh(args, cwd, timeout=60, env=None):
    t = time.time()
    try:
        r = subprocess.run([sys.executable, "-m", "scapo.cli", *map(str, args)], capture_output=True, text=True,
                           timeout=timeout, cwd=cwd, env=env)
        return r.returncode, r.stdout, r.stderr, time.time() - t
    except subprocess.TimeoutExpired:
        return None, "", "", time.time() - t


def digest(paths):
    out = {}
    for p in paths:
        p = Path(p)
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else []
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="scapo-probe-"))
    env = {**os.environ, "SCAPO_CACHE": str(tmp / "cache")}
    d = tmp / "data"
    assert sh(["generate", "--category", "laptop", "--instances", "6", "--views", "2", "--test-fraction", "0.34",
               "--val-fraction", "0", "--points", "256", "--out", d, "--no-progress"], tmp, 600, env)[0] == 0
    run = tmp / "run"
    assert sh(["train", "--method", "npcs", "--data", d, "--preset", "test", "--out", run, "--no-progress"], tmp, 600,
              env)[0] == 0
    pred = tmp / "p.npz"
    assert sh(["predict", "--run", run, "--data", d, "--out", pred], tmp, 600, env)[0] == 0
    (tmp / "notes").mkdir()
    (tmp / "notes" / "table1.md").write_text("mine")
    (tmp / "afile").write_text("x")
    (tmp / "bad.json").write_text("{")
    (tmp / "bad.toml").write_text("epochs = [")
    (tmp / "garbage.npz").write_bytes(b"garbage")
    (tmp / "empty").mkdir()
    (tmp / "dup.yaml").write_text("epochs: 3\nepochs: 4\n")
    (tmp / "twice.toml").write_text('"lr" = 0.1\n[losses]\nseg = 1\n"losses.seg" = 2\n')
    (tmp / "twice2.toml").write_text('"losses.seg" = 2\n[losses]\nseg = 1\n')
    (tmp / "notes.json").write_text('{"provenance": "mine"}')
    (tmp / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n not a preview")
    box = '<visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual>'
    links = f'<link name="a">{box}</link><link name="b">{box}</link>'
    joint = ('<joint name="{0}" type="{1}"><parent link="{2}"/><child link="{3}"/><axis xyz="0 0 1"/>'
             '<limit lower="{4}" upper="{5}"/></joint>')
    (tmp / "loop.urdf").write_text(f'<robot name="o">{links}{joint.format("j1", "revolute", "a", "b", 0, 1)}'
                                   f'{joint.format("j2", "revolute", "b", "a", 0, 1)}</robot>')
    (tmp / "slide.urdf").write_text(f'<robot name="o">{links}{joint.format("s", "prismatic", "a", "b", -1e9, 1e9)}'
                                    '</robot>')
    pred2 = tmp / "p2.npz"
    assert sh(["predict", "--run", run, "--data", d, "--out", pred2, "--option", "infer_points=128"], tmp, 600,
              env)[0] == 0
    import numpy as np

    np.savez(tmp / "extra.npz", **dict(np.load(pred, allow_pickle=False)), extra=np.zeros(3))
    d2 = tmp / "data2"
    assert sh(["generate", "--category", "laptop", "--instances", "4", "--views", "1", "--test-fraction", "0.5",
               "--val-fraction", "0", "--points", "256", "--seed", "3", "--out", d2, "--no-progress"], tmp, 600,
              env)[0] == 0
    scapo_base = ["train", "--data", d, "--preset", "test", "--no-progress"]
    cases = [  # (args, expected: "error" or "ok", files that must survive)
        (["list", "--bogus"], "error", []),
        (["assets", "build", "--category", "nope"], "error", []),
        (["assets", "build", "--category", "laptop", "--instances", "-1"], "error", []),
        (["assets", "check", tmp / "afile"], "error", []),
        (["assets", "check", tmp / "empty"], "error", []),
        (["generate", "--category", "laptop", "--instances", "0", "--views", "1", "--out", tmp / "g0"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "-3", "--out", tmp / "g1"], "error", []),
        (["generate", "--category", "laptop", "--instances", "1000000000000", "--views", "1", "--out", tmp / "g2"],
         "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--workers", "10000", "--out",
          tmp / "g3"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--seed", str(2 ** 66), "--out",
          tmp / "g4"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--out", tmp / "afile"], "error",
         [tmp / "afile"]),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--out", tmp / "notes"], "error",
         [tmp / "notes"]),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--seed", "9", "--out", d], "error",
         [d]),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--azimuth", "50,10", "--out",
          tmp / "g5"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--points", "5", "--out",
          tmp / "g6"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--num-envs", "4", "--out",
          tmp / "g7"], "error", []),
        (["generate", "--object", tmp / "nothing.urdf", "--views", "1", "--out", tmp / "g8"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--test-fraction", "1.5", "--out",
          tmp / "g9"], "error", []),
        (["train", "--data", tmp / "nowhere", "--out", tmp / "t0"], "error", []),
        (["train", "--data", d, "--preset", "nope", "--out", tmp / "t1"], "error", []),
        (["train", "--data", d, "--preset", "test", "--seed", str(2 ** 66), "--out", tmp / "t2"], "error", []),
        (["train", "--data", d, "--preset", "test", "--set", "nope=1", "--out", tmp / "t3"], "error", []),
        (["train", "--data", d, "--preset", "test", "--set", "stage1_epochs=x", "--out", tmp / "t4"], "error", []),
        (["train", "--data", d, "--preset", "test", "--config", tmp / "bad.toml", "--out", tmp / "t5"], "error", []),
        (["train", "--data", d, "--preset", "test", "--out", tmp / "afile"], "error", [tmp / "afile"]),
        (["train", "--data", d, "--preset", "test", "--out", run], "error", [run]),
        (["train", "--method", "icp", "--data", d, "--out", tmp / "t6"], "error", []),
        (["train", "--method", "npcs", "--data", d, "--preset", "test", "--device", "cuda:7", "--out", tmp / "t7"],
         "error", []),
        (["predict", "--run", run, "--data", d, "--out", d / "card.json"], "error", [d]),
        (["predict", "--run", run, "--data", d, "--out", run / "checkpoint.pt"], "error", [run]),
        (["predict", "--run", tmp / "empty", "--data", d, "--out", tmp / "q.npz"], "error", []),
        (["predict", "--method", "nope", "--data", d, "--out", tmp / "q.npz"], "error", []),
        (["predict", "--method", "icp", "--data", d, "--out", tmp / "q.npz", "--option", "bogus=1"], "error", []),
        (["predict", "--run", run, "--data", d, "--out", tmp / "q.npz", "--option", "batch_size=0"], "error", []),
        (["evaluate", "--data", d, "--pred", tmp / "garbage.npz"], "error", []),
        (["evaluate", "--data", d, "--pred", pred, "--pred", pred], "error", []),
        (["evaluate", "--data", d, "--pred", pred, "--protocol", "nope"], "error", []),
        (["evaluate", "--data", d, "--pred", pred, "--split", "train"], "error", []),
        (["evaluate", "--data", d, "--pred", pred, "--out", tmp / "notes"], "error", [tmp / "notes"]),
        (["evaluate", "--data", d, "--pred", pred, "--twin", "--twin-limit", "-3"], "error", []),
        (["export", "--data", d, "--pred", pred, "--sample", "999", "--out", tmp / "x0"], "error", []),
        (["export", "--data", d, "--pred", pred, "--sample", "0", "--out", tmp / "notes"], "error", [tmp / "notes"]),
        (["preview", "--data", d, "--out", tmp / "x.txt"], "error", []),
        (["preview", "--data", d, "--count", "0"], "error", []),
        (["preview", "--data", d, "--split", "nope"], "error", []),
        (["view", "--data", d, "--port", "-5"], "error", []),
        (["view", "--data", d, "--port", "70000"], "error", []),
        (["view", "--data", d, "--host", "999.1.1.1"], "error", []),
        (["convert", "opalign-real", "--root", tmp / "empty", "--category", "laptop", "--out", tmp / "c0"], "error",
         []),
        (["convert", "opalign-real", "--root", tmp / "empty", "--category", "laptop", "--seed", "-1", "--out",
          tmp / "c1"], "error", []),
        (["convert", "opalign-real", "--root", tmp / "empty", "--category", "laptop", "--image-size", "abc", "--out",
          tmp / "c2"], "error", []),
        (["bench", "table1", "--methods", "icp,icp", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "table1", "--instances", "0", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "table3", "--methods", "icp", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "table1", "--categories", "nope", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "perf", "--what", "model", "--method", "icp"], "error", []),
        (["bench", "perf", "--what", "model", "--method", "npcs", "--preset", "nope"], "error", []),
        (["demo", "--out", tmp / "afile"], "error", [tmp / "afile"]),
        # issue 54's cases: configuration reaching a preset
        *[([*scapo_base, "--set", kv, "--out", tmp / f"s{i}"], "error", []) for i, kv in enumerate((
            "lr_stage1=nan", "lr_stage1=-1", "lr_stage1=inf", "lr_stage2=inf", "weight_decay=-1", "gamma=0",
            "template_points=0", "encoder.k=0", "encoder.rot_channels=", "max_steps_per_epoch=-1",
            "train_points=100000", "losses.seg=nan", "anchors=Q", "grad_clip=0"))],
        ([*scapo_base, "--set", "stage1_epochs=0", "--set", "stage2_epochs=0", "--out", tmp / "s20"], "error", []),
        ([*scapo_base, "--seed", "1", "--set", "seed=5", "--out", tmp / "s21"], "error", []),
        (["train", "--method", "npcs", "--data", d, "--config", tmp / "dup.yaml", "--out", tmp / "s22"], "error", []),
        ([*scapo_base, "--config", tmp / "twice2.toml", "--out", tmp / "s23"], "error", []),
        (["train", "--method", "npcs", "--data", d, "--out", run, "--set", "lr=0.01"], "error", [run]),
        # outputs: names, dataset and run folders, files of other kinds
        (["evaluate", "--data", d, "--pred", pred, "--out", tmp / "o", "--name", "../escaped"], "error", []),
        (["evaluate", "--data", d, "--pred", pred, "--out", d, "--name", "card"], "error", [d]),
        (["evaluate", "--data", d, "--pred", pred, "--out", run, "--name", "run"], "error", [run]),
        (["assets", "symmetry", "--category", "laptop", "--instances", "1", "--views", "1", "--json", d / "card.json"],
         "error", [d]),
        (["assets", "symmetry", "--category", "laptop", "--instances", "1", "--views", "1", "--json",
          tmp / "notes.json"], "error", [tmp / "notes.json"]),
        (["preview", "--data", d, "--out", tmp / "photo.png"], "error", [tmp / "photo.png"]),
        (["export", "--data", d, "--pred", pred, "--sample", "0", "--out", run], "error", [run]),
        # statistics and lists
        (["evaluate", "--data", d, "--pred", pred, "--pred", pred2], "error", []),
        (["evaluate", "--data", d, "--pred", tmp / "extra.npz"], "error", []),
        (["bench", "table1", "--categories", "", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "table1", "--methods", ",", "--dry-run", "--work", tmp / "w"], "error", []),
        (["bench", "choose", "--data", d, "--candidate", f"1={pred}", "--candidate", f"1={pred2}"], "error", []),
        (["bench", "table1", "--seeds", "-1", "--categories", "laptop", "--work", tmp / "w2"], "error", []),
        (["bench", "table1", "--seeds", "-1", "--dry-run", "--work", tmp / "w2"], "error", []),
        (["bench", "table1", "--dry-run", "--work", tmp / "afile"], "error", [tmp / "afile"]),
        (["bench", "table1", "--dry-run", "--archive", tmp / "afile", "--work", tmp / "w"], "error", [tmp / "afile"]),
        (["bench", "compute", "--budgets", "5,5", "--work", tmp / "w3"], "error", []),
        (["bench", "compute", "--methods", "icp", "--work", tmp / "w3"], "error", []),
        (["bench", "ladder", "--rungs", "nope", "--work", tmp / "w3"], "error", []),
        # refusals before work
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--backend", "maniskill",
          "--num-envs", "4", "--out", tmp / "m0"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--num-envs", "0", "--out",
          tmp / "m1"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--azimuth", "nan,nan", "--out",
          tmp / "m2"], "error", []),
        (["generate", "--category", "laptop", "--instances", "2", "--views", "1", "--width", "100000", "--height",
          "100000", "--out", tmp / "m3"], "error", []),
        (["assets", "check", tmp / "loop.urdf"], "error", []),
        (["assets", "check", tmp / "slide.urdf"], "error", []),
        (["view", "--data", d2, "--pred", pred, "--port", "0"], "error", []),
        (["predict", "--method", "icp", "--data", d, "--out", tmp / "q2.npz", "--option", f"run={run}"], "error", []),
        (["doctor", "--no-progress"], "ok", []),
        (["list", "--no-progress"], "ok", []),
        (["--version"], "ok", []),
    ]
    counts, rows = {}, []
    for args, expected, keep in cases:
        before = digest(keep)
        code, out, err, secs = sh(args, tmp, 60, env)
        after = digest(keep)
        if code is None:
            kind = "hang"
        elif "Traceback" in err or "internal error" in err:
            kind = "traceback"
        elif before != after:
            kind = "lost"
        elif expected == "error":
            lines = [ln for ln in err.strip().splitlines() if ": error: " in ln]
            kind = "clear" if code == 2 and len(lines) == 1 else ("silent" if code == 0 else "unclear")
        else:
            kind = "ok" if code == 0 else "unclear"
        counts[kind] = counts.get(kind, 0) + 1
        msg = (err.strip().splitlines() or [""])[-1][:160]
        rows.append((" ".join(str(x).replace(str(tmp), "$TMP") for x in args), kind, f"{secs:.1f}",
                     msg.replace(str(tmp), "$TMP")))
        print(f"{kind:9s} {rows[-1][0][:90]}  {rows[-1][3][:110]}", flush=True)
    print(json.dumps(counts))
    if a.out:
        from scapo.provenance import provenance
        from scapo.report import markdown_table

        md = ["# Bad-input probe of every command", "", f"Counts: {json.dumps(counts)} (of {len(cases)} cases)", "",
              markdown_table(["command", "outcome", "s", "last stderr line"], rows), "",
              "Provenance: " + ", ".join(f"{k}={v}" for k, v in provenance(command="bench/probe_bad_input.py").items())]
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join(md) + "\n")
        print(f"wrote {a.out}")
    return 0 if set(counts) <= {"clear", "ok"} else 1


if __name__ == "__main__":
    sys.exit(main())
