"""Per cloud: the rotation taking the true object frame to the canonical frame of the saved call (exact point
correspondence), its angle from the most common offset (medoid), and whether temples are swapped in the labelling."""
import sys, numpy as np, torch
from scipy.spatial.transform import Rotation as Rot
from scapo.data import load
D, f, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
d = torch.load(f); C = d["clouds"].double().numpy()
a = load(D, "train").arrays(["points", "T_cam_obj", "joint_state"])
idx = torch.randperm(len(a["points"]), generator=torch.Generator().manual_seed(seed))[:64].numpy()
step = max(1, a["points"].shape[1] // 128)
Rs = []
for k, i in enumerate(idx):
    T = a["T_cam_obj"][i]; x = a["points"][i][::step][:C.shape[1]]
    obj = (x - T[:3, 3]) @ T[:3, :3]
    A = obj - obj.mean(0); B = C[k] - C[k].mean(0)
    U, S, Vt = np.linalg.svd(A.T @ B); dd = np.sign(np.linalg.det(U @ Vt))
    Rs.append(U @ np.diag([1, 1, dd]) @ Vt)  # obj @ R ~ canon
Rs = np.stack(Rs)
ang = lambda R: np.degrees(np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
G = np.array([[ang(Rs[i].T @ Rs[j]) for j in range(64)] for i in range(64)])
m = np.argmax((G < 15).sum(1)); off = ang(np.einsum("ij,bik->bjk", Rs[m], Rs))
print("inliers(15deg) of best centre", (G[m] < 15).mean().round(2), "| offsets from it: quantiles", np.percentile(off, [10, 25, 50, 75, 90]).round(0))
# the flipped clouds: their relative rotation's axis in the object frame
fl = off > 90
for b in np.where(fl)[0][:8]:
    Rr = Rs[b] @ Rs[m].T  # obj frame rotation: obj R_b = canon ; R_b Rm^T
    rv = Rot.from_matrix(Rr).as_rotvec(); print(f"  cloud {b}: off {off[b]:.0f} axis(obj) {np.round(rv/np.linalg.norm(rv),2)}")
print("share >90:", fl.mean().round(2), "share 30-90:", ((off > 30) & (off <= 90)).mean().round(2))
