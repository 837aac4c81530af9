"""Ad-hoc diagnosis (session 42): SCAPO's stage-1 frame against its final object frame, by the true joint state.

For each run on the dataset's test split, one-pass: the stage-1 canonical frame (``out.enc.R`` of
``model(X, stage=2)``) and the object frame the method predicts (``T_cam_obj``, slot 0's pose), each scored with
``scapo.bench.ladder.frame_inliers`` against the symmetric ground truths of three reference frames: the base's
(lambda 0), the base turned a quarter (0.25) and half (0.5, the bisector) of the way to the lid
(``bench/frame_by_state.py``'s ``joint_frames``, with the twin's). Shares overall and per quartile of the lid's
state. Run from the repository root:

    python results/canonical_ladder/stage2_parts/laptop_table/stage1_by_state/stage1_by_state.py DATA RUN [RUN ...]

Writes ``stage1_by_state.{md,json}`` beside this file, with provenance.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import torch

from scapo.bench.diagnosis import bench_script
from scapo.bench.ladder import frame_inliers
from scapo.data import load
from scapo.methods import load_run
from scapo.provenance import provenance
from scapo.sim.assets.symmetry import Symmetry, twin

HERE = Path(__file__).resolve().parent


def _poses(R: np.ndarray) -> np.ndarray:
    out = np.tile(np.eye(4), (len(R), 1, 1))
    out[:, :3, :3] = R
    return out


def main(data: Path, runs: list[Path]) -> None:
    fbs = bench_script("frame_by_state", Path("bench"))
    d = load(data, "test")
    fields = ["T_cam_obj", "part_pose", "joint_pivot", "joint_axis", "joint_state", "bbox_diag"]
    g = d.arrays(fields + ["points"])
    tw = twin({k: g[k] for k in fields}, Symmetry.from_dict(d.card["symmetry"]))
    refs = {lam: np.stack([fbs.joint_frames(g["part_pose"], lam), fbs.joint_frames(tw["part_pose"], lam)], 1)
            for lam in (0.0, 0.25, 0.5)}
    state = np.degrees(g["joint_state"][:, 0].astype(np.float64))
    edges = fbs.state_bins(state, 4)
    which = np.clip(np.searchsorted(edges, state, side="right") - 1, 0, 3)
    rows = []
    for run in runs:
        m = load_run(run, refine_steps=0)
        model = m.predictor.model.eval()
        with torch.no_grad():
            X, _ = model.normalize(torch.from_numpy(g["points"]).float())
            R1 = model(X, stage=2).enc.R.double().numpy()
        frames = {"stage 1": _poses(R1),
                  "object (T_cam_obj)": np.asarray(m.predict_points(g["points"])["T_cam_obj"], dtype=np.float64)}
        sha = hashlib.sha256((Path(run) / "checkpoint.pt").read_bytes()).hexdigest()[:16]
        for name, T in frames.items():
            for lam, ref in refs.items():
                inl = frame_inliers(T, ref)[0]
                rows.append({"run": Path(run).name, "checkpoint_sha256_16": sha, "frame": name, "lambda": lam,
                             "sym": round(float(inl.mean()), 4),
                             "by_state": [round(float(inl[which == k].mean()), 4) for k in range(4)]})
    heads = [f"{edges[k]:.0f} to {edges[k + 1]:.0f} deg" for k in range(4)]
    lines = [f"# SCAPO's stage-1 frame and its object frame, by joint state ({Path(data).name}, test)", "",
             "Symmetry-aware share of views within 15 deg of the common offset, against the base frame turned lambda "
             "of the way to the lid (0: the base, 0.5: the bisector), overall and per quartile of the lid's state "
             "(about the 90 deg rest opening; negative: more closed).", "",
             "| run | frame | lambda | sym | " + " | ".join(heads) + " |", "|:--|:--|--:|--:|" + "--:|" * 4]
    for r in rows:
        lines.append(f"| {r['run']} | {r['frame']} | {r['lambda']:g} | {r['sym']:.2f} | "
                     + " | ".join(f"{x:.2f}" for x in r["by_state"]) + " |")
    command = "python " + " ".join([str(Path(__file__).relative_to(Path.cwd().resolve())), *sys.argv[1:]])
    lines += ["", f"Written by `{command}`."]
    (HERE / "stage1_by_state.md").write_text("\n".join(lines) + "\n")
    (HERE / "stage1_by_state.json").write_text(json.dumps(
        {"command": command, "dataset": str(data), "dataset_hash": d.card.get("dataset_hash"), "rows": rows,
         "provenance": provenance()}, indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    torch.set_num_threads(1)
    main(Path(sys.argv[1]), [Path(r) for r in sys.argv[2:]])
