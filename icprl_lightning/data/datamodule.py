"""The shared LightningDataModule of every task family: generate once, store, memory-map, batch.

A family's DataModule subclass says how to generate its dataset (``generator_config`` and
``generate``), what its contexts look like (``context_kind``, ``state_dim``, ``action_spec``) and how its
held-out tasks are evaluated (``evaluation_suites``); it sets ``self.family`` (whose ``horizon`` is the
context length) and ``self.per_task`` (trajectories per task in train and val). This base class owns the rest:

* ``prepare_data()`` generates the dataset when it is missing (atomic write, see ``data/store.py``);
  an existing one made with another config is an error that names the differing keys.
* Batches are drawn a whole batch at a time from the memory-mapped arrays (one fancy index per field).
* A training sample is one context (a trajectory of one task). With ``pairs=True`` it also carries the
  comparisons of *another* trajectory of the same task (``pair_*`` fields): ICPO's default loss pairs,
  which the model cannot copy from its context. With ``query_labels=True`` it carries query states and
  their optimal-action labels (``query_states``, ``optimal_actions``) for DPT/DP²T.

Trajectories are stored task-major: row ``task * trajectories_per_task + j``.
"""

from __future__ import annotations

import hashlib
import json
from abc import abstractmethod
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec, context_fields
from icprl_lightning.data.batches import PAIR_FIELDS, ContextBatches
from icprl_lightning.data.store import StoredDataset, load_dataset, write_dataset
from icprl_lightning.data.suites import EvalSuite


class InContextDataModule(L.LightningDataModule):
    """Base DataModule: see the module docstring. Subclasses define the family-specific parts."""

    family_name: str = "family"  # names the dataset directory
    metric_env: str = "env"  # names the logged validation metrics: val/<metric_env>/...
    pair_fields: tuple[str, ...] = PAIR_FIELDS  # what ``pairs=True`` serves from another trajectory of the task

    def __init__(self, data_dir: str | None = None, root_dir: str = "data", batch_size: int = 32,
                 pairs: bool = False, query_labels: bool = False, overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__()
        self.data_dir = data_dir
        self.root_dir = root_dir
        self.batch_size = batch_size
        self.pairs = pairs
        self.query_labels = query_labels
        self.overwrite = overwrite
        self.verify_checksums = verify_checksums
        self.progress = progress
        self.dataset: StoredDataset | None = None

    # ---- family-specific -------------------------------------------------------------------------
    @property
    @abstractmethod
    def context_kind(self) -> str: ...

    @property
    @abstractmethod
    def state_dim(self) -> int: ...

    @property
    @abstractmethod
    def action_spec(self) -> ActionSpec: ...

    @property
    def context_length(self) -> int:
        """Transitions per context (the model's ``max_context``): the family's horizon."""
        return self.family.horizon

    @abstractmethod
    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""

    @abstractmethod
    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        """Return ``(splits, info)``; splits need ``train`` and ``val`` with task-major trajectories."""

    @abstractmethod
    def evaluation_suites(self) -> list[EvalSuite]:
        """The held-out-task evaluations the rollout callback runs (one per context quality)."""

    @property
    def trajectories_per_task(self) -> tuple[int, int]:
        """Trajectories per task in the (train, val) splits."""
        return self.per_task

    def batch_fields(self) -> tuple[str, ...]:
        """The stored fields a training sample serves (besides query labels and pairs)."""
        return context_fields(self.context_kind)

    # ---- shared ------------------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        if self.data_dir is not None:
            return Path(self.data_dir)
        digest = hashlib.sha256(json.dumps(self.generator_config(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root_dir) / f"{self.family_name}-{self.context_kind}-{digest}"

    @property
    def regenerate_hint(self) -> str:
        return (f"delete {self.path} (or pass --data.init_args.overwrite true) and run "
                f"`icprl generate --config <your config>`; fit also generates a missing dataset")

    def prepare_data(self) -> None:
        if self.path.exists() and not self.overwrite:
            load_dataset(self.path, self.generator_config(), verify=False, regenerate_hint=self.regenerate_hint)
            return
        splits, info = self.generate()
        write_dataset(self.path, splits, self.generator_config(), info=info, overwrite=True)
        self.overwrite = False  # generated now; later calls (e.g. setup in another stage) reuse it

    def load(self) -> StoredDataset:
        if self.dataset is None:
            self.dataset = load_dataset(self.path, self.generator_config(), verify=self.verify_checksums,
                                        regenerate_hint=self.regenerate_hint)
        return self.dataset

    def setup(self, stage: str | None = None) -> None:
        self.load()

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        per_task = self.trajectories_per_task[0 if split == "train" else 1]
        data = ContextBatches(self.load()[split], self.batch_fields(), per_task, self.pairs, self.query_labels,
                              self.pair_fields)
        base = RandomSampler(data) if shuffle else SequentialSampler(data)
        return DataLoader(data, sampler=BatchSampler(base, self.batch_size, drop_last=shuffle), batch_size=None)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)
