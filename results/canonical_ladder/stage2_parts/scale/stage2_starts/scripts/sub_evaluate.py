"""Ad hoc (session 44): `scapo evaluate` of predictions made by sub_predict.py (training split every TRAIN_STRIDE-th
cloud, default 8): the evaluator's alignment is fitted on that same subsample of the training split; the evaluator's
code is otherwise the project's own. For choices on val only (every arm alike); not a reported score.
usage: python sub_evaluate.py evaluate --data D --split val --pred LABEL=FILE ... --out DIR --name NAME"""
import os
import sys

from scapo.eval import evaluator as ev

STRIDE = int(os.environ.get("TRAIN_STRIDE", "8"))
orig_load = ev.load


class _Sub:
    def __init__(self, ds):
        self._ds = ds

    def __getattr__(self, name):
        return getattr(self._ds, name)

    def arrays(self, fields=None):
        return {k: v[::STRIDE] for k, v in self._ds.arrays(fields).items()}

    def keys(self):
        return self._ds.keys()[::STRIDE]

    def __len__(self):
        return (len(self._ds) + STRIDE - 1) // STRIDE


def load(root, split="train", *a, **k):
    ds = orig_load(root, split, *a, **k)
    return _Sub(ds) if split == "train" and STRIDE > 1 else ds


ev.load = load
from scapo.cli.main import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
