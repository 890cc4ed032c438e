"""Windows of learning histories: the Dataset and the shared LightningDataModule base of Algorithm Distillation.

AD (Laskin et al. 2022) distills a source learner from its whole learning histories; its context is a window of
consecutive steps of one history, at any offset. Two sources serve such windows, each a subclass of
``HistoryWindowDataModule``: ``data/learning_histories.py`` (tabular Q-learning on DarkRoom, (s, a, r) steps) and
``data/duel_histories.py`` (Double Thompson Sampling on the linear dueling bandit, duels and their outcomes). What
they share lives here:

* ``HistoryWindows``: the Dataset, a whole batch of windows per list of indices; training windows come from a
  uniformly drawn history at a uniformly drawn offset (``torch``'s generator, so ``seed_everything`` fixes them),
  validation windows from fixed (row, offset) pairs.
* ``HistoryWindowDataModule``: the checks and fields its subclasses' constructors share, the data contract
  (``data_contract.PreferenceData``: no held-out suites, ``offers`` empty, since AD is evaluated online), and the
  train / val loaders; the storage (``<root_dir>/<family>-<store_name>-<hash of the config>``, written atomically
  with its manifest under the dataset's lock) is the one stored-data base's, ``data/stored.py``, as for every
  generated dataset (``val_windows_per_history`` evenly spaced offsets per
  val history, so ``val/loss`` is comparable across epochs).

A subclass keeps what differs: its family and learner types (class attributes), its explicit ``__init__`` (the
LightningCLI reads the typed parameters and defaults from it), ``context_length``, ``generator_config`` (the
dataset's identity), ``generate``, the arrays a dataset must hold (``required_fields``), how a window becomes a
context, and the ``train_arrays`` it serves. One process: under several processes every rank would draw its own
windows (nothing is sharded).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec, Context, RewardTrajectoryContext
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.store import (
    StoredDataset,
)
from icprl_lightning.data.stored import StoredData
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_int

FIELDS = ("states", "actions", "rewards")  # a learner's (s_h, a_h, r_h) steps: HistoryWindows' default


def reward_trajectory(window: dict[str, Tensor]) -> Context:
    """A window of (s, a, r) steps as the ``RewardTrajectoryContext`` AD on DarkRoom reads."""
    return RewardTrajectoryContext(*(window[k] for k in FIELDS))


class HistoryWindows(Dataset):
    """Windows of ``length`` steps of the histories in ``arrays``, a whole batch per list of indices.

    ``offsets`` None: each index draws a history and an offset at random (training); else ``offsets`` [M, 2]
    holds (row, offset) of window i (validation). Rows are task-major, ``per_goal`` per training task.
    ``fields``: the arrays a window takes, each [rows, steps, ...]; ``build`` makes the typed context of a window
    from them (tensors [B, length, ...]); the defaults are the (s, a, r) steps of DarkRoom's histories.
    """

    def __init__(self, arrays: dict[str, np.ndarray], length: int, per_goal: int, size: int,
                 offsets: np.ndarray | None = None, fields: tuple[str, ...] = FIELDS,
                 build: Callable[[dict[str, Tensor]], Context] = reward_trajectory) -> None:
        self.arrays, self.length, self.per_goal, self.size, self.offsets = arrays, length, per_goal, size, offsets
        self.fields, self.build = fields, build
        self.rows, self.steps = arrays[fields[0]].shape[:2]

    def __len__(self) -> int:
        return self.size if self.offsets is None else len(self.offsets)

    def __getitem__(self, index: list[int]) -> ContextSamples:
        if self.offsets is None:
            rows = torch.randint(0, self.rows, (len(index),)).numpy()
            starts = torch.randint(0, self.steps - self.length + 1, (len(index),)).numpy()
        else:
            rows, starts = self.offsets[np.asarray(index)].T
        window = {k: to_tensor(np.stack([self.arrays[k][r, s:s + self.length]
                                         for r, s in zip(rows, starts, strict=True)])) for k in self.fields}
        return ContextSamples(self.build(window), task=torch.from_numpy(rows // self.per_goal).long())


class HistoryWindowDataModule(StoredData):
    """A source learner's histories on a family's training tasks, stored once and served as windows.

    The base of ``LearningHistoryDataModule`` and ``DuelHistoryDataModule``; see the module docstring. A subclass
    sets the class attributes below and calls ``__init__`` with its own count hyperparameters in ``counts`` (each
    an int >= 1, checked in order before the shared ones); the shared arguments are documented on the subclasses.
    """

    pairs = False          # a window is its own context and its own targets: nothing served beside it
    query_labels = False
    offers: frozenset[str] = frozenset()  # evaluated online across episodes, not on stored contexts

    family_type: ClassVar[type]    # the family the learner runs on
    family_note: ClassVar[str] = ""  # why that family, in the error refusing another
    learner_type: ClassVar[type]   # the source learner (built with its defaults when none is given)
    kind: ClassVar[str]            # the context kind a window becomes
    fields: ClassVar[tuple[str, ...]]  # the stored arrays a window takes, each [rows, steps, ...]
    served: ClassVar[tuple[str, ...]]  # the fields of a served context (batch_fields)
    store_name: ClassVar[str]      # the dataset directory's middle part
    histories: ClassVar[str]       # the histories, as the errors name them
    generating: ClassVar[str]      # what prepare_data says it generates
    unique_val_offsets: ClassVar[bool] = False  # drop coinciding validation offsets (e.g. a window = a history)

    def __init__(self, family: Any, learner: Any, counts: dict[str, int], windows_per_epoch: int,
                 val_windows_per_history: int, batch_size: int, data_dir: str | None, root_dir: str, overwrite: bool,
                 verify_checksums: bool, progress: bool) -> None:
        owner = type(self).__name__
        if not isinstance(family, self.family_type):
            raise HyperparameterError(f"{owner}: family must be a {self.family_type.__name__}{self.family_note}, "
                                      f"got {type(family).__name__}")
        learner = self.learner_type() if learner is None else learner
        if not isinstance(learner, self.learner_type):
            raise HyperparameterError(f"{owner}: learner must be a {self.learner_type.__name__}, got "
                                      f"{type(learner).__name__}")
        for key, value in {**counts, "windows_per_epoch": windows_per_epoch,
                           "val_windows_per_history": val_windows_per_history, "batch_size": batch_size}.items():
            check_int(owner, key, value, 1)
        super().__init__()
        self.family, self.learner = family, learner
        self.windows_per_epoch, self.val_windows_per_history = windows_per_epoch, val_windows_per_history
        self.batch_size = batch_size
        self.data_dir, self.root_dir = data_dir, root_dir
        self.overwrite, self.verify_checksums, self.progress = overwrite, verify_checksums, progress
        self.dataset: StoredDataset | None = None

    # ---- what a subclass defines ---------------------------------------------------------------------
    @property
    def context_length(self) -> int:
        """Steps per window (the model's ``max_context``)."""
        raise NotImplementedError

    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        raise NotImplementedError


    def histories_per_task(self, split: str) -> int:
        """Histories per task in ``split`` (rows are task-major)."""
        raise NotImplementedError

    def window_context(self, window: dict[str, Tensor]) -> Context:
        """The typed context of a batch of windows of the stored ``fields``."""
        raise NotImplementedError

    # ---- the data contract (data_contract.PreferenceData) ----------------------------------------------
    @property
    def data_name(self) -> str:
        return self.histories

    @property
    def context_kind(self) -> str:
        return self.kind

    @property
    def state_dim(self) -> int:
        return self.family.obs_dim

    @property
    def action_spec(self) -> ActionSpec:
        return self.family.action_spec

    @property
    def metric_env(self) -> str:
        return self.family.metric_env

    def batch_fields(self) -> tuple[str, ...]:
        return self.served

    # ---- batches -------------------------------------------------------------------------------------
    def val_offsets(self) -> np.ndarray:
        """(row, offset) of every validation window [M, 2]: evenly spaced offsets in each val history."""
        rows, steps = self.load()["val"][self.fields[0]].shape[:2]
        starts = np.linspace(0, steps - self.context_length, self.val_windows_per_history).astype(np.int64)
        if self.unique_val_offsets:
            starts = np.unique(starts)
        return np.stack(np.meshgrid(np.arange(rows), starts, indexing="ij"), axis=-1).reshape(-1, 2)

    def _windows(self, split: str, size: int, offsets: np.ndarray | None) -> HistoryWindows:
        return HistoryWindows(self.load()[split], self.context_length, self.histories_per_task(split), size, offsets,
                              fields=self.fields, build=self.window_context)

    def train_dataloader(self) -> DataLoader:
        data = self._windows("train", self.windows_per_epoch, None)
        sampler = BatchSampler(RandomSampler(data), self.batch_size, drop_last=len(data) >= self.batch_size)
        return DataLoader(data, sampler=sampler, batch_size=None)

    def val_dataloader(self) -> DataLoader:
        data = self._windows("val", 0, self.val_offsets())
        return DataLoader(data, sampler=BatchSampler(SequentialSampler(data), self.batch_size, drop_last=False),
                          batch_size=None)
