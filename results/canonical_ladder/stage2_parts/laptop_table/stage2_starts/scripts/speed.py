import time, torch
from scapo.methods import load_run
from scapo.data import load
torch.set_num_threads(1)
m = load_run("/work/exp/s43/runs/run_scapo_cpu-laptop+epochs-5-4_s0", refine_steps=0)
model = m.predictor.model.eval()
pts = torch.from_numpy(load("/work/exp/s43/w/laptop_i150_v8_t64_s0_paper", "val").arrays(["points"])["points"][:32]).float()
X, _ = model.normalize(pts)
with torch.no_grad():
    for st in ("", "D2", "O"):
        t = time.perf_counter(); model.passes(X, st); print(st or "none", round((time.perf_counter() - t) / 32 * 1000, 1), "ms/cloud")
import cProfile, pstats
with torch.no_grad():
    cProfile.run('model.passes(X, "O")', '/tmp/prof2')
pstats.Stats('/tmp/prof2').sort_stats('tottime').print_stats(14)
