"""Meta-World Reach datasets as a LightningDataModule: I-PRL step preferences or DPT reward contexts.

Splits written to disk (see ``data/store.py``):

* ``tasks``: ``train_goals`` [45, 3], ``test_goals`` [5, 3] — read only by evaluation, never batched;
* ``train`` / ``val``: contexts on the training goals (``val`` are extra trajectories of the same goals,
  for the validation loss), task-major, with ``task_index`` and ``quality`` per trajectory;
* ``eval_low`` / ``eval_medium`` / ``eval_high``: contexts on the held-out goals, one quality each.

Behavior policies are the oracle's mixtures (expert with probability p, else uniform), p calibrated at
generation to 20/40/80% of the expert's normalized return (the calibration is in the manifest).

Which policies a context comes from (``quality`` stores the index of the second policy):

* I-PRL pretraining: every step compares a low (20%) action with a high (80%) action (paper, appendix
  "Pretraining Data Generation"), so all training contexts have quality ``high``.
* I-PRL evaluation at quality q compares a low-policy action with a q-policy action (for q = low both
  come from the 20% policy): the pretraining pair with its better side swapped for π_q.
* Reward contexts: rollouts of one behavior policy; training trajectory j of a task has quality j mod 3.

The manifest also records the label statistics of the training and of each evaluation split (I-PRL: label
agreement rate and tie fraction; reward contexts: mean context return), and for the
held-out goals the return and success rate of each behavior policy π_q, of the expert and of the
uniform policy (``test_reference``; per goal in ``test_reference_per_task``). Normalized return is
(R − R_uniform) / (R_expert − R_uniform) with the episode's own goal's references.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec, context_from_batch
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.datamodule import InContextDataModule
from icprl_lightning.data.metaworld_reach import generate_reward_contexts, generate_step_preferences
from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.envs.metaworld_reach import ACTION_DIM, HORIZON, OBS_DIM, ReachTaskFamily
from icprl_lightning.metrics import mean_sem, per_task_mean
from icprl_lightning.oracles.metaworld_reach import DEFAULT_BT_TEMPERATURE, calibrate_mixing, rollout_returns

QUALITIES = ("low", "medium", "high")
LOW, HIGH = 0, 2


class ReachDataModule(InContextDataModule):
    """Meta-World Reach I-PRL (``context_kind="step_preference"``) or reward-context (``"reward"``) data.

    Args:
        context_kind: ``step_preference`` (DP²T, ICPO) or ``reward`` (DPT).
        trajectories_per_task: training contexts per training goal (paper: 1000).
        val_trajectories_per_task: extra contexts per training goal for the validation loss.
        eval_contexts_per_task: contexts (= evaluation episodes) per held-out goal and quality.
        bt_temperature: Bradley–Terry temperature of the step labels on A differences (see the oracle:
            at 1, the paper's DarkRoom value, Meta-World labels would be coin flips).
        quality_targets: normalized return of the low/medium/high behavior policies.
        calibration_episodes: episodes per policy when calibrating p on the training goals.
        reference_episodes: episodes per held-out goal for the behavior/expert/uniform references.
        num_workers: environment worker processes (does not change the data).
        seed: seeds the goal split (metaworld's ML1 draw), calibration, all sampling and the environments.
    """

    family_name = "metaworld_reach"
    metric_env = "metaworld"
    context_kinds: tuple[str, ...] = ("step_preference", "reward")

    def __init__(self, context_kind: str = "step_preference", trajectories_per_task: int = 20,
                 val_trajectories_per_task: int = 2, eval_contexts_per_task: int = 4,
                 bt_temperature: float = DEFAULT_BT_TEMPERATURE,
                 quality_targets: tuple[float, float, float] = (0.2, 0.4, 0.8), horizon: int = HORIZON,
                 n_train_tasks: int = 45, n_test_tasks: int = 5, calibration_episodes: int = 8,
                 reference_episodes: int = 6, num_workers: int = 2, seed: int = 0, data_dir: str | None = None,
                 root_dir: str = "data", batch_size: int = 32, pairs: bool = False, query_labels: bool = False,
                 overwrite: bool = False, verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__(data_dir=data_dir, root_dir=root_dir, batch_size=batch_size, pairs=pairs,
                         query_labels=query_labels, overwrite=overwrite, verify_checksums=verify_checksums,
                         progress=progress)
        if context_kind not in self.context_kinds:
            raise ValueError(f"context_kind must be one of {list(self.context_kinds)}, got {context_kind!r}")
        self.kind = context_kind
        self.family = ReachTaskFamily(seed=seed, n_train=n_train_tasks, n_test=n_test_tasks, horizon=horizon)
        self.per_task = (trajectories_per_task, val_trajectories_per_task)
        self.eval_per_task = eval_contexts_per_task
        self.bt_temperature = bt_temperature
        self.quality_targets = dict(zip(QUALITIES, quality_targets, strict=True))
        self.calibration_episodes = calibration_episodes
        self.reference_episodes = reference_episodes
        self.num_workers = num_workers
        self.seed = seed

    @property
    def context_kind(self) -> str:
        return self.kind

    @property
    def state_dim(self) -> int:
        return OBS_DIM

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=False, size=ACTION_DIM)

    def generator_config(self) -> dict[str, Any]:
        f = self.family
        return {"family": "metaworld_reach", "env": "reach-v3", "expert": "tcp", "context_kind": self.kind,
                "horizon": f.horizon, "n_train_tasks": f.n_train, "n_test_tasks": f.n_test,
                "trajectories_per_task": self.per_task[0], "val_trajectories_per_task": self.per_task[1],
                "eval_contexts_per_task": self.eval_per_task, "bt_temperature": self.bt_temperature,
                "quality_targets": self.quality_targets, "calibration_episodes": self.calibration_episodes,
                "reference_episodes": self.reference_episodes, "seed": self.seed}

    def _split(self, goals: np.ndarray, n_per_task: int, p: np.ndarray, rng: np.random.Generator, description: str,
               quality: int | None = None) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """Task-major contexts; ``quality`` None: I-PRL (low, high) pairs or reward qualities cycling."""
        task_index = np.repeat(np.arange(len(goals)), n_per_task).astype(np.int32)
        if quality is not None:
            qual = np.full(len(task_index), quality)
        elif self.kind == "reward":
            qual = np.tile(np.arange(n_per_task) % len(QUALITIES), len(goals))
        else:
            qual = np.full(len(task_index), HIGH)
        qual = qual.astype(np.int8)
        kw = dict(num_workers=self.num_workers, progress=self.progress, description=description)
        if self.kind == "reward":
            arrays, stats = generate_reward_contexts(self.family, goals[task_index], p[qual], rng, **kw)
        else:
            arrays, stats = generate_step_preferences(self.family, goals[task_index], np.full(len(qual), p[LOW]),
                                                      p[qual], self.bt_temperature, rng, **kw)
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats

    def _references(self, test_goals: np.ndarray, p: np.ndarray, seed: int) -> tuple[dict, dict]:
        """Returns and success of uniform, π_low, π_medium, π_high and the expert on each held-out goal."""
        goals = np.repeat(test_goals, self.reference_episodes, axis=0)
        tasks = np.repeat(np.arange(len(test_goals)), self.reference_episodes)
        returns, success = rollout_returns(self.family, goals, np.array([0.0, *p, 1.0]), seed, self.num_workers)
        per_task = [per_task_mean(r, tasks) for r in returns]  # uniform, low, medium, high, expert
        uniform, expert = per_task[0], per_task[-1]
        expert_success = mean_sem(per_task_mean(success[-1].astype(float), tasks))[0]
        reference = {}
        for qi, q in enumerate(QUALITIES):
            b_mean, b_sem = mean_sem(per_task[qi + 1])
            reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem,
                            "behavior_success": mean_sem(per_task_mean(success[qi + 1].astype(float), tasks))[0],
                            "behavior_normalized_return": mean_sem((per_task[qi + 1] - uniform)
                                                                   / (expert - uniform))[0],
                            "expert_return": mean_sem(expert)[0], "expert_success": expert_success,
                            "uniform_return": mean_sem(uniform)[0]}
        return reference, {"uniform_return": uniform.tolist(), "expert_return": expert.tolist()}

    def calibration_targets(self) -> dict[str, float]:
        """Normalized returns to calibrate a mixing probability for; ``quality`` indexes them in this order."""
        return self.quality_targets

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        rng = np.random.default_rng(self.seed)
        calibration = calibrate_mixing(self.family, self.calibration_targets(), self.calibration_episodes,
                                       seed=int(rng.integers(2**31)), num_workers=self.num_workers)
        p = np.array([c["p_expert"] for c in calibration.values()])
        train_goals, test_goals = self.family.train_goals, self.family.test_goals
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {"train_goals": train_goals, "test_goals": test_goals}}
        splits["train"], train_stats = self._split(train_goals, self.per_task[0], p, rng, "train contexts")
        splits["val"], _ = self._split(train_goals, self.per_task[1], p, rng, "val contexts")
        eval_stats: dict[str, dict[str, float]] = {}
        for qi, q in enumerate(QUALITIES):
            splits[f"eval_{q}"], eval_stats[q] = self._split(test_goals, self.eval_per_task, p, rng, f"eval {q}",
                                                             quality=qi)
        reference, per_task = self._references(test_goals, p[:len(QUALITIES)], int(rng.integers(2**31)))
        info = {"calibration": calibration, "train_statistics": train_stats, "eval_statistics": eval_stats,
                "test_reference": reference, "test_reference_per_task": per_task}
        return splits, info

    def eval_context(self, arrays: dict[str, Any]):
        """The typed deployment context of an evaluation split's arrays."""
        return context_from_batch(self.kind, arrays)

    def evaluation_suites(self) -> list[EvalSuite]:
        data = self.load()
        test_goals = np.asarray(data["tasks"]["test_goals"])
        info = data.manifest["info"]
        uniform = np.asarray(info["test_reference_per_task"]["uniform_return"])
        expert = np.asarray(info["test_reference_per_task"]["expert_return"])
        suites = []
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            arrays = {k: to_tensor(np.asarray(v)) for k, v in split.items()}
            tasks = np.asarray(split["task_index"])
            suites.append(EvalSuite(
                env_name=self.metric_env, quality=q, context=self.eval_context(arrays),
                make_env=lambda goals=test_goals[tasks]: self.family.make_env(goals, num_workers=self.num_workers),
                task_index=tasks, horizon=self.family.horizon, reference=info["test_reference"][q],
                normalize=lambda r, t=tasks: (r - uniform[t]) / (expert[t] - uniform[t])))
        return suites
