"""Offline: would more / other starts of the split fit find a lower-score split, and is it the true one?"""
import sys, itertools, torch, time
from scapo.models import part_init
torch.set_num_threads(1)
d = torch.load(sys.argv[1]); seed = int(sys.argv[2]); n = int(sys.argv[3])
C, T, truth, tl, K = d["clouds"], d["template"], d["truth"], d["tl"], d["K"]
P = 3
def miou(pred, gt):
    best = 0.0
    for perm in itertools.permutations(range(P)):
        ious = [((pred == perm[p]) & (gt == p)).sum(-1).float() / ((pred == perm[p]) | (gt == p)).sum(-1).float().clamp_min(1) for p in range(P)]
        best = max(best, float(torch.stack(ious, -1).mean()))
    return best
g = torch.Generator().manual_seed(seed)
a, b = part_init.random_pairs(C.shape[0], 128, g)
score = lambda cl: float(part_init.part_rigidity_residual(C[a], C[b], cl[a], cl[b], P).mean())
rows = []
t0 = time.time()
g2 = torch.Generator().manual_seed(1000 + seed)
for k in range(n):
    Kr = T[torch.randperm(len(T), generator=g2)[:P]]
    l, cl = part_init.fit_template_parts(T, C, part_init.nearest_keypoint(T, Kr), P, rounds=8)
    if len(torch.unique(l)) == P:
        rows.append((score(cl), miou(cl, truth), miou(l[None], tl[None]), k))
print(f"{n} starts in {time.time()-t0:.0f}s; valid {len(rows)}")
rows.sort()
for r in rows[:6]: print("  score %.6f cloud miou %.3f tpl miou %.3f start %d" % r)
print("best-of-first-24:", min(rows[i] for i in range(len(rows)) if rows[i][3] < 24))
# longer fit (more rounds) from the truth
l, cl = part_init.fit_template_parts(T, C, tl, P, rounds=8)
print("truth start: score %.6f miou %.3f tpl %.3f" % (score(cl), miou(cl, truth), miou(l[None], tl[None])))
