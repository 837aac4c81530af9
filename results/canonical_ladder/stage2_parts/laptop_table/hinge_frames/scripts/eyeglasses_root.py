# session 40: the hinge-frames step on a B9 run's hinge-axis predictions with the base slot held at the kinematic root
# (choose_base_slot replaced by slot 0), run at 0dc6165 (PYTHONPATH=/work/wt39t): python eyeglasses_root.py B9s0 0
import sys
import scapo.methods.base_frame as bf
from scapo.methods import hinge as H
name, vp = sys.argv[1], sys.argv[2] == "1"
bf.choose_base_slot = lambda a, **k: (0, None)
D = "/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper"
q = H.hinge_frame_predictions(D, f"/work/exp/s39/h/eg_{name}/pred+hinge-axis.npz", view_prior=vp)
q.method = q.method + "+root"
q.save(f"/work/exp/s40/eg_{name}_root{int(vp)}.npz")
print(q.info["hinge_frames"])
