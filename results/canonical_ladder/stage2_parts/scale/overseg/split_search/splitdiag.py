"""Diagnosis (issue 52, session 36): at stage 2's start, does the split search's objective (part rigidity over cloud
pairs) prefer the true split, and is a good split among its candidates? Resumes a copy of a run stopped at the end of
stage 1, wraps part_init.choose_split (both calls: stage-1 frames, then the refit in the target frames), and per call
prints every candidate's score and its mIoU against the true labels, plus the true split's score and the fit started
from the true template labels. Stops after the second call.
usage: python splitdiag.py DATA RUN_COPY SEED OUT.json"""
import json, sys, itertools
import numpy as np, torch
from scapo.data import load
from scapo.models import part_init
import scapo.ops.sampling as sampling

data, run, seed, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
torch.set_num_threads(1)
lab = torch.from_numpy(load(data, "train").arrays(["part_label"])["part_label"]).long()
idx = torch.randperm(len(lab), generator=torch.Generator().manual_seed(seed))[:64]
step = max(1, lab.shape[1] // 128)
truth = lab[idx][:, ::step]
rec = {"calls": []}
orig_med, orig_fps, orig_choose = part_init.medoid, sampling.farthest_point_indices, part_init.choose_split

def med(c, *a, **k):
    m = orig_med(c, *a, **k); rec["medoid"] = int(m); return m
def fps(S, M, rng):
    f = orig_fps(S, M, rng)
    if "fps" not in rec: rec["fps"] = np.asarray(f)
    return f
part_init.medoid, sampling.farthest_point_indices = med, fps

def miou(pred, gt, P):
    best = 0.0
    for perm in itertools.permutations(range(P)):
        ious = []
        for p in range(P):
            a, b = pred == perm[p], gt == p
            ious.append((a & b).sum(-1).float() / (a | b).sum(-1).float().clamp_min(1))
        best = max(best, float(torch.stack(ious, -1).mean()))
    return best

def choose(clouds, template, K, starts=24, pairs=128, seed=0, rounds=8, keypoint_split=True):
    B, P = clouds.shape[0], K.shape[0]
    g = torch.Generator().manual_seed(seed)
    a, b = part_init.random_pairs(B, pairs, g)
    score = lambda cl: float(part_init.part_rigidity_residual(clouds[a], clouds[b], cl[a], cl[b], P).mean())
    tl = lab[idx[rec["medoid"]]][torch.from_numpy(rec["fps"])]
    rows = []
    for k in range(starts + 1):
        Kr = K if k == 0 else template[torch.randperm(len(template), generator=g)[:P]]
        l, cl = part_init.fit_template_parts(template, clouds, part_init.nearest_keypoint(template, Kr), P, rounds=rounds)
        rows.append({"k": k, "parts": len(torch.unique(l)), "score": score(cl), "miou": miou(cl, truth, P),
                     "tpl_miou": miou(l[None], tl[None], P)})
    l, cl = part_init.fit_template_parts(template, clouds, tl, P, rounds=rounds)
    call = {"truth_score": score(truth), "truth_fit": {"score": score(cl), "miou": miou(cl, truth, P),
            "tpl_miou": miou(l[None], tl[None], P)}, "cands": rows}
    rec["calls"].append(call)
    torch.save({"clouds": clouds, "template": template, "truth": truth, "tl": tl, "K": K},
               out.replace(".json", f"_call{len(rec['calls'])}.pt"))
    ok = [r for r in rows if r["parts"] == P]
    best = min(ok, key=lambda r: r["score"])
    print(f"call {len(rec['calls'])}: truth score {call['truth_score']:.6f}; fit from truth {call['truth_fit']}; "
          f"chosen score {best['score']:.6f} miou {best['miou']:.3f}; best-miou cand "
          f"{max(ok, key=lambda r: r['miou'])}", flush=True)
    json.dump({k: v for k, v in rec.items() if k != "fps"}, open(out, "w"), indent=1)
    if len(rec["calls"]) == 2:
        sys.exit(0)
    return orig_choose(clouds, template, K, starts=starts, pairs=pairs, seed=seed, rounds=rounds,
                       keypoint_split=keypoint_split)
part_init.choose_split = choose

from scapo.methods.registry import train_method
train_method("scapo", data, run, None, progress=False)
