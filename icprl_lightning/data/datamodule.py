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
  that differ, one lacking a field the setting serves an error naming the field. The directory is
  ``<root_dir>/<family>-<kind>-<hash of the config>`` unless ``data_dir``. Generation holds the
  dataset's lock (``<parent>/.<name>.lock``), so a second process preparing the same dataset waits and
  then loads the finished one. ``overwrite`` replaces only one of our datasets (a ``manifest.json`` of
  this schema version); anything else at the path is refused before generating, never deleted.
* Batches are drawn a whole batch at a time from the memory-mapped arrays (``data/batches.py``): with
  ``pairs`` a sample also carries another row of the same task, with ``query_labels`` the query states
  and optimal actions of DPT/DP²T.
* Under several processes (``--trainer.strategy ddp --trainer.devices N``) each rank draws a disjoint
  shard of every epoch: the rows go through a ``DistributedSampler`` (shuffled by ``PL_GLOBAL_SEED`` and
  the epoch, so all ranks agree on the permutation) before they are cut into batches. Lightning's own
  sampler injection would wrap the whole ``BatchSampler`` and shard *batches* of each rank's own shuffle,
  so the CLI sets ``use_distributed_sampler: false`` and a trainer that leaves it on is refused here. A
  training epoch drops the last ``len % world_size`` rows (no row twice); validation pads to equal
  shards, as Lightning does, so every rank runs the same number of steps. One process draws exactly
  the batches it always did.
* Every batch of a setting with ``has_folds`` (the MDP settings) carries ``task`` (int64 (B,)), the
  training-task index ``row // per_task`` of each row (bandit batches do not: their val problems are not the
  training ones, and nothing reads it).
* Cross-fitting (ICRG's labels, ``methods/icrg.py``): ``folds=k, holdout_fold=i`` leaves the rows of every
  training task t with ``t % k == i`` out of the train *and* val loaders, so a RewardGen fitted on them has
  never seen fold i's tasks and can label them as it would label an unseen task. The dataset on disk, its
  directory and hash do not change (the knobs only choose rows; they are not part of ``generator_config``).
  The sampler draws positions among the kept rows and maps them to rows (``KeptRows``), so under DDP the
  ranks still deal disjoint shards of the kept rows; a ``pairs`` partner is another row of the same task,
  which is kept or left out whole. The fold settings go into every checkpoint of a fit as this
  DataModule's ``state_dict`` (Lightning stores it under the key ``"PreferenceDataModule"``), which is
  how ICRG checks that its ``cross_fit_checkpoints`` hold out fold 0, 1, ..., k − 1 of k in that order.
  Not ``save_hyperparameters``: that would store the family and setting objects as well. The record sits
  beside the checkpoint's checksummed part (``checkpoints.py``); resuming a fit with other fold settings
  is refused (validating or testing with others is not).
* The evaluation suites of the held-out tasks, built by the setting from the stored evaluation splits.
  ``prepare_heldout`` (``icprl evaluate``), if the whole dataset is missing, draws only those splits from the
  generator state recorded after the training splits (``heldout_streams.json``) into ``<path>.heldout``
  (``heldout_only`` in its manifest): kept if every byte matches the whole generation's recorded checksums.

What it serves is the data contract (``data_contract.PreferenceData``), and which of it applies is read from
the setting's class-level declarations (``data/settings/base.py``: ``family_type``, ``per_task_keys``,
``has_folds``, ``has_query_labels``, ``evaluations``), so this module knows no family and no setting by name.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator, Sized
from pathlib import Path
from typing import Any

import numpy as np
from torch.utils.data import BatchSampler, DataLoader, DistributedSampler, RandomSampler, Sampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.batches import LABEL_FIELDS, ContextBatches
from icprl_lightning.data.schema import DatasetSchema, check_dataset
from icprl_lightning.data.settings.base import Setting
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.data.stored import StoredData
from icprl_lightning.data.suites import BanditSuite, EvalSuite
from icprl_lightning.families.base import Family
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_int

HELDOUT_STREAMS = Path(__file__).with_name("heldout_streams.json")


class EpochBatchSampler(BatchSampler):
    """A ``BatchSampler`` that passes ``set_epoch`` on to its row sampler.

    The loader is ``DataLoader(sampler=EpochBatchSampler(...), batch_size=None)`` (a whole batch per
    ``__getitem__``), so Lightning's per-epoch ``set_epoch`` (``_set_sampler_epoch``: the loader's
    ``sampler`` and ``batch_sampler.sampler``) reaches this object, not the ``DistributedSampler`` inside;
    without the pass-through every epoch would draw the first epoch's shuffle.
    """

    def set_epoch(self, epoch: int) -> None:
        if hasattr(self.sampler, "set_epoch"):
            self.sampler.set_epoch(epoch)


class KeptRows(Sampler[int]):
    """The rows at the positions ``sampler`` draws among ``rows`` (the kept rows of a held-out fold).

    The inner sampler (random, sequential or a rank's ``DistributedSampler``) sees only the kept rows, so
    shuffles, epochs and DDP shards work as for the whole dataset; ``set_epoch`` is passed on.
    """

    def __init__(self, sampler: Sampler[int], rows: np.ndarray) -> None:
        self.sampler = sampler
        self.rows = rows

    def __iter__(self) -> Iterator[int]:
        return (int(self.rows[i]) for i in self.sampler)

    def __len__(self) -> int:
        return len(self.sampler)

    def set_epoch(self, epoch: int) -> None:
        if hasattr(self.sampler, "set_epoch"):
            self.sampler.set_epoch(epoch)


def check_folds(setting: Setting, folds: Any, holdout_fold: Any) -> None:
    """``folds`` >= 1; ``holdout_fold`` in [0, folds), given exactly when folds >= 2; only if the setting
    ``has_folds``."""
    check_int("PreferenceDataModule", "folds", folds, 1)
    if holdout_fold is None:
        if folds > 1:
            raise HyperparameterError(f"PreferenceDataModule: folds={folds} needs holdout_fold in [0, {folds}) (the "
                                      "fold of training tasks to leave out); without it every task is served")
        return
    if folds < 2:
        raise HyperparameterError(f"PreferenceDataModule: holdout_fold needs folds >= 2 (cross-fitting leaves out "
                                  f"one of k >= 2 folds of the training tasks), got holdout_fold={holdout_fold!r} "
                                  f"with folds={folds}")
    check_int("PreferenceDataModule", "holdout_fold", holdout_fold, 0, folds - 1)
    if not setting.has_folds:
        raise HyperparameterError(f"PreferenceDataModule: holdout_fold must be None with {type(setting).__name__} "
                                  "(its val split holds other tasks than the training ones, so there is no fold "
                                  f"of training tasks to leave out of both), got {holdout_fold}")


class PreferenceDataModule(StoredData):
    """Generated in-context datasets of ``setting`` on ``family``; see the module docstring.

    Args:
        family: the task family (its ``seed`` fixes the task split and every draw of the dataset).
        setting: the data recipe.
        data_dir: the dataset directory; by default one named by the config under ``root_dir``.
        batch_size: contexts per batch.
        pairs: serve another context of the same task as the samples' ``pair`` (ICPO's loss pairs, RewardGen).
        query_labels: serve query states and their optimal actions (DPT, DP²T).
        overwrite: regenerate even when the dataset exists.
        verify_checksums: check every file's SHA-256 when loading.
        progress: progress bars during generation.
        folds: number of folds k of the training tasks for cross-fitting (task t is in fold t % k).
        holdout_fold: the fold i whose tasks are left out of the train and val loaders (needs folds >= 2);
            None serves every task.
    """

    def __init__(self, family: Family, setting: Setting, data_dir: str | None = None,
                 root_dir: str = "data", batch_size: int = 32, pairs: bool = False, query_labels: bool = False,
                 overwrite: bool = False, verify_checksums: bool = True, progress: bool = True, folds: int = 1,
                 holdout_fold: int | None = None) -> None:
        if not isinstance(family, Family):
            raise HyperparameterError(f"PreferenceDataModule: family must be a Family (families/base.py), got "
                                      f"{type(family).__name__}")
        if not isinstance(setting, Setting):
            raise HyperparameterError(f"PreferenceDataModule: setting must be a Setting (data/settings/), got "
                                      f"{type(setting).__name__}")
        if not isinstance(family, setting.family_type):
            raise HyperparameterError(
                f"PreferenceDataModule: family must be a {setting.family_type.__name__} for setting "
                f"{type(setting).__name__}, got {type(family).__name__} (dueling bandits take the BanditDuels "
                "setting; MDP families take StepPreferences, TrajectoryPairs, RewardContexts or RewardTrajectories)")
        check_int("PreferenceDataModule", "batch_size", batch_size, 1)
        if pairs:
            for key, n in zip(setting.per_task_keys, setting.per_task, strict=True):
                if n < 2:
                    raise HyperparameterError(
                        f"PreferenceDataModule: pairs=True serves another context of the same task, so "
                        f"{type(setting).__name__}'s {key} must be >= 2, got {n}")
        if query_labels and not setting.has_query_labels:
            raise HyperparameterError(f"PreferenceDataModule: query_labels must be false with {type(setting).__name__} "
                                      "(its data has no query states nor optimal-action labels), got True")
        check_folds(setting, folds, holdout_fold)
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
        self.folds = folds
        self.holdout_fold = holdout_fold
        self.dataset: StoredDataset | None = None
        self.heldout: dict[str, Any] | None = None  # the recorded stream, while only held-out splits are made

    # ---- the data contract (data_contract.PreferenceData): what the CLI, methods and callbacks read ------
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
    def offers(self) -> frozenset[str]:
        """The held-out evaluations the setting declares (``Setting.evaluations``)."""
        return frozenset(self.setting.evaluations)

    @property
    def trajectories_per_task(self) -> tuple[int, int]:
        """Contexts per task in the (train, val) splits."""
        return self.setting.per_task

    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.setting.config()}

    # ---- storage (data/stored.py) -------------------------------------------------------------------
    @property
    def store_name(self) -> str:
        return self.context_kind

    @property
    def data_name(self) -> str:
        return f"{type(self.setting).__name__} data"

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        if self.heldout is None:
            return self.setting.generate(self.family, self.progress)
        splits, info = self.setting.generate(self.family, self.progress, heldout_stream=self.heldout["stream"])
        return splits, {**info, "heldout_only": True}

    def prepare_heldout(self) -> None:
        """What evaluation reads: the whole dataset if it exists or nothing is recorded for it, else only the
        held-out splits (see the module docstring), checked against the whole generation's checksums."""
        recorded = json.loads(HELDOUT_STREAMS.read_text()).get(self.path.name)
        if recorded is None or self.data_dir is not None or self.overwrite or self.path.exists():
            return self.prepare_data()
        self.data_dir, self.heldout = str(self.path.with_name(f"{self.path.name}.heldout")), recorded
        self.prepare_data()
        found = {name: meta["sha256"] for name, meta in self.load().manifest["files"].items()}
        changed = sorted(k for k in set(found) | set(recorded["files"]) if found.get(k) != recorded["files"].get(k))
        if changed:  # other generators or other numerics (MuJoCo, BLAS): only the whole generation is sure
            print(f"note: the held-out splits in {self.path} differ from the whole generation's recorded in "
                  f"{HELDOUT_STREAMS.name} ({', '.join(changed[:3])}); generating the whole dataset", flush=True)
            shutil.rmtree(self.path)
            self.data_dir, self.heldout, self.dataset = None, None, None
            self.prepare_data()

    @property
    def regenerate_hint(self) -> str:
        return (f"delete {self.path} (or pass --data.init_args.overwrite true) and run "
                f"`icprl generate --config <your config>`; fit also generates a missing dataset")

    def required_fields(self) -> dict[str, list[str]]:
        """The fields the batches read from each split: the setting's, ``pair_fields``, query labels."""
        if self.heldout is not None:
            return {}
        fields = list(self.setting.batch_fields())
        fields += [f for f in self.setting.pair_fields if self.pairs and f not in fields]
        fields += [f for f in LABEL_FIELDS if self.query_labels and f not in fields]
        return {"train": fields, "val": fields}

    def batch_fields(self) -> tuple[str, ...]:
        """The fields a training batch is made of (as ``RecordedPreferenceDataModule.batch_fields``)."""
        return tuple(self.required_fields()["train"])

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training split's arrays of ``batch_fields()`` only (memory-mapped): a method's input statistics
        are fitted on these, so a preference method never sees the scale of a stored reward it is not served."""
        train = self.load()["train"]
        return {k: train[k] for k in self.batch_fields()}

    def schema(self) -> DatasetSchema:
        """What the model built from this DataModule's sizes expects of every split (``data/schema.py``)."""
        return DatasetSchema(kind=self.context_kind, actions=self.action_spec, state_dim=self.state_dim,
                             max_steps=self.context_length)

    def setup(self, stage: str | None = None) -> None:
        """Load the dataset and check it as a whole once (``schema.check_dataset``: every split's dtypes, row
        and step counts, state and action sizes, labels, action indices, finite bounded values), one
        ``InvalidDatasetError`` naming the split, field and path — before any batch is served."""
        data = self.load()
        if getattr(self, "_values_checked", None) is not data:  # once per loaded dataset, not per stage
            check_dataset(data, self.schema(), self.regenerate_hint)
            self._values_checked = data

    # ---- fold settings in checkpoints (see the module docstring) ---------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"folds": self.folds, "holdout_fold": self.holdout_fold}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Resuming a fit (``--ckpt_path``) with other fold settings is refused: the run would switch the
        tasks it trains on midway. Validating or testing a checkpoint on any rows is fine."""
        saved = (state_dict.get("folds", 1), state_dict.get("holdout_fold"))
        fitting = self.trainer is not None and self.trainer.state.fn == "fit"
        if fitting and saved != (self.folds, self.holdout_fold):
            raise HyperparameterError(
                f"PreferenceDataModule: the checkpoint was trained with folds={saved[0]}, holdout_fold={saved[1]}; "
                f"this data has folds={self.folds}, holdout_fold={self.holdout_fold}: resume with the same "
                "--data.init_args.folds and --data.init_args.holdout_fold")

    # ---- batches -------------------------------------------------------------------------------------
    def kept_rows(self, split: str) -> np.ndarray | None:
        """The rows of ``split`` the loaders serve: None (all) without ``holdout_fold``, else those of the tasks
        outside the held-out fold, in row order."""
        if self.holdout_fold is None:
            return None
        per_task = self.trajectories_per_task[0 if split == "train" else 1]
        task = np.arange(len(self.load()[split][self.setting.batch_fields()[0]])) // per_task
        n_tasks = int(task[-1]) + 1 if len(task) else 0
        if self.folds > n_tasks:
            raise HyperparameterError(f"PreferenceDataModule: folds must be <= the number of training tasks "
                                      f"({n_tasks}), got {self.folds}")
        return np.flatnonzero(task % self.folds != self.holdout_fold)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        per_task = self.trajectories_per_task[0 if split == "train" else 1]
        data = ContextBatches(self.load()[split], self.setting.batch_fields(), per_task, self.pairs,
                              self.query_labels, self.setting.pair_fields, tasks=self.setting.has_folds,
                              kind=self.context_kind)
        rows = self.kept_rows(split)
        sampler = self._row_sampler(data if rows is None else rows, shuffle)
        if rows is not None:
            sampler = KeptRows(sampler, rows)
        return DataLoader(data, sampler=EpochBatchSampler(sampler, self.batch_size, drop_last=shuffle),
                          batch_size=None)

    def _row_sampler(self, data: Sized, shuffle: bool) -> Sampler[int]:
        """Every position of ``data`` in one process; this rank's shard of them under several (see the module
        docstring). ``data`` is the dataset, or the kept rows of a held-out fold (positions into them)."""
        trainer = self.trainer
        world_size = trainer.world_size if trainer is not None else 1
        if world_size == 1:
            return RandomSampler(data) if shuffle else SequentialSampler(data)
        if trainer._accelerator_connector.use_distributed_sampler:  # no public accessor for the flag
            raise ValueError("PreferenceDataModule shards its rows itself: set use_distributed_sampler=False on "
                             "the Trainer (the icprl CLI does), or each rank would also draw only every "
                             f"{world_size}th batch of its shard")
        return DistributedSampler(data, num_replicas=world_size, rank=trainer.global_rank, shuffle=shuffle,
                                  seed=int(os.environ.get("PL_GLOBAL_SEED", 0)), drop_last=shuffle)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    # ---- evaluation (what the setting declares in ``evaluations``) --------------------------------------
    def _held_out(self, evaluation: str) -> list[EvalSuite] | list[BanditSuite] | dict[str, ContextSamples]:
        """The setting's held-out rollouts (one per context quality), weak-regret duels (bandits) or T-PRL pairs
        per quality, each with another pair of its task (RewardGen's accuracy)."""
        if evaluation == "pair_accuracy":
            return self.setting.heldout_pairs(self.load())
        read = self.setting.evaluation_suites if evaluation == "rollouts" else self.setting.bandit_suites
        return read(self.family, self.load())
