"""Session 40: which stage-1 frame is one frame: from all 1024 points or every 4th? Frame consistency against the
ground-truth object rotation (share within 15 deg of the chordal-mean offset), every 5th training cloud."""
import json, sys
import numpy as np, torch
from scapo.data import load
from scapo.models.predict import Predictor
from scapo.models.scapo_model import SCAPOModel
from scapo.models.branch import apply_branch
from scapo.models.train import TrainingClouds
torch.set_num_threads(1)
run, data_dir = sys.argv[1], sys.argv[2]
m = Predictor.load(run).model.eval()
data = TrainingClouds(data_dir, 256)
ds = load(data_dir, "train")
gt = ds.arrays(["T_cam_obj", "part_pose"])
sel = np.arange(0, len(data), 5)
def consistency(R, G):
    off = np.einsum("bji,bjk->bik", G, R)  # G^T R
    U, _, Vt = np.linalg.svd(off.sum(0)); M = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    cos = (np.einsum("bij,ij->b", off, M) - 1) / 2
    return float((np.degrees(np.arccos(np.clip(cos, -1, 1))) <= 15).mean())
res = {}
for s in (1, 2, 4):
    F = []
    with torch.no_grad():
        for k in range(0, len(sel), 64):
            X, _ = SCAPOModel.normalize(data.clouds[sel[k:k + 64]])
            F.append(apply_branch(m.frame(X[:, ::s]).R, m.branch, m.branch_flip))
    F = torch.cat(F).double().numpy()
    res[s] = {"object": consistency(F, gt["T_cam_obj"][sel, :3, :3].astype(np.float64)),
              "part0": consistency(F, gt["part_pose"][sel, 0, :3, :3].astype(np.float64)),
              "part1": consistency(F, gt["part_pose"][sel, 1, :3, :3].astype(np.float64))}
    print(s, res[s], flush=True)
json.dump(res, open(sys.argv[3], "w"), indent=1)
