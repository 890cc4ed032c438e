"""Meta-World Reach T-PRL datasets as a LightningDataModule (paper, appendix "Pretraining Data Generation",
Meta-World T-PRL).

Two kinds over the *same* trajectories (same seed, same bytes of states and actions; ``data/tprl.py``):

* ``trajectory_preference`` — the reward-free T-PRL data of DP²T, RewardGen and ICRG: pairs (ξ_a, ξ_b)
  of behavior-policy rollouts with a Bradley–Terry label on their return difference, no rewards, goals
  or expert values anywhere in the dataset (the expert's actions at visited query states are served
  only with ``query_labels``, DP²T's supervision);
* ``reward_trajectory`` — the same trajectories with their true per-step rewards and no labels: the
  reward-supervised DIT baseline's data (an oracle, as DPT's reward contexts are).

Behavior policies are the oracle's expert/uniform mixtures (``oracles/metaworld_reach.py``). One
calibration run finds the mixing probability for each normalized-return target: low/medium/high
(``quality_targets``, 20/40/80%) and ``tprl_quality`` (50%, the paper's T-PRL pretraining policy), stored
in the manifest's ``calibration`` under ``low``, ``medium``, ``high`` and ``pretraining``.

Splits written to disk (see ``data/store.py``), task-major:

* ``tasks``: ``train_goals`` [45, 3], ``test_goals`` [5, 3] — read only by evaluation, never batched;
* ``train`` / ``val``: ``trajectories_per_task`` / ``val_trajectories_per_task`` pairs per training goal,
  both trajectories from the 50% policy (``quality`` = 3, ``PRETRAINING``), with query states and the
  expert's actions there, ``task_index`` and ``quality``;
* ``eval_low`` / ``eval_medium`` / ``eval_high``: pairs on the held-out goals plus the unlabeled behavior
  trajectory ICRG labels at deployment, all three rollouts from π_q (``quality`` = 0, 1, 2).

With ``pairs=True`` a training sample also carries another pair of the same task (``pair_*`` fields):
RewardGen's context when it scores a pair it cannot see, and ICRG's context when it relabels one.
The manifest records the calibration, the label agreement and tie fraction (train and per evaluation
quality), and the held-out references of ``ReachDataModule`` (return, success and normalized return of
π_low/π_medium/π_high, the expert and the uniform policy), which the rollout callback logs beside the
method's return, normalized return and success rate.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.data.metaworld_reach_tprl import DEFAULT_TPRL_BT_TEMPERATURE, generate_trajectory_preferences
from icprl_lightning.data.reach_datamodule import QUALITIES, ReachDataModule
from icprl_lightning.data.tprl import TrajectoryPreferenceData
from icprl_lightning.envs.metaworld_reach import HORIZON

PRETRAINING = len(QUALITIES)  # ``quality`` of the training pairs: the calibrated 50% policy


class ReachTPRLDataModule(TrajectoryPreferenceData, ReachDataModule):
    """Meta-World Reach T-PRL data; see the module docstring.

    Args:
        bt_temperature: Bradley–Terry temperature on return differences (the paper's 1; the default dataset's
            label agreement is 0.918, see ``data/metaworld_reach_tprl.py``).
        tprl_quality: normalized return of the behavior policy of the training pairs (paper: 50%).
        The other T-PRL arguments as ``TrajectoryPreferenceData``, the rest as ``ReachDataModule``.
    """

    def __init__(self, context_kind: str = "trajectory_preference", trajectories_per_task: int = 10,
                 val_trajectories_per_task: int = 2, eval_contexts_per_task: int = 4,
                 bt_temperature: float = DEFAULT_TPRL_BT_TEMPERATURE, tprl_quality: float = 0.5,
                 quality_targets: tuple[float, float, float] = (0.2, 0.4, 0.8), horizon: int = HORIZON,
                 n_train_tasks: int = 45, n_test_tasks: int = 5, calibration_episodes: int = 8,
                 reference_episodes: int = 6, num_workers: int = 2, seed: int = 0, data_dir: str | None = None,
                 root_dir: str = "data", batch_size: int = 32, pairs: bool = False, query_labels: bool = False,
                 overwrite: bool = False, verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__(context_kind=context_kind, trajectories_per_task=trajectories_per_task,
                         val_trajectories_per_task=val_trajectories_per_task,
                         eval_contexts_per_task=eval_contexts_per_task, bt_temperature=bt_temperature,
                         quality_targets=quality_targets, horizon=horizon, n_train_tasks=n_train_tasks,
                         n_test_tasks=n_test_tasks, calibration_episodes=calibration_episodes,
                         reference_episodes=reference_episodes, num_workers=num_workers, seed=seed,
                         data_dir=data_dir, root_dir=root_dir, batch_size=batch_size, pairs=pairs,
                         query_labels=query_labels, overwrite=overwrite, verify_checksums=verify_checksums,
                         progress=progress)
        self.tprl_quality = tprl_quality

    def generator_config(self) -> dict[str, Any]:
        return {**super().generator_config(), "setting": "T-PRL", "tprl_quality": self.tprl_quality}

    def calibration_targets(self) -> dict[str, float]:
        return {**self.quality_targets, "pretraining": self.tprl_quality}

    def _split(self, goals: np.ndarray, n_per_task: int, p: np.ndarray, rng: np.random.Generator, description: str,
               quality: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """One T-PRL pair per row; evaluation rows (``quality`` given) also roll out the behavior trajectory."""
        task_index = np.repeat(np.arange(len(goals)), n_per_task).astype(np.int32)
        qual = np.full(len(task_index), PRETRAINING if quality is None else quality, dtype=np.int8)
        arrays, rewards, stats = generate_trajectory_preferences(
            self.family, goals[task_index], p[qual], self.bt_temperature, rng, behavior=quality is not None,
            num_workers=self.num_workers, progress=self.progress, description=description)
        arrays = self.stored_arrays(arrays, rewards)
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats
