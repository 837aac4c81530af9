"""Loading datasets written by ``scapo generate`` as a ``torch.utils.data.Dataset``."""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np
import pandas as pd
from torch.utils.data import Dataset

from scapo.data.config import FORMAT_VERSION
from scapo.data.storage import ARRAY_FIELDS, read_shard
from scapo.errors import CorruptShardError, DatasetError
from scapo.files import read_json

SPLITS = ("train", "val", "test", "all")

#: Entries of ``card.json`` the loader and the evaluator rely on.
CARD_KEYS = ("category", "part_names", "joint_names", "joint_type", "joint_parts", "shards", "dataset_hash")
#: Columns of ``manifest.parquet`` the loader relies on.
MANIFEST_COLUMNS = ("split", "shard", "row", "category", "instance_id", "view_id", "seed")

#: dtypes of the arrays handed out (storage may be narrower).
OUTPUT_DTYPES = {
    "points": np.float32, "part_label": np.int64, "npcs": np.float32, "part_pose": np.float64,
    "joint_type": np.int64, "joint_parts": np.int64, "joint_axis": np.float64, "joint_pivot": np.float64,
    "joint_state": np.float64, "joint_limit": np.float64, "T_cam_obj": np.float64, "K": np.float64,
    "bbox_diag": np.float64,
}


class ArticulationDataset(Dataset):
    """Samples of one split of a generated dataset.

    Each item is a dict with exactly the SPEC section 5 fields: ``points (N,3) float32`` (m,
    OpenCV camera frame), ``part_label (N,) int64`` (-1 = not object), ``npcs (N,3) float32``,
    ``part_pose (P,4,4) float64``, ``joint_type (J,) int64``, ``joint_parts (J,2) int64``,
    ``joint_axis (J,3)``, ``joint_pivot (J,3)`` (camera frame), ``joint_state (J,)``,
    ``joint_limit (J,2)``, ``T_cam_obj (4,4)``, ``K (3,3)``, ``bbox_diag ()`` (float64), and the
    metadata ``category`` (str), ``instance_id``, ``view_id``, ``seed`` (int).

    Shards are read lazily and kept in an LRU cache of ``cache_shards`` shards; the first read
    of a shard checks its sha256 against the card.

    Raises:
        DatasetError: the directory does not exist, has no ``card.json`` (generation unfinished), a
            truncated or incomplete card, or an unreadable manifest (each names the file and what to do).
        CorruptShardError: on access to a damaged shard (the message names it).
    """

    def __init__(self, root: str | Path, split: str = "train", cache_shards: int = 64, verify: bool = True):
        self.root = Path(root)
        if split not in SPLITS:
            raise DatasetError(f"unknown split {split!r}; known splits: {', '.join(SPLITS)}")
        if not self.root.is_dir():
            what = "it is a file" if self.root.exists() else "the folder does not exist"
            raise DatasetError(f"{self.root} is not a scapo dataset: {what}; give the folder written by "
                               "'scapo generate --out'")
        card_path = self.root / "card.json"
        rerun = "rerun 'scapo generate' with the same arguments to rewrite it"
        if not card_path.is_file():
            hint = " (generation unfinished: rerun 'scapo generate' with the same arguments to resume)" \
                if (self.root / "config.json").is_file() else ""
            raise DatasetError(f"{self.root} is not a scapo dataset: no card.json{hint}")
        self.card = read_json(card_path, "dataset card", DatasetError, rerun)
        missing = [k for k in CARD_KEYS if k not in self.card]
        if missing:
            raise DatasetError(f"dataset card {card_path} lacks {missing} (incomplete, or not written by scapo "
                               f"generate); {rerun}")
        fv = self.card.get("format_version", FORMAT_VERSION)
        if fv != FORMAT_VERSION:
            raise DatasetError(f"{self.root} has dataset format version {fv}; this scapo reads version "
                               f"{FORMAT_VERSION}: regenerate it with this version")
        try:
            manifest = pd.read_parquet(self.root / "manifest.parquet")
        except Exception as e:  # noqa: BLE001 - pyarrow raises several kinds for a damaged file
            raise DatasetError(f"{self.root}/manifest.parquet cannot be read ({type(e).__name__}: {e}); {rerun}") \
                from e
        lacking = [c for c in MANIFEST_COLUMNS if c not in manifest.columns]
        if lacking:
            raise DatasetError(f"{self.root}/manifest.parquet lacks columns {lacking}; {rerun}")
        if split == "val" and "val" not in self.card.get("splits", {}):
            raise DatasetError(f"{self.root} has no val split (generated with --val-fraction 0, or before val splits "
                               "existed); choices need one: regenerate into a new folder with --val-fraction (default "
                               "0.1)")
        if split != "all":
            manifest = manifest[manifest["split"] == split]
        self.manifest = manifest.reset_index(drop=True)
        self.split = split
        self.verify = verify
        self._cache: OrderedDict[str, dict] = OrderedDict()
        self._cache_size = max(1, int(cache_shards))
        self._shard = self.manifest["shard"].to_numpy()
        self._row = self.manifest["row"].to_numpy()

    # ------------------------------------------------------------------ info
    @property
    def category(self) -> str:
        return self.card["category"]

    @property
    def part_names(self) -> list[str]:
        return list(self.card["part_names"])

    @property
    def num_parts(self) -> int:
        return len(self.card["part_names"])

    @property
    def num_joints(self) -> int:
        return len(self.card["joint_names"])

    @property
    def dataset_hash(self) -> str:
        return self.card["dataset_hash"]

    def __len__(self) -> int:
        return len(self.manifest)

    # ------------------------------------------------------------------ access
    def _load_shard(self, name: str) -> dict:
        if name in self._cache:
            self._cache.move_to_end(name)
            return self._cache[name]
        expected = None
        if self.verify:
            if name not in self.card["shards"]:
                raise CorruptShardError(f"shard {name} of {self.root}/manifest.parquet is not listed in card.json; "
                                        "rerun 'scapo generate' with the dataset's arguments to rewrite both")
            expected = self.card["shards"][name].get("sha256")
        arrays = read_shard(self.root / "shards" / f"{name}.npz", expected)
        self._cache[name] = arrays
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return arrays

    def __getitem__(self, i: int) -> dict:
        import numbers

        if isinstance(i, bool) or not isinstance(i, numbers.Integral):
            raise TypeError(f"a sample index must be an integer, got {i!r} ({type(i).__name__})")
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        i = int(i) % len(self)
        arrays = self._load_shard(self._shard[i])
        r = int(self._row[i])
        item = {k: np.asarray(arrays[k][r]).astype(OUTPUT_DTYPES[k], copy=True) for k in ARRAY_FIELDS}
        row = self.manifest.iloc[i]
        item["category"] = str(row["category"])
        item["instance_id"] = int(row["instance_id"])
        item["view_id"] = int(row["view_id"])
        item["seed"] = int(row["seed"])
        return item

    def arrays(self, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """All samples of the split stacked: name -> (len(self), ...) arrays (SPEC dtypes) plus
        ``instance_id`` and ``view_id``. Faster than iterating items."""
        names = list(ARRAY_FIELDS) if names is None else names
        out = {k: [] for k in names}
        for shard, rows in self.manifest.groupby("shard", sort=False)["row"]:
            arrays = self._load_shard(shard)
            rows = rows.to_numpy()
            for k in names:
                out[k].append(arrays[k][rows])
        res = {k: np.concatenate(v).astype(OUTPUT_DTYPES[k]) if v else np.zeros((0,)) for k, v in out.items()}
        res["instance_id"] = self.manifest["instance_id"].to_numpy()
        res["view_id"] = self.manifest["view_id"].to_numpy()
        return res

    @property
    def num_instances(self) -> int:
        """The number of distinct object instances in this split."""
        return int(self.manifest["instance_id"].nunique()) if len(self.manifest) else 0

    def keys(self) -> list[tuple[int, int]]:
        """(instance_id, view_id) of every sample in order (the sample keys used by predictions)."""
        return list(zip(self.manifest["instance_id"].astype(int), self.manifest["view_id"].astype(int)))


def load(path: str | Path, split: str = "train", **kwargs) -> ArticulationDataset:
    """Open ``split`` ("train", "val", "test" or "all") of the dataset at ``path``; see :class:`ArticulationDataset`."""
    return ArticulationDataset(path, split, **kwargs)
