"""Ad hoc (session 44): object-frame consistency (share of views whose chosen start reaches the common frame) of
choice rules over stage2_starts' scores (starts_score.py's npz files), overall and by true-state quartile.
usage: python score_rules.py score_s0_val.npz ..."""
import sys

import numpy as np

RULES = {"fwd (built-in)": lambda D: D[..., 0], "rev": lambda D: D[..., 1], "vis": lambda D: D[..., 2],
         "fwd+rev": lambda D: D[..., 0] + D[..., 1], "fwd+vis": lambda D: D[..., 0] + D[..., 2],
         "fwd+2vis": lambda D: D[..., 0] + 2 * D[..., 2], "fwd+0.5vis": lambda D: D[..., 0] + 0.5 * D[..., 2]}
print("| rule | " + " | ".join(f"{f.split('_')[1]} all | q1 | q2 | q3 | q4" for f in sys.argv[1:]) + " |")
for name, rule in RULES.items():
    cells = []
    for f in sys.argv[1:]:
        z = np.load(f)
        D, reach, state = z["D"], z["reach"], z["state"]
        ch = rule(D).argmin(1)
        r = reach[np.arange(len(D)), ch]
        q = np.quantile(state, [0, .25, .5, .75, 1])
        b = np.clip(np.searchsorted(q, state, side="right") - 1, 0, 3)
        cells.append(f"{r.mean():.3f} | " + " | ".join(f"{r[b == i].mean():.2f}" for i in range(4)))
    print(f"| {name} | " + " | ".join(cells) + " |")
z = np.load(sys.argv[1])
print("any start reaches:", [f"{np.load(f)['reach'].any(1).mean():.3f}" for f in sys.argv[1:]])
print()
print("| seed | quartile (deg) | views | chosen reaches | some start reaches | starts that reach (mean of 24) | "
      "chosen misses, another reaches | their score ratio, best reaching / chosen (median) |")
print("|:--|:--|--:|--:|--:|--:|--:|--:|")
for f in sys.argv[1:]:
    z = np.load(f)
    D, reach, state = z["D"][..., 0], z["reach"], z["state"]
    M = len(D)
    ch = D.argmin(1)
    cr = reach[np.arange(M), ch]
    q = np.quantile(state, [0, .25, .5, .75, 1])
    b = np.clip(np.searchsorted(q, state, side="right") - 1, 0, 3)
    for i in range(4):
        s = b == i
        miss = s & ~cr & reach.any(1)
        ratio = [D[m][reach[m]].min() / D[m, ch[m]] for m in np.flatnonzero(miss)]
        print(f"| {f.split('_')[1]} | {np.degrees(q[i]):.1f} to {np.degrees(q[i + 1]):.1f} | {s.sum()} | "
              f"{cr[s].mean():.2f} | {reach[s].any(1).mean():.2f} | {reach[s].sum(1).mean():.1f} | {miss.sum()} | "
              + (f"{np.median(ratio):.2f}" if ratio else "-") + " |")
print()
from scipy.spatial.transform import Rotation  # noqa: E402

print("The turn from the best reaching start's frame to the chosen one, for the views where the choice misses a "
      "reachable frame: its angle, and the share of those turns whose axis lies within 25 deg of the hinge "
      "(the true joint axis, the base's y, carried into the canonical frame by the common offset)")
print()
print("| seed | views | turn angle (deg, median) | about the hinge |")
print("|:--|--:|--:|--:|")
for f in sys.argv[1:]:
    z = np.load(f)
    D, reach, T, C = z["D"][..., 0], z["reach"], z["T"], z["C"]
    M = len(D)
    ch = D.argmin(1)
    hinge = C @ np.array([0.0, 1.0, 0.0])
    angs, about = [], []
    for m in np.flatnonzero(~reach[np.arange(M), ch] & reach.any(1)):
        ks = np.flatnonzero(reach[m])
        k = ks[D[m, ks].argmin()]
        rv = Rotation.from_matrix(T[m, ch[m], :3, :3].T @ T[m, k, :3, :3]).as_rotvec()
        a = np.linalg.norm(rv)
        angs.append(np.degrees(a))
        about.append(abs(rv @ hinge) / a > np.cos(np.radians(25)))
    print(f"| {f.split('_')[1]} | {len(angs)} | {np.median(angs):.0f} | {np.mean(about):.2f} |")
