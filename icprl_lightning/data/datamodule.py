"""The one LightningDataModule of generated data: ``PreferenceDataModule(family, setting)``.

The family (``families/``) says what the tasks are; the setting (``data/settings/``) says how a dataset
is made from them (I-PRL step preferences, T-PRL pairs, DPT reward contexts, DIT reward trajectories, the
bandit recipe). Both are chosen by ``class_path`` in YAML::

    data:
      class_path: icprl_lightning.data.PreferenceDataModule
      init_args:
        family: {class_path: icprl_lightning.families.darkroom.DarkRoomFamily}
        setting:
          class_path: icprl_lightning.data.settings.StepPreferences
          init_args: {trajectories_per_task: 100, bt_temperature: 1.0}
        pairs: true

This module owns what every dataset shares:

* ``prepare_data()`` generates the dataset when it is missing and writes it atomically with its
  manifest (``data/store.py``); an existing one made with another config is an error naming the keys
  that differ. The directory is ``<root_dir>/<family>-<kind>-<hash of the config>`` unless ``data_dir``.
* Batches are drawn a whole batch at a time from the memory-mapped arrays (``data/batches.py``): with
  ``pairs`` a sample also carries another row of the same task, with ``query_labels`` the query states
  and optimal actions of DPT/DP²T.
* The evaluation suites of the held-out tasks, built by the setting from the stored evaluation splits.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.batches import ContextBatches
from icprl_lightning.data.settings.base import Setting
from icprl_lightning.data.store import StoredDataset, load_dataset, write_dataset
from icprl_lightning.data.suites import BanditSuite, EvalSuite
from icprl_lightning.families.base import Family


class PreferenceDataModule(L.LightningDataModule):
    """Generated in-context datasets of ``setting`` on ``family``; see the module docstring.

    Args:
        family: the task family (its ``seed`` fixes the task split and every draw of the dataset).
        setting: the data recipe.
        data_dir: the dataset directory; by default one named by the config under ``root_dir``.
        batch_size: contexts per batch.
        pairs: serve another context of the same task as ``pair_*`` (ICPO's loss pairs, RewardGen).
        query_labels: serve query states and their optimal actions (DPT, DP²T).
        overwrite: regenerate even when the dataset exists.
        verify_checksums: check every file's SHA-256 when loading.
        progress: progress bars during generation.
    """

    def __init__(self, family: Family, setting: Setting, data_dir: str | None = None,
                 root_dir: str = "data", batch_size: int = 32, pairs: bool = False, query_labels: bool = False,
                 overwrite: bool = False, verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__()
        self.family = family
        self.setting = setting
        self.data_dir = data_dir
        self.root_dir = root_dir
        self.batch_size = batch_size
        self.pairs = pairs
        self.query_labels = query_labels
        self.overwrite = overwrite
        self.verify_checksums = verify_checksums
        self.progress = progress
        self.dataset: StoredDataset | None = None

    # ---- what the CLI links into the model and the callbacks read ----------------------------------
    @property
    def context_kind(self) -> str:
        return self.setting.kind

    @property
    def state_dim(self) -> int:
        return self.family.obs_dim

    @property
    def action_spec(self) -> ActionSpec:
        return self.family.action_spec

    @property
    def context_length(self) -> int:
        """Transitions per context (the model's ``max_context``): the family's horizon."""
        return self.family.horizon

    @property
    def metric_env(self) -> str:
        return self.family.metric_env

    @property
    def trajectories_per_task(self) -> tuple[int, int]:
        """Contexts per task in the (train, val) splits."""
        return self.setting.per_task

    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.setting.config()}

    # ---- storage -------------------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        if self.data_dir is not None:
            return Path(self.data_dir)
        digest = hashlib.sha256(json.dumps(self.generator_config(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root_dir) / f"{self.family.name}-{self.context_kind}-{digest}"

    @property
    def regenerate_hint(self) -> str:
        return (f"delete {self.path} (or pass --data.init_args.overwrite true) and run "
                f"`icprl generate --config <your config>`; fit also generates a missing dataset")

    def prepare_data(self) -> None:
        if self.path.exists() and not self.overwrite:
            load_dataset(self.path, self.generator_config(), verify=False, regenerate_hint=self.regenerate_hint)
            return
        splits, info = self.setting.generate(self.family, self.progress)
        write_dataset(self.path, splits, self.generator_config(), info=info, overwrite=True)
        self.overwrite = False  # generated now; later calls (e.g. setup in another stage) reuse it

    def load(self) -> StoredDataset:
        if self.dataset is None:
            self.dataset = load_dataset(self.path, self.generator_config(), verify=self.verify_checksums,
                                        regenerate_hint=self.regenerate_hint)
        return self.dataset

    def setup(self, stage: str | None = None) -> None:
        self.load()

    # ---- batches -------------------------------------------------------------------------------------
    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        per_task = self.trajectories_per_task[0 if split == "train" else 1]
        data = ContextBatches(self.load()[split], self.setting.batch_fields(), per_task, self.pairs,
                              self.query_labels, self.setting.pair_fields)
        base = RandomSampler(data) if shuffle else SequentialSampler(data)
        return DataLoader(data, sampler=BatchSampler(base, self.batch_size, drop_last=shuffle), batch_size=None)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    # ---- evaluation ----------------------------------------------------------------------------------
    def evaluation_suites(self) -> list[EvalSuite]:
        """The held-out in-context rollouts the rollout callback runs (one per context quality)."""
        return self.setting.evaluation_suites(self.family, self.load())

    def bandit_suites(self) -> list[BanditSuite]:
        """The held-out weak-regret evaluations (dueling bandits only)."""
        if not hasattr(self.setting, "bandit_suites"):
            raise ValueError(f"{type(self.setting).__name__} data has no bandit evaluation; use a BanditDuels setting")
        return self.setting.bandit_suites(self.family, self.load())

    def heldout_pairs(self) -> dict[str, dict[str, torch.Tensor]]:
        """Held-out T-PRL pairs per quality, each with another pair of its task (RewardGen's accuracy)."""
        if not hasattr(self.setting, "heldout_pairs"):
            raise ValueError("held-out pairs exist in trajectory_preference datasets only")
        return self.setting.heldout_pairs(self.load())
