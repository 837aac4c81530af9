"""Offline: how well does label_clouds label the 64 canonical clouds from the TRUE template split, per variant."""
import sys, itertools, torch, time
from scapo.models import part_init
torch.set_num_threads(1)
d = torch.load(sys.argv[1])
C, T, truth, tl = d["clouds"], d["template"], d["truth"], d["tl"]
P = 3
def miou(pred, gt):
    best = 0.0
    for perm in itertools.permutations(range(P)):
        ious = [((pred == perm[p]) & (gt == p)).sum(-1).float() / ((pred == perm[p]) | (gt == p)).sum(-1).float().clamp_min(1) for p in range(P)]
        best = max(best, float(torch.stack(ious, -1).mean()))
    return best
def per_part(pred, gt):
    return [round(float(((pred == p) & (gt == p)).sum() / ((pred == p) | (gt == p)).sum().clamp_min(1)), 3) for p in range(P)]
vis = torch.stack([(truth == p).float().mean(1) for p in range(P)], 1)
print("clouds", C.shape, "template", T.shape, "median part shares", vis.median(0).values)
for name, kw in [("identity", {}),
                 ("A", {"joint_starts": part_init.joint_turn_starts(T, tl, P)}),
                 ("A fine", {"joint_starts": part_init.joint_turn_starts(T, tl, P, turns_deg=tuple(range(-150, 151, 15)))}),
                 ]:
    t0 = time.time(); lab = part_init.label_clouds(T, tl, C, P, **kw)
    print(f"{name:10s} miou {miou(lab, truth):.3f} per-part IoU {per_part(lab, truth)} {time.time()-t0:.1f}s", flush=True)
def miou_each(pred, gt):  # best permutation per cloud
    out = []
    for b in range(len(gt)):
        out.append(max(float(torch.stack([((pred[b] == perm[p]) & (gt[b] == p)).sum().float() / ((pred[b] == perm[p]) | (gt[b] == p)).sum().float().clamp_min(1) for p in range(P)]).mean()) for perm in itertools.permutations(range(P))))
    return torch.tensor(out)
lab = part_init.label_clouds(T, tl, C, P)
m = miou_each(lab, truth)
sw = miou_each(lab, truth) 
# swapped temples only (perm 0,2,1) vs identity
def m_perm(pred, gt, perm):
    return torch.stack([((pred == perm[p]) & (gt == p)).sum(-1).float() / ((pred == perm[p]) | (gt == p)).sum(-1).float().clamp_min(1) for p in range(P)], -1).mean(-1)
a, b = m_perm(lab, truth, (0, 1, 2)), m_perm(lab, truth, (0, 2, 1))
print("per-cloud best-perm miou mean", m.mean().item(), "| identity perm", a.mean().item(), "| temples swapped", b.mean().item(),
      "| clouds where swapped better", (b > a + 0.05).float().mean().item(), "| per-cloud max(a,b) mean", torch.maximum(a, b).mean().item())
