# session 41: label_view_prior (scapo.methods.hinge) applied offline to the split_labels.npy of Table 1's three SCAPO
# laptop cells (0dc6165), from the clean worktree of e1dbf2f (PYTHONPATH=/work/wt41d); with the true parts, the share
# of training views whose labels give the base's slot to the lid (the majority permutation counted as exchanged)
# before and after. Output: prior_on_table_labels.txt
import sys, time, numpy as np, itertools, json
from scapo.data import load
from scapo.methods.hinge import label_view_prior, exchange_pair
D='/work/exp/tab39/w/laptop_i150_v8_t64_s0_paper'
tr=load(D,'train'); a=tr.arrays(['points','part_label']); gt=a['part_label']; pts=a['points']
for s in (0,1,2):
    lab=np.load(f'{D}/run_scapo_cpu-laptop+epochs-5-4_s{s}/split_labels.npy')
    t=time.time(); sw,info=label_view_prior(pts,lab,[0],[[0,1]]); dt=time.time()-t
    new=exchange_pair(lab,sw,info['pair'])
    def shares(l):
        acc0=(l==gt).mean(1); acc1=((1-l)==gt).mean(1)
        return float((acc1>acc0).mean())
    print(s, info, f'{dt:.0f}s', 'exchanged before', round(shares(lab),3), 'after', round(shares(new),3))
