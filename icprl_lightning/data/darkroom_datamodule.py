"""DarkRoom datasets as a LightningDataModule: I-PRL step preferences or DPT reward contexts.

Splits written to disk (see ``data/store.py``):

* ``tasks``: ``train_goals`` [80, 2], ``test_goals`` [20, 2] — read only by evaluation, never batched;
* ``train`` / ``val``: contexts on the training goals (``val`` are extra trajectories of the same goals,
  for the validation loss), task-major, with ``task_index`` and ``quality`` per trajectory;
* ``eval_low`` / ``eval_medium`` / ``eval_high``: contexts on the held-out goals, one quality each.

Training contexts cycle through the three calibrated qualities (trajectory j of a task has quality
j mod 3). The manifest records the calibration, the label agreement rate, and the behavior and optimal
returns on the held-out goals (the references logged beside the methods' returns).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec, context_from_batch
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.darkroom import generate_reward_contexts, generate_step_preferences, query_labels
from icprl_lightning.data.datamodule import InContextDataModule
from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.envs.darkroom import N_ACTIONS, DarkRoomFamily
from icprl_lightning.metrics import mean_sem, per_task_mean
from icprl_lightning.oracles.darkroom import QUALITIES, calibrate_mixing, rollout_returns


class DarkRoomDataModule(InContextDataModule):
    """DarkRoom I-PRL (``context_kind="step_preference"``) or reward-context (``"reward"``) data.

    Args:
        context_kind: ``step_preference`` (DP²T, ICPO) or ``reward`` (DPT).
        trajectories_per_task: training contexts per training goal (paper: 1000).
        val_trajectories_per_task: extra contexts per training goal for the validation loss.
        eval_contexts_per_task: contexts (= evaluation episodes) per held-out goal and quality.
        bt_temperature: Bradley–Terry temperature of the step labels (paper: 1).
        quality_targets: share of the optimal return the low/medium/high behavior policies earn.
        terminate_on_goal: the paper's "episode ends at the goal" convention (see ``envs/darkroom.py``).
        seed: seeds the goal split, calibration and all sampling.
    """

    family_name = "darkroom"
    metric_env = "darkroom"
    context_kinds: tuple[str, ...] = ("step_preference", "reward")  # T-PRL: DarkRoomTPRLDataModule

    def __init__(self, context_kind: str = "step_preference", trajectories_per_task: int = 100,
                 val_trajectories_per_task: int = 4, eval_contexts_per_task: int = 5, bt_temperature: float = 1.0,
                 quality_targets: tuple[float, float, float] = (0.2, 0.4, 0.8), size: int = 10, horizon: int = 100,
                 n_train_tasks: int = 80, n_test_tasks: int = 20, terminate_on_goal: bool = False,
                 calibration_episodes: int = 25, seed: int = 0, data_dir: str | None = None, root_dir: str = "data",
                 batch_size: int = 32, pairs: bool = False, query_labels: bool = False, overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__(data_dir=data_dir, root_dir=root_dir, batch_size=batch_size, pairs=pairs,
                         query_labels=query_labels, overwrite=overwrite, verify_checksums=verify_checksums,
                         progress=progress)
        if context_kind not in self.context_kinds:
            raise ValueError(f"context_kind must be one of {list(self.context_kinds)}, got {context_kind!r}")
        self.kind = context_kind
        self.family = DarkRoomFamily(size=size, horizon=horizon, n_train_tasks=n_train_tasks,
                                     n_test_tasks=n_test_tasks, terminate_on_goal=terminate_on_goal, seed=seed)
        self.per_task = (trajectories_per_task, val_trajectories_per_task)
        self.eval_per_task = eval_contexts_per_task
        self.bt_temperature = bt_temperature
        self.quality_targets = dict(zip(QUALITIES, quality_targets, strict=True))
        self.calibration_episodes = calibration_episodes
        self.seed = seed

    @property
    def context_kind(self) -> str:
        return self.kind

    @property
    def state_dim(self) -> int:
        return DarkRoomFamily.obs_dim

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=True, size=N_ACTIONS)

    def generator_config(self) -> dict[str, Any]:
        f = self.family
        return {"family": "darkroom", "context_kind": self.kind, "size": f.size, "horizon": f.horizon,
                "n_train_tasks": f.n_train_tasks, "n_test_tasks": f.n_test_tasks,
                "terminate_on_goal": f.terminate_on_goal, "trajectories_per_task": self.per_task[0],
                "val_trajectories_per_task": self.per_task[1], "eval_contexts_per_task": self.eval_per_task,
                "bt_temperature": self.bt_temperature, "quality_targets": self.quality_targets,
                "calibration_episodes": self.calibration_episodes, "seed": self.seed}

    def _contexts(self, goals: np.ndarray, p: np.ndarray, rng: np.random.Generator,
                  description: str) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        if self.kind == "reward":
            return generate_reward_contexts(self.family, goals, p, rng, self.progress, description)
        return generate_step_preferences(self.family, goals, p, self.bt_temperature, rng, self.progress, description)

    def _split(self, goals: np.ndarray, n_per_task: int, p_by_quality: np.ndarray, rng: np.random.Generator,
               description: str, quality: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        task_index, qual = self._task_rows(len(goals), n_per_task, quality)
        arrays, stats = self._contexts(goals[task_index], p_by_quality[qual], rng, description)
        arrays.update(query_labels(self.family, goals[task_index], rng))
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats

    @staticmethod
    def _task_rows(n_tasks: int, n_per_task: int, quality: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Task-major rows: the task of each row, and its quality (row j of a task cycles j mod 3)."""
        task_index = np.repeat(np.arange(n_tasks), n_per_task).astype(np.int32)
        qual = (np.tile(np.arange(n_per_task) % 3, n_tasks) if quality is None
                else np.full(len(task_index), quality)).astype(np.int8)
        return task_index, qual

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        rng = np.random.default_rng(self.seed)
        calibration = calibrate_mixing(self.family, self.quality_targets, self.calibration_episodes,
                                       seed=int(rng.integers(2**31)))
        p = np.array([calibration[q]["p_optimal"] for q in QUALITIES])
        train_goals, test_goals = self.family.train_goals, self.family.test_goals
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {"train_goals": train_goals, "test_goals": test_goals}}
        splits["train"], train_stats = self._split(train_goals, self.per_task[0], p, rng, "train contexts")
        splits["val"], _ = self._split(train_goals, self.per_task[1], p, rng, "val contexts")
        reference: dict[str, dict[str, float]] = {}
        eval_stats: dict[str, dict[str, float]] = {}
        for qi, q in enumerate(QUALITIES):
            splits[f"eval_{q}"], eval_stats[q] = self._split(test_goals, self.eval_per_task, p, rng, f"eval {q}",
                                                             quality=qi)
            goals = np.repeat(test_goals, self.calibration_episodes, axis=0)
            ret, opt = rollout_returns(self.family, goals, np.full(len(goals), p[qi]), rng)
            tasks = np.repeat(np.arange(len(test_goals)), self.calibration_episodes)
            b_mean, b_sem = mean_sem(per_task_mean(ret, tasks))
            o_mean, _ = mean_sem(per_task_mean(opt, tasks))
            reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem, "optimal_return": o_mean}
        info = {"calibration": calibration, "train_statistics": train_stats, "eval_statistics": eval_stats,
                "test_reference": reference}
        return splits, info

    def eval_context(self, arrays: dict[str, Any]):
        """The typed deployment context of an evaluation split's arrays."""
        return context_from_batch(self.kind, arrays)

    def evaluation_suites(self) -> list[EvalSuite]:
        data = self.load()
        test_goals = np.asarray(data["tasks"]["test_goals"])
        reference = data.manifest["info"]["test_reference"]
        suites = []
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            arrays = {k: to_tensor(np.asarray(v)) for k, v in split.items()}
            goals = test_goals[np.asarray(split["task_index"])]
            optimal = reference[q]["optimal_return"]
            suites.append(EvalSuite(
                env_name=self.metric_env, quality=q, context=self.eval_context(arrays),
                make_env=lambda goals=goals: self.family.make_env(goals),
                task_index=np.asarray(split["task_index"]), horizon=self.family.horizon,
                reference=reference[q], normalize=lambda r, optimal=optimal: r / optimal))
        return suites
