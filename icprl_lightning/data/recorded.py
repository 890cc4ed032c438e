"""Train any preference method on recorded preference data: a LightningDataModule over an imported dataset.

    icprl import prefs.npz --out data/my_prefs --kind step_preference --n-actions 5
    icprl fit --config configs/recorded_icpo.yaml --data.init_args.data_dir data/my_prefs

The dataset is what ``icprl import`` writes (docs/recorded_data.md); its manifest's kind and sizes are exposed
as ``context_kind``, ``state_dim``, ``action_spec`` and ``context_length``, so the CLI links the model's sizes
from the data. ``pairs=True`` adds the comparisons of *another* row of the same task as the samples' ``pair``
(recorded tasks may hold any number of rows, so every task needs at least two). The dataset is checked as a
whole (``data/schema.py``) when the DataModule is built, before training. There is no simulator behind
recorded data, so it offers no held-out evaluation (``held_out`` refuses each): validation reports the losses
on the ``val`` split's tasks.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import lightning as L
import numpy as np
import torch
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.batches import ContextBatches
from icprl_lightning.data.importer import FORMAT, KINDS, QUERY_FIELDS, TASK_FIELD
from icprl_lightning.data.schema import DatasetSchema, check_dataset
from icprl_lightning.data.store import DatasetError, StoredDataset, load_dataset
from icprl_lightning.data_contract import not_offered
from icprl_lightning.samples import ContextSamples

if TYPE_CHECKING:  # types only: recorded data never builds a suite, so it needs no evaluation code
    pass

SPLITS = ("train", "val")
# the manifest config keys this DataModule reads, with their JSON types (bool is not an int here)
CONFIG_TYPES = {"discrete": bool, "action_size": int, "state_dim": int, "context_length": int,
                "has_task_index": bool, "has_query_labels": bool}
MINIMUM = {"action_size": 1, "state_dim": 0, "context_length": 1}


class RecordedBatches(Dataset):
    """``ContextBatches`` of one split, plus another row of each row's task as the samples' ``pair``.

    ``task_index`` must be sorted (task-major, as the importer writes it); tasks may differ in size.
    """

    def __init__(self, arrays: dict[str, np.ndarray], kind: str, fields: tuple[str, ...], pairs: bool,
                 query_labels: bool, split: str) -> None:
        self.rows = ContextBatches(arrays, fields, trajectories_per_task=1, pairs=False, query_labels=query_labels,
                                   kind=kind)
        self.arrays = arrays
        self.fields = fields
        self.pairs = pairs
        if pairs:
            task = np.asarray(arrays[TASK_FIELD])
            if np.any(np.diff(task) < 0):
                raise DatasetError(f"split {split!r}: rows are not task-major (task_index not sorted); "
                                   "write the dataset with icprl import")
            _, first, inverse, counts = np.unique(task, return_index=True, return_inverse=True, return_counts=True)
            if len(task) and counts.min() < 2:
                few = np.unique(task[counts[inverse] < 2])
                raise ValueError(
                    f"pairs=True scores each context against another row of the same task, but in split "
                    f"{split!r} {len(few)} task(s) have a single row (task_index {few[:10].tolist()}); "
                    "re-import with at least two rows per task, or set data.init_args.pairs false "
                    "(ICPO: model.init_args.pair_source context)")
            self.start = first[inverse]  # (N,) first row of each row's task
            self.count = counts[inverse]  # (N,) rows of each row's task

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, index: list[int]) -> ContextSamples:
        batch = self.rows[index]
        if self.pairs:
            idx = np.sort(np.asarray(index))  # the order ContextBatches serves the rows in
            count = self.count[idx]
            shift = 1 + (torch.rand(len(idx)).numpy() * (count - 1)).astype(np.int64)  # uniform in [1, count)
            other = self.start[idx] + (idx - self.start[idx] + shift) % count
            batch = batch._replace(pair=self.rows.context(other))
        return batch


class RecordedPreferenceDataModule(L.LightningDataModule):
    """Recorded preference data written by ``icprl import``; see the module docstring.

    Args:
        data_dir: the dataset directory (``icprl import ... --out DIR``).
        batch_size: contexts per batch.
        pairs: also serve another row of the same task as the samples' ``pair`` (ICPO, RewardGen, ICRG).
        query_labels: also serve ``query_states`` / ``optimal_actions`` (DPT, DP²T).
        verify_checksums: check every file's SHA-256 against the manifest in ``setup``.
    """

    metric_env = "recorded"
    offers: frozenset[str] = frozenset()  # no simulator behind the data: no held-out evaluation

    def __init__(self, data_dir: str, batch_size: int = 32, pairs: bool = False, query_labels: bool = False,
                 verify_checksums: bool = True) -> None:
        super().__init__()
        self.data_dir = data_dir
        self.batch_size = batch_size
        self.pairs = pairs
        self.query_labels = query_labels
        self.verify_checksums = verify_checksums
        self.dataset: StoredDataset = load_dataset(self.path, verify=False, regenerate_hint=self.hint)
        self._verified = not verify_checksums
        self.config = self.dataset.manifest["config"]
        self._check_config()
        self.soft_labels = self.config.get("soft_labels", False) is True  # ties as 0.5: ICPO and RewardGen only
        missing = [s for s in SPLITS if s not in self.dataset.splits]
        if missing:
            raise DatasetError(f"{self.path} has no {missing} split. To fix: {self.hint}")
        fields = [*self.batch_fields(), *([TASK_FIELD] if self.config["has_task_index"] else []),
                  *(QUERY_FIELDS if self.config["has_query_labels"] else [])]
        self.dataset.require(dict.fromkeys(SPLITS, fields), self.hint)
        check_dataset(self.dataset, self.schema(), self.hint)
        if query_labels and not self.config.get("has_query_labels"):
            raise ValueError(f"query_labels=True serves {list(QUERY_FIELDS)}, but {self.path} was imported "
                             "without them; add both fields to the source and re-import, or pick a method that "
                             "needs no optimal-action labels (ICPO, RewardGen)")
        if pairs and not self.config.get("has_task_index"):
            raise ValueError(f"pairs=True needs to know which rows share a task, but {self.path} was imported "
                             f"without field {TASK_FIELD!r}; add it to the source and re-import, or set "
                             "data.init_args.pairs false (ICPO: model.init_args.pair_source context)")
        self._batches = {split: self._make_batches(split) for split in SPLITS}  # checks rows per task now

    def _check_config(self) -> None:
        """The manifest config this DataModule reads: one ``DatasetError`` naming a missing or mistyped key."""
        kind = self.config.get("kind")
        if self.config.get("format") != FORMAT or not isinstance(kind, str) or kind not in KINDS:
            raise DatasetError(f"{self.path} is not a recorded preference dataset (its manifest config has format "
                               f"{self.config.get('format')!r}, kind {self.config.get('kind')!r}). To fix: "
                               f"{self.hint}")
        for key, expected in CONFIG_TYPES.items():
            value = self.config.get(key)
            if type(value) is not expected or value < MINIMUM.get(key, value):
                low = f" >= {MINIMUM[key]}" if key in MINIMUM else ""
                raise DatasetError(f"{self.path}: manifest config {key!r} is {value!r}; expected "
                                   f"{expected.__name__}{low} (the manifest is corrupt). To fix: {self.hint}")

    def schema(self) -> DatasetSchema:
        """What the model linked from this data's sizes expects of every split (``data/schema.py``)."""
        return DatasetSchema(self.context_kind, self.action_spec, self.state_dim, self.context_length,
                             soft_labels=self.soft_labels)

    @property
    def path(self) -> Path:
        return Path(self.data_dir)

    @property
    def hint(self) -> str:
        return f"import the data again: icprl import SOURCE --out {self.data_dir} --kind KIND --overwrite"

    @property
    def context_kind(self) -> str:
        return self.config["kind"]

    @property
    def state_dim(self) -> int:
        return int(self.config["state_dim"])

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=bool(self.config["discrete"]), size=int(self.config["action_size"]))

    @property
    def context_length(self) -> int:
        """Steps per context (T; for trajectory pairs the pair's length H): the model's ``max_context``."""
        return int(self.config["context_length"])

    def batch_fields(self) -> tuple[str, ...]:
        return tuple(KINDS[self.context_kind])

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training split's arrays of ``batch_fields()`` only (memory-mapped): what a method fits its input
        statistics on."""
        return {k: self.dataset["train"][k] for k in self.batch_fields()}

    def held_out(self, evaluation: str) -> None:
        """No simulator behind recorded data, no held-out split: it offers no evaluation."""
        raise not_offered("recorded data", evaluation, self.offers)

    def _make_batches(self, split: str) -> RecordedBatches:
        return RecordedBatches(self.dataset[split], self.context_kind, self.batch_fields(), self.pairs,
                               self.query_labels, split)

    def setup(self, stage: str | None = None) -> None:
        if not self._verified:  # re-open with every checksum checked, once
            dataset = load_dataset(self.path, verify=True, regenerate_hint=self.hint)
            if dataset.manifest != self.dataset.manifest:  # replaced since __init__ checked it: refuse
                raise DatasetError(f"{self.path} changed on disk since this DataModule was built; build it again")
            self.dataset = dataset
            self._batches = {split: self._make_batches(split) for split in SPLITS}
            self._verified = True

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        data = self._batches[split]
        base = RandomSampler(data) if shuffle else SequentialSampler(data)
        drop_last = shuffle and len(data) >= self.batch_size  # a dataset smaller than a batch is one batch
        return DataLoader(data, sampler=BatchSampler(base, self.batch_size, drop_last=drop_last), batch_size=None)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)
