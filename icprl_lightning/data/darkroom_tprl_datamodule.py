"""DarkRoom T-PRL datasets as a LightningDataModule (paper, appendix "Pretraining Data Generation", T-PRL).

Two kinds over the *same* trajectories (same seed, same bytes of states and actions):

* ``trajectory_preference`` — the reward-free T-PRL data of DP²T, RewardGen and ICRG: pairs (ξ_a, ξ_b)
  of mixed-policy rollouts with a Bradley–Terry label, no rewards anywhere in the dataset;
* ``reward_trajectory`` — the same trajectories with their true per-step rewards and no labels: the
  reward-supervised DIT baseline's data (an oracle, as DPT's reward contexts are).

Splits written to disk (see ``data/store.py``), task-major like the I-PRL data:

* ``tasks``: ``train_goals`` [80, 2], ``test_goals`` [20, 2] — read only by evaluation, never batched;
* ``train`` / ``val``: ``trajectories_per_task`` / ``val_trajectories_per_task`` pairs per training goal,
  pair j of a task rolled out at quality j mod 3 (both trajectories), with query states and their
  optimal actions (served only with ``query_labels``, for DP²T), ``task_index`` and ``quality``;
* ``eval_low`` / ``eval_medium`` / ``eval_high``: pairs on the held-out goals plus the unlabeled behavior
  trajectory ICRG labels at deployment, all three rollouts at that quality.

With ``pairs=True`` a training sample also carries another pair of the same task (``pair_*`` fields):
RewardGen's context when it scores a pair it cannot see, and ICRG's context when it relabels one.
The manifest records the calibration, the label agreement and tie fraction (train and per evaluation
quality) and the behavior and optimal returns on the held-out goals.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.data.darkroom import query_labels
from icprl_lightning.data.darkroom_datamodule import DarkRoomDataModule
from icprl_lightning.data.darkroom_tprl import generate_trajectory_preferences
from icprl_lightning.data.tprl import TrajectoryPreferenceData


class DarkRoomTPRLDataModule(TrajectoryPreferenceData, DarkRoomDataModule):
    """DarkRoom T-PRL data; see the module docstring.

    Args:
        bt_temperature: Bradley–Terry temperature on return differences (paper: 1; nearly deterministic
            on DarkRoom's 0–95 returns, see ``data/darkroom_tprl.py``).
        The other T-PRL arguments as ``TrajectoryPreferenceData``, the rest as ``DarkRoomDataModule``.
    """

    def __init__(self, context_kind: str = "trajectory_preference", trajectories_per_task: int = 60,
                 val_trajectories_per_task: int = 4, eval_contexts_per_task: int = 5, bt_temperature: float = 1.0,
                 quality_targets: tuple[float, float, float] = (0.2, 0.4, 0.8), size: int = 10, horizon: int = 100,
                 n_train_tasks: int = 80, n_test_tasks: int = 20, terminate_on_goal: bool = False,
                 calibration_episodes: int = 25, seed: int = 0, data_dir: str | None = None, root_dir: str = "data",
                 batch_size: int = 32, pairs: bool = False, query_labels: bool = False, overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__(context_kind=context_kind, trajectories_per_task=trajectories_per_task,
                         val_trajectories_per_task=val_trajectories_per_task,
                         eval_contexts_per_task=eval_contexts_per_task, bt_temperature=bt_temperature,
                         quality_targets=quality_targets, size=size, horizon=horizon, n_train_tasks=n_train_tasks,
                         n_test_tasks=n_test_tasks, terminate_on_goal=terminate_on_goal,
                         calibration_episodes=calibration_episodes, seed=seed, data_dir=data_dir, root_dir=root_dir,
                         batch_size=batch_size, pairs=pairs, query_labels=query_labels, overwrite=overwrite,
                         verify_checksums=verify_checksums, progress=progress)

    def generator_config(self) -> dict[str, Any]:
        return {**super().generator_config(), "setting": "T-PRL"}

    def _split(self, goals: np.ndarray, n_per_task: int, p_by_quality: np.ndarray, rng: np.random.Generator,
               description: str, quality: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """One T-PRL pair per row; evaluation rows (``quality`` given) also roll out the behavior trajectory."""
        task_index, qual = self._task_rows(len(goals), n_per_task, quality)
        arrays, rewards, stats = generate_trajectory_preferences(
            self.family, goals[task_index], p_by_quality[qual], self.bt_temperature, rng,
            behavior=quality is not None, progress=self.progress, description=description)
        arrays = self.stored_arrays(arrays, rewards)
        arrays.update(query_labels(self.family, goals[task_index], rng))
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats
