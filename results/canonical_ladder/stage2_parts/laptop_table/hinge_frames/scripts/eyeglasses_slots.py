# session 40: which slot the hinge-frames step takes as the base on a B9 run, the slots' dispersions and their true parts
# (run at 0dc6165, PYTHONPATH=/work/wt39t): python eyeglasses_slots.py B9s0
import sys, numpy as np
from scapo.eval.predictions import Predictions
from scapo.methods import hinge as H
from scapo.methods.base_frame import choose_base_slot
name = sys.argv[1]
D = "/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper"
p = Predictions.load(f"/work/exp/s39/h/eg_{name}/pred+hinge-axis.npz")
pts = H._points_of(D, p)
tr = p.split == "train"
fields = {k: getattr(p, k) for k in ("part_label", "part_pose", "joint_axis", "joint_pivot", "T_cam_obj")}
print("joint_parts", p.joint_parts[0].tolist(), "types", p.joint_type[0].tolist())
E, ok = H.part_axes(pts[tr], {k: v[tr] for k, v in fields.items()}, p.joint_type[0], p.joint_parts[0])
print("ok share per slot", ok.mean(0).round(3), "all", ok.all(1).mean().round(3))
every = ok.all(1)
axes = np.tile(np.eye(4), (int(every.sum()), E.shape[1], 1, 1)); axes[..., :3, :3] = E[every]
slot, disp = choose_base_slot(axes)
print("hinge-axes slot", slot, "disp", disp.round(3))
slot2, disp2 = choose_base_slot(np.asarray(p.part_pose[tr], float))
print("pose slot", slot2, "disp", disp2.round(3))
# truth: which true part does each slot hold (majority)
from scapo.methods.hinge import prediction_arrays
g = prediction_arrays(D, p, ("part_label",))["part_label"]
for s in range(E.shape[1]):
    m = p.part_label == s
    vals = np.bincount(g[m].ravel(), minlength=3)
    print("slot", s, "true label share", (vals / vals.sum()).round(3))
for vp in (False, True):
    st = H.HingeFrames(p.joint_type[0], p.joint_parts[0], view_prior=vp).fit(pts[tr], {k: v[tr] for k, v in fields.items()})
    print("view_prior", vp, "base", st.base, "prior_share", st.prior_share, "support", st.support)
