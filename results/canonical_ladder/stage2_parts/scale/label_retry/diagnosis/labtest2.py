"""Offline (session 37): does labelling from the 24 octahedral starts (label_starts=O) rescue the clouds whose
pseudo-labels are random? Template: the run's template sample (template_split.npz) in its target frame, split by
labels_refit; clouds normalised, centred, in their target frames. Scores with the truth: base IoU, and the frame
consistency of the signed axes read from the new labels."""
import json, sys, time
import numpy as np, torch
from scapo.data import load
from scapo.models import part_init
from scapo.ops import signed_axes
from scapo.ops.groups import rotation_group
data, snap, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
ds = load(data, "train"); gt = ds.arrays(["points", "part_label", "T_cam_obj"])
F = np.load(f"{snap}/frame_targets.npy"); lab = np.load(f"{snap}/split_labels.npy")
z = np.load(f"{snap}/template_split.npz"); d = json.load(open(f"{snap}_tgtdiag.json"))
idx = np.array(d["idx"]); a = np.array(d["angle"])
rng = np.random.default_rng(0)
bad = rng.choice(idx[a > 15], n, replace=False); good = rng.choice(idx[a <= 15], n, replace=False)
X = torch.from_numpy(gt["points"]).double()
c = X.mean(1, keepdim=True); s = 2 * ((X - c) ** 2).sum(-1).mean(-1).sqrt()
Xn = (X - c) / s[:, None, None]
s0 = int(z["sample"]); tpl = (Xn[s0] @ torch.from_numpy(F[s0]))[torch.from_numpy(z["points"])]
tl = torch.from_numpy(z["labels_refit"]).long()
Rg = gt["T_cam_obj"][:, :3, :3]
def ang(A, B):
    return np.degrees(np.arccos(np.clip((np.einsum("...ij,...ij->...", A, B) - 1) / 2, -1, 1)))
for name, sel in (("good", good), ("bad", bad)):
    C = torch.bmm(Xn[sel], torch.from_numpy(F[sel]))
    for st in ("", "O"):
        t0 = time.time()
        L = part_init.label_clouds(tpl, tl, C, 3, starts=None if not st else torch.tensor(rotation_group(st)).double()).numpy()
        dt = time.time() - t0
        true = gt["part_label"][sel]
        iou = np.mean([((L[m] == 0) & (true[m] == 0)).sum() / max(((L[m] == 0) | (true[m] == 0)).sum(), 1) for m in range(len(sel))])
        E, ok = signed_axes.parts_signed_axes(gt["points"][sel], L, (1, 2), 0, 8, axes="plane")
        # consensus offset from the good clouds' old targets
        O = np.einsum("mji,mjk->mik", E, Rg[sel])
        ref = np.einsum("mji,mjk->mik", F[good], Rg[good])
        # per-cloud: within 15 deg of the good clouds' majority offset in E-space: use the E of old labels for good
        print(f"{name} starts={st or 'id'}: base IoU {iou:.3f} (old {np.mean([((lab[m]==0)&(gt['part_label'][m]==0)).sum()/max(((lab[m]==0)|(gt['part_label'][m]==0)).sum(),1) for m in sel]):.3f}) labelling {dt:.1f}s", flush=True)
        np.save(f"{snap}_E_{name}_{st or 'id'}.npy", E)
