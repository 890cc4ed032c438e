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
import torch
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler

from icprl_lightning.data.contexts import RewardTrajectoryContext
from icprl_lightning.data.darkroom import query_labels
from icprl_lightning.data.darkroom_datamodule import DarkRoomDataModule
from icprl_lightning.data.darkroom_tprl import PAIR_FIELDS, generate_trajectory_preferences
from icprl_lightning.data.datamodule import ContextBatches, to_tensor
from icprl_lightning.evaluation import mean_sem, per_task_mean
from icprl_lightning.oracles.darkroom import QUALITIES, calibrate_mixing, rollout_returns

LABELED_FIELDS = ("states_a", "actions_a", "rewards_a", "states_b", "actions_b", "rewards_b")


def other_rows(rows: np.ndarray, per_task: int, shift: np.ndarray | int) -> np.ndarray:
    """Row of the pair ``shift`` places after each row's, within the same task (task-major storage)."""
    j = rows % per_task
    return rows - j + (j + shift) % per_task


class TrajectoryPairBatches(ContextBatches):
    """Whole batches of T-PRL pairs; with ``pairs`` also another pair of the same task as ``pair_*``."""

    def __init__(self, arrays: dict[str, np.ndarray], fields: tuple[str, ...], trajectories_per_task: int,
                 pairs: bool, query_labels: bool) -> None:
        super().__init__(arrays, fields, trajectories_per_task, pairs=False, query_labels=query_labels)
        if pairs and trajectories_per_task < 2:
            raise ValueError("another pair of the same task needs trajectories_per_task >= 2")
        self.other_pairs = pairs

    def __len__(self) -> int:
        return len(self.arrays["states_a"])

    def __getitem__(self, index: list[int]) -> dict[str, torch.Tensor]:
        batch = super().__getitem__(index)
        if self.other_pairs:
            idx = np.sort(np.asarray(index))
            other = other_rows(idx, self.per_task, torch.randint(1, self.per_task, (len(idx),)).numpy())
            for k in PAIR_FIELDS:
                batch[f"pair_{k}"] = to_tensor(self.arrays[k][other])
        return batch


class DarkRoomTPRLDataModule(DarkRoomDataModule):
    """DarkRoom T-PRL data; see the module docstring.

    Args:
        context_kind: ``trajectory_preference`` (DP²T, RewardGen, ICRG) or ``reward_trajectory`` (DIT
            on true rewards).
        trajectories_per_task: T-PRL pairs per training goal (paper: 5000).
        val_trajectories_per_task: extra pairs per training goal for the validation loss.
        eval_contexts_per_task: contexts (= evaluation episodes) per held-out goal and quality; RewardGen's
            held-out pair accuracy scores each against the next one of its goal, so use at least 2.
        bt_temperature: Bradley–Terry temperature on return differences (paper: 1; nearly deterministic
            on DarkRoom's 0–95 returns, see ``data/darkroom_tprl.py``).
        Other arguments as ``DarkRoomDataModule``.
    """

    context_kinds = ("trajectory_preference", "reward_trajectory")

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

    def _pair_split(self, goals: np.ndarray, n_per_task: int, p_by_quality: np.ndarray, rng: np.random.Generator,
                    description: str, quality: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        task_index = np.repeat(np.arange(len(goals)), n_per_task).astype(np.int32)
        qual = (np.tile(np.arange(n_per_task) % 3, len(goals)) if quality is None
                else np.full(len(task_index), quality)).astype(np.int8)
        arrays, rewards, stats = generate_trajectory_preferences(
            self.family, goals[task_index], p_by_quality[qual], self.bt_temperature, rng,
            behavior=quality is not None, progress=self.progress, description=description)
        if self.kind == "reward_trajectory":
            arrays.update(rewards)
            del arrays["preferred"]
        arrays.update(query_labels(self.family, goals[task_index], rng))
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        rng = np.random.default_rng(self.seed)
        calibration = calibrate_mixing(self.family, self.quality_targets, self.calibration_episodes,
                                       seed=int(rng.integers(2**31)))
        p = np.array([calibration[q]["p_optimal"] for q in QUALITIES])
        train_goals, test_goals = self.family.train_goals, self.family.test_goals
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {"train_goals": train_goals, "test_goals": test_goals}}
        splits["train"], train_stats = self._pair_split(train_goals, self.per_task[0], p, rng, "train pairs")
        splits["val"], _ = self._pair_split(train_goals, self.per_task[1], p, rng, "val pairs")
        reference: dict[str, dict[str, float]] = {}
        eval_stats: dict[str, dict[str, float]] = {}
        for qi, q in enumerate(QUALITIES):
            splits[f"eval_{q}"], eval_stats[q] = self._pair_split(test_goals, self.eval_per_task, p, rng,
                                                                  f"eval {q}", quality=qi)
            goals = np.repeat(test_goals, self.calibration_episodes, axis=0)
            ret, opt = rollout_returns(self.family, goals, np.full(len(goals), p[qi]), rng)
            tasks = np.repeat(np.arange(len(test_goals)), self.calibration_episodes)
            b_mean, b_sem = mean_sem(per_task_mean(ret, tasks))
            o_mean, _ = mean_sem(per_task_mean(opt, tasks))
            reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem, "optimal_return": o_mean}
        info = {"calibration": calibration, "train_statistics": train_stats, "eval_statistics": eval_stats,
                "test_reference": reference}
        return splits, info

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        per_task = self.trajectories_per_task[0 if split == "train" else 1]
        fields = PAIR_FIELDS if self.kind == "trajectory_preference" else LABELED_FIELDS
        data = TrajectoryPairBatches(self.load()[split], fields, per_task, self.pairs, self.query_labels)
        base = RandomSampler(data) if shuffle else SequentialSampler(data)
        return DataLoader(data, sampler=BatchSampler(base, self.batch_size, drop_last=shuffle), batch_size=None)

    def eval_context(self, arrays: dict[str, Any]):
        if self.kind == "reward_trajectory":
            return RewardTrajectoryContext(arrays["behavior_states"], arrays["behavior_actions"],
                                           arrays["behavior_rewards"])
        return super().eval_context(arrays)

    def heldout_pairs(self) -> dict[str, dict[str, torch.Tensor]]:
        """Per quality, the held-out goals' pairs, each with another pair of its goal as ``pair_*``.

        The context pair is the next evaluation context of the same goal and quality (the pair itself
        when there is only one per goal). RewardGen's held-out pair accuracy is measured on these.
        """
        if self.kind != "trajectory_preference":
            raise ValueError("held-out pairs exist in trajectory_preference datasets only")
        data = self.load()
        out = {}
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            rows = np.arange(len(split["preferred"]))
            other = other_rows(rows, self.eval_per_task, 1)
            batch = {k: to_tensor(np.asarray(split[k])) for k in PAIR_FIELDS}
            batch.update({f"pair_{k}": to_tensor(np.asarray(split[k])[other]) for k in PAIR_FIELDS})
            out[q] = batch
        return out
