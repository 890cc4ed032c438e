"""Learning histories as training data: the LightningDataModule of Algorithm Distillation (``methods/ad.py``).

AD (Laskin et al. 2022) trains on the *whole* learning history of a source learner per task, and its context is
a sliding window of that history across episode boundaries. ``PreferenceDataModule`` serves whole stored rows of
one context each, calibrated per quality; neither fits a window drawn at any offset of a history tens of episodes
long, so learning histories have their own DataModule, which still keeps the project's storage conventions:

* ``prepare_data()`` runs the learner (``families/darkroom/learning_histories.py``: tabular Q-learning, all goals at
  once) on the family's *training* goals and writes the histories atomically with their manifest under the
  dataset's lock (``data/store.py``), in ``<root_dir>/<family>-learning_history-<hash of the config>``. Split
  ``train`` holds ``histories_per_goal`` independent learner runs per training goal and ``val``
  ``val_histories_per_goal`` more (task-major rows: ``states`` [N, E·H, S], ``actions`` [N, E·H], ``rewards``
  [N, E·H], ``episode_returns`` [N, E], ``task_index`` [N]). A dataset made with another config is an error
  naming the keys that differ. The held-out goals are never touched: they are for deployment
  (``evaluation/ad_rollout.py``).
* A training batch is B windows of ``context_length = context_episodes · H`` consecutive steps, each from a
  uniformly drawn history at a uniformly drawn offset (``torch``'s generator, so ``seed_everything`` fixes them),
  served as ``ContextSamples`` whose ``context`` is a ``RewardTrajectoryContext`` (s, a, r) and whose ``task`` is
  the row's training-goal index; ``windows_per_epoch`` windows make an epoch. Validation windows are fixed:
  ``val_windows_per_history`` per val history at evenly spaced offsets, first to last, so ``val/loss`` is comparable
  across epochs and covers early (exploring) and late (converged) stretches of learning.

It implements the data contract (``data_contract.PreferenceData``): ``context_kind`` ``reward_trajectory``,
the sizes the CLI links into the model, and no held-out evaluation suites (``offers`` is empty): AD is evaluated
online across episodes by ``evaluation.ad_rollout``, not from a stored context. One process: under several
processes every rank would draw its own windows (nothing is sharded).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec, Context, RewardTrajectoryContext
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.store import (
    StoredDataset,
    check_replaceable_dataset,
    dataset_lock,
    load_dataset,
    write_dataset,
)
from icprl_lightning.data_contract import EVALUATIONS
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.learning_histories import QLearningHistories
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_int

KIND = "reward_trajectory"
FIELDS = ("states", "actions", "rewards")  # what a window serves: (s_h, a_h, r_h)
SPLITS = ("train", "val")


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


class LearningHistoryDataModule(L.LightningDataModule):
    """Learning histories of ``learner`` on ``family``'s training goals, served as windows; see the module docstring.

    Args:
        family: the DarkRoom family (its ``seed`` fixes the goal split and every draw of the histories).
        learner: the source learner whose histories AD distills.
        histories_per_goal: independent learner runs per training goal in ``train``.
        val_histories_per_goal: more runs per training goal in ``val`` (the validation loss).
        context_episodes: the window, in episodes: ``context_length`` = ``context_episodes`` · H steps (the
            model's ``max_context``).
        windows_per_epoch: training windows per epoch (drawn afresh each epoch).
        val_windows_per_history: fixed validation windows per val history.
        batch_size: windows per batch.
        data_dir: the dataset directory; by default one named by the config under ``root_dir``.
        overwrite: regenerate even when the dataset exists.
        verify_checksums: check every file's SHA-256 when loading.
        progress: say when the histories are generated (as the other DataModules do).
    """

    pairs = False          # a window is its own context and its own targets: nothing served beside it
    query_labels = False
    offers: frozenset[str] = frozenset()  # evaluated online across episodes (evaluation/ad_rollout.py)

    def __init__(self, family: DarkRoomFamily, learner: QLearningHistories | None = None,
                 histories_per_goal: int = 2, val_histories_per_goal: int = 1, context_episodes: int = 2,
                 windows_per_epoch: int = 2048, val_windows_per_history: int = 4, batch_size: int = 16,
                 data_dir: str | None = None, root_dir: str = "data", overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        owner = type(self).__name__
        if not isinstance(family, DarkRoomFamily):
            raise HyperparameterError(f"{owner}: family must be a DarkRoomFamily (the tabular learner's grid), got "
                                      f"{type(family).__name__}")
        learner = QLearningHistories() if learner is None else learner
        if not isinstance(learner, QLearningHistories):
            raise HyperparameterError(f"{owner}: learner must be a QLearningHistories, got {type(learner).__name__}")
        for key, value in (("histories_per_goal", histories_per_goal),
                           ("val_histories_per_goal", val_histories_per_goal),
                           ("context_episodes", context_episodes), ("windows_per_epoch", windows_per_epoch),
                           ("val_windows_per_history", val_windows_per_history), ("batch_size", batch_size)):
            check_int(owner, key, value, 1)
        if context_episodes > learner.episodes:
            raise HyperparameterError(f"{owner}: context_episodes must be <= the learner's episodes "
                                      f"({learner.episodes}): a window lies inside one history, got {context_episodes}")
        super().__init__()
        self.family, self.learner = family, learner
        self.histories_per_goal, self.val_histories_per_goal = histories_per_goal, val_histories_per_goal
        self.context_episodes = context_episodes
        self.windows_per_epoch, self.val_windows_per_history = windows_per_epoch, val_windows_per_history
        self.batch_size = batch_size
        self.data_dir, self.root_dir = data_dir, root_dir
        self.overwrite, self.verify_checksums, self.progress = overwrite, verify_checksums, progress
        self.dataset: StoredDataset | None = None

    # ---- the data contract (data_contract.PreferenceData) ----------------------------------------------
    @property
    def context_kind(self) -> str:
        return KIND

    @property
    def state_dim(self) -> int:
        return self.family.obs_dim

    @property
    def action_spec(self) -> ActionSpec:
        return self.family.action_spec

    @property
    def context_length(self) -> int:
        """Steps per window (the model's ``max_context``): ``context_episodes`` · H."""
        return self.context_episodes * self.family.horizon

    @property
    def metric_env(self) -> str:
        return self.family.metric_env

    def batch_fields(self) -> tuple[str, ...]:
        return FIELDS

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training histories' ``states``, ``actions`` and ``rewards`` (memory-mapped)."""
        train = self.load()["train"]
        return {k: train[k] for k in FIELDS}

    def evaluation_suites(self) -> list:
        """None: AD deploys online across episodes (``evaluation.ad_rollout``), not on a stored context."""
        return []

    def bandit_suites(self) -> list:
        raise ValueError(f"learning histories offer no bandit_suites; it needs {EVALUATIONS['bandit_suites']}")

    def heldout_pairs(self) -> dict[str, ContextSamples]:
        raise ValueError(f"learning histories offer no heldout_pairs; it needs {EVALUATIONS['heldout_pairs']}")

    # ---- storage -------------------------------------------------------------------------------------
    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.learner.config(), "setting": "LearningHistories",
                "histories_per_goal": self.histories_per_goal, "val_histories_per_goal": self.val_histories_per_goal}

    @property
    def path(self) -> Path:
        if self.data_dir is not None:
            return Path(self.data_dir)
        digest = hashlib.sha256(json.dumps(self.generator_config(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root_dir) / f"{self.family.name}-learning_history-{digest}"

    @property
    def regenerate_hint(self) -> str:
        return f"delete {self.path} (or pass --data.init_args.overwrite true); fit generates a missing dataset"

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        """The ``train`` and ``val`` splits (one seed stream each, from ``family.seed``) and the manifest's info."""
        goals = self.family.train_goals
        splits, info = {}, {}
        streams = np.random.SeedSequence(self.family.seed).spawn(len(SPLITS))
        for split, per_goal, seq in zip(SPLITS, (self.histories_per_goal, self.val_histories_per_goal), streams,
                                        strict=True):
            task_index = np.repeat(np.arange(len(goals)), per_goal)
            history = self.learner.run(self.family, goals[task_index], np.random.default_rng(seq))
            history["actions"] = history["actions"].astype(np.int16)
            history["task_index"] = task_index.astype(np.int32)
            splits[split] = history
            returns = history["episode_returns"].mean(0)
            info[split] = {"first_episode_return": float(returns[0]), "last_episode_return": float(returns[-1])}
        return splits, {"mean_episode_return": info}

    def prepare_data(self) -> None:
        path = self.path
        with dataset_lock(path):  # a second process waits here, then finds the dataset made by the first
            if not self.overwrite and (path.exists() or path.is_symlink()):
                self._read(verify=False)
                return
            check_replaceable_dataset(path)
            if self.progress:  # one line: the whole generation takes about a second
                print(f"generating learning histories -> {path}", flush=True)
            splits, info = self.generate()
            write_dataset(path, splits, self.generator_config(), info=info, overwrite=True)
        self.overwrite = False

    def _read(self, verify: bool) -> StoredDataset:
        data = load_dataset(self.path, self.generator_config(), verify=verify, regenerate_hint=self.regenerate_hint)
        data.require(dict.fromkeys(SPLITS, [*FIELDS, "episode_returns", "task_index"]), self.regenerate_hint)
        return data

    def load(self) -> StoredDataset:
        if self.dataset is None:
            self.dataset = self._read(verify=self.verify_checksums)
        return self.dataset

    # ---- batches -------------------------------------------------------------------------------------
    def val_offsets(self) -> np.ndarray:
        """(row, offset) of every validation window [M, 2]: evenly spaced offsets in each val history."""
        rows, steps = self.load()["val"]["actions"].shape
        starts = np.linspace(0, steps - self.context_length, self.val_windows_per_history).astype(np.int64)
        return np.stack(np.meshgrid(np.arange(rows), starts, indexing="ij"), axis=-1).reshape(-1, 2)

    def train_dataloader(self) -> DataLoader:
        data = HistoryWindows(self.load()["train"], self.context_length, self.histories_per_goal,
                              self.windows_per_epoch)
        sampler = BatchSampler(RandomSampler(data), self.batch_size, drop_last=len(data) >= self.batch_size)
        return DataLoader(data, sampler=sampler, batch_size=None)

    def val_dataloader(self) -> DataLoader:
        data = HistoryWindows(self.load()["val"], self.context_length, self.val_histories_per_goal, 0,
                              self.val_offsets())
        return DataLoader(data, sampler=BatchSampler(SequentialSampler(data), self.batch_size, drop_last=False),
                          batch_size=None)

