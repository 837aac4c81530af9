"""Session 40: pseudo-labels with label_stride 1, 2, 4 against the true parts (every 5th training cloud of the table's
laptop data; the finished s0 run's model and its template split): accuracy under the best slot permutation."""
import itertools, json, sys, time
import numpy as np, torch
from scapo.data import load
from scapo.models import part_init
from scapo.models.predict import Predictor
from scapo.models.scapo_model import SCAPOModel
from scapo.models.branch import apply_branch
from scapo.models.train import TrainingClouds
torch.set_num_threads(1)
run, data_dir = sys.argv[1], sys.argv[2]
m = Predictor.load(run).model.eval()
data = TrainingClouds(data_dir, 256)
true = load(data_dir, "train").arrays(["part_label"])["part_label"]
sel = np.arange(0, len(data), 5)
with np.load(f"{run}/template_split.npz") as z:
    split = torch.from_numpy(z["labels"])
tpl = m.y_base.detach().cpu()
P = m.cfg.num_parts
res = {}
for s in (1, 2, 4):
    t0 = time.perf_counter(); canon = []
    with torch.no_grad():
        for k in range(0, len(sel), 64):
            X, _ = SCAPOModel.normalize(data.clouds[sel[k:k + 64]])
            enc = m.frame(X[:, ::s])
            canon.append((X - enc.t[:, None]) @ apply_branch(enc.R, m.branch, m.branch_flip))
    lab = part_init.label_clouds(tpl, split, torch.cat(canon), P, fit_stride=s).numpy()
    acc = max(float((np.asarray(perm)[lab] == true[sel]).mean()) for perm in itertools.permutations(range(P)))
    res[s] = {"accuracy": round(acc, 4), "seconds": round(time.perf_counter() - t0, 1)}
    print(s, res[s], flush=True)
json.dump(res, open(sys.argv[3], "w"), indent=1)
