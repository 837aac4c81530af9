import sys, itertools, torch, time, numpy as np
from scapo.models import part_init
from scapo.ops.sampling import farthest_point_indices
torch.set_num_threads(1)
d = torch.load(sys.argv[1]); seed = int(sys.argv[2])
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
def run(name, starts):
    rows = []
    for k, lab0 in enumerate(starts):
        l, cl = part_init.fit_template_parts(T, C, lab0, P, rounds=8)
        if len(torch.unique(l)) == P:
            rows.append((score(cl), miou(cl, truth), miou(l[None], tl[None]), miou(lab0[None], tl[None]), k))
    rows.sort()
    print(name, len(starts), "starts; best: score %.6f cloud %.3f tpl %.3f start-tpl %.3f (#%d)" % rows[0],
          "| max tpl among starts %.3f" % max(r[3] for r in rows), flush=True)
# (1) farthest-point keypoints from 24 random first points
rng = np.random.default_rng(seed)
st = []
for k in range(24):
    f = farthest_point_indices(T.numpy(), P, np.random.default_rng(seed * 100 + k))
    st.append(part_init.nearest_keypoint(T, T[torch.as_tensor(np.asarray(f))]))
run("fps", st)
# (2) k-means with k = P from 24 seedings
Cs = part_init.kmeans(T, P, 24, generator=torch.Generator().manual_seed(seed))
run("kmeans3", [part_init.nearest_keypoint(T, c) for c in Cs])
# (3) over-segmentation: 6 k-means clusters, every grouping into P non-empty groups as a start
C6 = part_init.kmeans(T, 6, 1, generator=torch.Generator().manual_seed(seed))[0]
cl6 = part_init.nearest_keypoint(T, C6)
groups = set()
for assign in itertools.product(range(P), repeat=6):
    if len(set(assign)) < P: continue
    # canonical form: relabel by first occurrence
    m = {}; can = tuple(m.setdefault(x, len(m)) for x in assign); groups.add(can)
starts = [torch.tensor(gp)[cl6] for gp in sorted(groups)]
run("overseg6", starts)
