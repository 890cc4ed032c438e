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

What it shares with ``data/duel_histories.py`` (the ``HistoryWindows`` Dataset, the storage, the loaders and
the refusals of the data contract) is ``HistoryWindowDataModule`` (``data/history_windows.py``); here are the
learner, the goals, the windows' length and the stored arrays. It implements the data contract
(``data_contract.PreferenceData``): ``context_kind`` ``reward_trajectory``, the sizes the CLI links into the model,
and no held-out evaluation suites (``offers`` is empty): AD is evaluated online across episodes by
``evaluation.ad_rollout``, not from a stored context. One process: under several processes every rank would draw
its own windows (nothing is sharded).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from torch import Tensor

from icprl_lightning.contexts import Context
from icprl_lightning.data.history_windows import FIELDS, HistoryWindowDataModule, HistoryWindows, reward_trajectory
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.learning_histories import QLearningHistories
from icprl_lightning.validation import HyperparameterError

__all__ = ["HistoryWindows", "LearningHistoryDataModule"]  # HistoryWindows still importable from its old home

KIND = "reward_trajectory"
SPLITS = ("train", "val")


class LearningHistoryDataModule(HistoryWindowDataModule):
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

    family_type = DarkRoomFamily
    family_note = " (the tabular learner's grid)"
    learner_type = QLearningHistories
    kind = KIND
    fields = FIELDS  # what a window serves: (s_h, a_h, r_h)
    served = FIELDS
    store_name = "learning_history"
    histories = "learning histories"
    generating = "learning histories"  # one line: the whole generation takes about a second

    def __init__(self, family: DarkRoomFamily, learner: QLearningHistories | None = None,
                 histories_per_goal: int = 2, val_histories_per_goal: int = 1, context_episodes: int = 2,
                 windows_per_epoch: int = 2048, val_windows_per_history: int = 4, batch_size: int = 16,
                 data_dir: str | None = None, root_dir: str = "data", overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        counts = {"histories_per_goal": histories_per_goal, "val_histories_per_goal": val_histories_per_goal,
                  "context_episodes": context_episodes}
        super().__init__(family, learner, counts, windows_per_epoch, val_windows_per_history, batch_size, data_dir,
                         root_dir, overwrite, verify_checksums, progress)
        if context_episodes > self.learner.episodes:
            raise HyperparameterError(f"{type(self).__name__}: context_episodes must be <= the learner's episodes "
                                      f"({self.learner.episodes}): a window lies inside one history, got "
                                      f"{context_episodes}")
        self.histories_per_goal, self.val_histories_per_goal = histories_per_goal, val_histories_per_goal
        self.context_episodes = context_episodes

    @property
    def context_length(self) -> int:
        """Steps per window (the model's ``max_context``): ``context_episodes`` · H."""
        return self.context_episodes * self.family.horizon

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training histories' ``states``, ``actions`` and ``rewards`` (memory-mapped)."""
        train = self.load()["train"]
        return {k: train[k] for k in FIELDS}

    # ---- storage -------------------------------------------------------------------------------------
    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.learner.config(), "setting": "LearningHistories",
                "histories_per_goal": self.histories_per_goal, "val_histories_per_goal": self.val_histories_per_goal}

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

    def required_fields(self) -> dict[str, list[str]]:
        return dict.fromkeys(SPLITS, [*FIELDS, "episode_returns", "task_index"])

    # ---- batches -------------------------------------------------------------------------------------
    def histories_per_task(self, split: str) -> int:
        return {"train": self.histories_per_goal, "val": self.val_histories_per_goal}[split]

    def window_context(self, window: dict[str, Tensor]) -> Context:
        return reward_trajectory(window)
