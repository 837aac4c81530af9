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
def fit(Cc, starts=None, sub=4, clip=0.01):
    if starts is None:
        Rc, tc, _ = part_init.register_template_parts(tpl, tl, Cc, 3, 6)
    else:
        R0, t0 = part_init.whole_template_start(tpl, Cc[:, ::sub], starts)
        Rc, tc, _ = part_init.register_template_parts(tpl, tl, Cc, 3, 6, R=R0.repeat_interleave(3, 0), t=t0.repeat_interleave(3, 0))
    posed = part_init._posed(tpl, tl, Rc, tc, len(Cc), 3)
    D = part_init.pairwise_sq_dist(Cc, posed)
    score = D.min(-1)[0].clamp(max=clip).mean(-1) + D.min(-2)[0].clamp(max=clip).mean(-1)
    return tl[D.argmin(-1)].numpy(), score.numpy()
res = {}
for name, sel in (("good", good), ("bad", bad)):
    C = torch.bmm(Xn[sel], torch.from_numpy(F[sel]))
    true = gt["part_label"][sel]
    L0, s0_ = fit(C); L1, s1_ = fit(C, O)
    iou = lambda L: np.array([((L[m] == 0) & (true[m] == 0)).sum() / max(((L[m] == 0) | (true[m] == 0)).sum(), 1) for m in range(len(sel))])
    i0, i1 = iou(L0), iou(L1)
    pick = s1_ < s0_
    ib = np.where(pick, i1, i0)
    res[name] = (s0_, s1_)
    print(f"{name}: id IoU {i0.mean():.3f} O/4 {i1.mean():.3f} min-score pick {ib.mean():.3f} (O picked {pick.mean():.2f}); score id median {np.median(s0_):.5f} O {np.median(s1_):.5f}")
g, b = res["good"][0], res["bad"][0]
auc = (g[:, None] < b[None]).mean()
print("AUC of identity score (bad higher)", round(auc, 3), "quantiles good", np.percentile(g, [50, 75, 90]).round(5), "bad", np.percentile(b, [25, 50]).round(5))
gr, br = res["good"][0] - res["good"][1], res["bad"][0] - res["bad"][1]
print("gain id-O: good median", np.median(gr).round(5), "bad median", np.median(br).round(5))
