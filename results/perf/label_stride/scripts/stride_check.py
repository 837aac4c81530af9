"""Session 40: label_stride 4 vs 1 on a finished cpu-laptop run of the table (s0): stage-1 frames and pseudo-labels of
every training cloud (no files of the run are written)."""
import json, sys, time
import numpy as np, torch
from scapo.models.predict import Predictor
from scapo.models.scapo_model import SCAPOModel
from scapo.models.train import TrainingClouds
from scapo.models import part_init
from scapo.models.branch import apply_branch
torch.set_num_threads(1)
run, data_dir = sys.argv[1], sys.argv[2]
pr = Predictor.load(run)
m = pr.model.eval()
data = TrainingClouds(data_dir, 256)
tpl = m.y_base.detach().cpu()
with np.load(f"{run}/template_split.npz") as z:
    split = torch.from_numpy(z["labels"])
out = {}
frames = {}
for s in (1, 4):
    t0 = time.perf_counter(); canon, F = [], []
    with torch.no_grad():
        for k in range(0, len(data), 64):
            X, _ = SCAPOModel.normalize(data.clouds[k:k + 64])
            enc = m.frame(X[:, ::s])
            R = apply_branch(enc.R, m.branch, m.branch_flip)
            canon.append((X - enc.t[:, None]) @ R); F.append(R)
    canon, F = torch.cat(canon), torch.cat(F)
    t1 = time.perf_counter()
    lab = part_init.label_clouds(tpl, split, canon, m.cfg.num_parts, fit_stride=s)
    t2 = time.perf_counter()
    frames[s] = (F, lab)
    out[s] = {"frame_s": round(t1 - t0, 1), "label_s": round(t2 - t1, 1)}
    print(s, out[s], flush=True)
F1, L1 = frames[1]; F4, L4 = frames[4]
cos = (((F1 * F4).sum((-2, -1)) - 1) / 2).clamp(-1, 1)
ang = torch.rad2deg(torch.arccos(cos)).numpy()
out["frame_angle_deg"] = {"median": float(np.median(ang)), "p90": float(np.percentile(ang, 90)),
                          "over_15": float((ang > 15).mean()), "over_90": float((ang > 90).mean())}
out["labels_agree"] = float((L1 == L4).double().mean())
out["clouds"] = len(data)
print(json.dumps(out, indent=1))
json.dump(out, open(sys.argv[3], "w"), indent=1)
