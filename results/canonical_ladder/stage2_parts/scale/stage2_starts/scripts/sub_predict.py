"""Ad hoc (session 44): `scapo predict` with the training split subsampled (every TRAIN_STRIDE-th cloud, default 8)
for the evaluator's alignment; everything else is the project's own predict (the built-in --option stage2_starts).
Enough for the object-frame consistency of val/test (which needs only the split's own predictions); the same
subsample for every arm. Used to choose stage2_starts on the eyeglasses' val split.
usage: python sub_predict.py predict --run R --data D --out O --option refine_steps=0 --option stage2_starts=X"""
import os
import sys

from scapo.methods import scapo as sc_method

STRIDE = int(os.environ.get("TRAIN_STRIDE", "8"))
orig_predict = sc_method.SCAPOMethod.predict


class _Sub:
    def __init__(self, ds):
        self._ds, self.split, self.card = ds, ds.split, ds.card

    def arrays(self, fields=None):
        return {k: v[::STRIDE] for k, v in self._ds.arrays(fields).items()}

    def __len__(self):
        return (len(self._ds) + STRIDE - 1) // STRIDE


def predict(self, dataset):
    return orig_predict(self, _Sub(dataset) if dataset.split == "train" and STRIDE > 1 else dataset)


sc_method.SCAPOMethod.predict = predict
from scapo.cli.main import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
