import json, sys, time
import numpy as np, torch
from scapo.data import load
from scapo.models import part_init
from scapo.ops.groups import rotation_group
data, snap, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
ds = load(data, "train"); gt = ds.arrays(["points", "part_label"])
F = np.load(f"{snap}/frame_targets.npy")
z = np.load(f"{snap}/template_split.npz"); d = json.load(open(f"{snap}_tgtdiag.json"))
idx = np.array(d["idx"]); a = np.array(d["angle"])
rng = np.random.default_rng(0)
bad = rng.choice(idx[a > 15], n, replace=False); good = rng.choice(idx[a <= 15], n, replace=False)
X = torch.from_numpy(gt["points"]).double()
c = X.mean(1, keepdim=True); s = 2 * ((X - c) ** 2).sum(-1).mean(-1).sqrt()
Xn = (X - c) / s[:, None, None]
s0 = int(z["sample"]); tpl = (Xn[s0] @ torch.from_numpy(F[s0]))[torch.from_numpy(z["points"])]
tl = torch.from_numpy(z["labels_refit"]).long()
O = torch.tensor(rotation_group("O")).double()
D2 = O[[k for k in range(24) if np.allclose(np.abs(np.diag(O[k].numpy())), 1)]]
print("D2 size", len(D2))
def label(C, starts, sub):
    out = []
    for k in range(0, len(C), 64):
        Cc = C[k:k + 64]
        R0, t0 = part_init.whole_template_start(tpl, Cc[:, ::sub], starts)
        Rc, tc, _ = part_init.register_template_parts(tpl, tl, Cc, 3, 6, R=R0.repeat_interleave(3, 0), t=t0.repeat_interleave(3, 0))
        posed = part_init._posed(tpl, tl, Rc, tc, len(Cc), 3)
        out.append(tl[part_init.pairwise_sq_dist(Cc, posed).argmin(-1)])
    return torch.cat(out).numpy()
for name, sel in (("good", good), ("bad", bad)):
    C = torch.bmm(Xn[sel], torch.from_numpy(F[sel]))
    true = gt["part_label"][sel]
    for sname, st, sub in (("D2", D2, 1), ("D2/4", D2, 4), ("O/4", O, 4), ("O/8", O, 8)):
        t0 = time.time(); L = label(C, st, sub); dt = time.time() - t0
        iou = np.mean([((L[m] == 0) & (true[m] == 0)).sum() / max(((L[m] == 0) | (true[m] == 0)).sum(), 1) for m in range(len(sel))])
        print(f"{name} {sname}: base IoU {iou:.3f} {dt:.1f}s", flush=True)
