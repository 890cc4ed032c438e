"""Meta-World Reach as a ``TaskFamily`` (paper, appendix "MDP Environment Details"): metaworld's ML1
``reach-v3`` goals fixed by ``seed`` — the first ``n_train`` train, the last ``n_test`` are held out —
H = 150, 39-D observations with the goal zeroed, 4-D continuous actions.

The paper holds out 5 goals. ``fresh_test_goals = N`` replaces them by N goals drawn afresh, uniformly from
reach-v3's goal box (``GOAL_LOW``/``GOAL_HIGH``, the box ML1 samples its goals from), with a stream of their own
(``SeedSequence([seed, FRESH_GOALS_STREAM])``): a wider held-out evaluation (``configs/eval/``) that changes no
training goal, and no goal of it is a training goal (continuous draws; tested).

Both kinds of rollouts are episodes of ``ReachVectorEnv`` (worker processes over both cores), at most
``max_parallel`` at once (≈0.7 MB per env); ``num_workers`` does not change any number.
``independent_state_rollouts`` places every hand at a fresh uniform point of the hand box before each
step (``ReachVectorEnv.place_hands``), so its states are independent of the goal and of the actions.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.families.base import EnvRollouts, TaskFamily
from icprl_lightning.families.metaworld_reach.env import (
    ACTION_DIM,
    GOAL_HIGH,
    GOAL_LOW,
    HAND_HIGH,
    HAND_LOW,
    HORIZON,
    OBS_DIM,
    ReachVectorEnv,
    SawyerReachEnvV3,
    ml1_goals,
)
from icprl_lightning.families.metaworld_reach.oracle import ReachOracle
from icprl_lightning.families.metaworld_reach.simulation import calibrate_mixing, rollout_returns
from icprl_lightning.metrics import mean_sem, per_task_mean
from icprl_lightning.validation import HyperparameterError, check_int

FRESH_GOALS_STREAM = 50  # the seed stream of the fresh held-out goals, apart from ML1's


def fresh_goals(seed: int, n: int) -> np.ndarray:
    """``n`` held-out goals [n, 3] uniform in reach-v3's goal box, fixed by ``seed``, apart from ML1's draws."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, FRESH_GOALS_STREAM]))
    return rng.uniform(GOAL_LOW, GOAL_HIGH, size=(n, 3))


class ReachTaskFamily(TaskFamily):
    """Reach goals fixed by ``seed``: ML1's 50 goals, the first ``n_train`` to train, the last ``n_test`` held out
    (or, with ``fresh_test_goals = N``, N fresh goals of the same box held out instead)."""

    name = "metaworld_reach"
    metric_env = "metaworld"
    task_name = "goals"
    obs_dim = OBS_DIM
    action_dim = ACTION_DIM
    max_parallel = 1024  # episodes simulated at once; bounds memory for paper-sized datasets

    def __init__(self, seed: int = 0, n_train: int = 45, n_test: int = 5, horizon: int = HORIZON,
                 num_workers: int = 2, fresh_test_goals: int = 0) -> None:
        check_int("ReachTaskFamily", "n_train", n_train, 1, 49)
        check_int("ReachTaskFamily", "fresh_test_goals", fresh_test_goals, 0, 10_000)
        check_int("ReachTaskFamily", "n_test", n_test, 1, 49)
        if n_train + n_test > 50:
            raise HyperparameterError(f"ReachTaskFamily: n_train + n_test must be <= 50 (ML1 offers 50 goals), "
                                      f"got {n_train} + {n_test}")
        check_int("ReachTaskFamily", "horizon", horizon, 1, SawyerReachEnvV3.max_path_length)
        check_int("ReachTaskFamily", "num_workers", num_workers, 0)
        self.seed = seed
        self.n_train = n_train
        self.n_test = n_test
        self.horizon = horizon
        self.num_workers = num_workers
        self.fresh_test_goals = fresh_test_goals
        goals = ml1_goals(seed)  # continuous i.i.d. draws: distinct (tested)
        self._train, self._test = goals[:n_train].copy(), goals[len(goals) - n_test:].copy()
        if fresh_test_goals:
            self._test = fresh_goals(seed, fresh_test_goals)
            self.n_test = fresh_test_goals

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=False, size=ACTION_DIM)

    @cached_property
    def oracle(self) -> ReachOracle:
        return ReachOracle(self)

    @property
    def train_goals(self) -> np.ndarray:
        return self._train.copy()

    @property
    def test_goals(self) -> np.ndarray:
        return self._test.copy()

    def tasks(self, split: str) -> np.ndarray:
        if split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        return self.train_goals if split == "train" else self.test_goals

    goals = tasks

    def make_env(self, goals: np.ndarray, num_workers: int | None = None) -> ReachVectorEnv:
        workers = self.num_workers if num_workers is None else num_workers
        return ReachVectorEnv(goals, horizon=self.horizon, num_workers=workers)

    def independent_state_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> IndependentHandStates:
        return IndependentHandStates(self.make_env(tasks), rng)

    def calibrate(self, targets: Mapping[str, float], episodes: int, seed: int) -> dict[str, dict[str, float]]:
        """Mixing level per target normalized return (R − R_uniform) / (R_expert − R_uniform), by simulation with
        common random numbers on ``episodes`` training-goal episodes (``simulation.calibrate_mixing``).

        An exception to the shared calibration (``families/calibration.py``) with the same measure and method
        (made monotone, inverted, re-measured) on this family's ``oracle.CALIBRATION_GRID``: 10 levels instead of
        21, dense at small p where q(p) bends (q ≈ 0.07 at p = 0.02, 0.2 near p = 0.06), which halves the MuJoCo
        episodes of a calibration. Its random streams (goal order, seeds) are part of every Reach dataset's
        bytes, which is why it is not the shared function called with that grid. Its levels reach their targets
        when measured by the shared simulation, within its noise (tested).
        """
        return calibrate_mixing(self, targets, episodes, seed=seed, num_workers=self.num_workers)

    def references(self, tasks: np.ndarray, mixing: Mapping[str, float], episodes: int,
                   rng: np.random.Generator) -> dict[str, Any]:
        """Return and success of uniform, each behavior π_q and the expert on each held-out goal.

        The shared ``references_by_simulation``'s returns (uniform, behaviors, reference policy per goal, with
        common random numbers), kept as an exception for two additions: metaworld's success rate of each policy,
        which the tables report beside the returns, and the reference named for what it is, the scripted expert
        (``expert_return``), which is not the optimum. Its returns agree with the shared simulation's within
        their noise (tested).
        """
        goals = np.repeat(tasks, episodes, axis=0)
        task_of = np.repeat(np.arange(len(tasks)), episodes)
        ps = np.array([0.0, *mixing.values(), 1.0])
        returns, success = rollout_returns(self, goals, ps, int(rng.integers(2**31)), self.num_workers)
        per_task = [per_task_mean(r, task_of) for r in returns]  # uniform, the behaviors, expert
        uniform, expert = per_task[0], per_task[-1]
        expert_success = mean_sem(per_task_mean(success[-1].astype(float), task_of))[0]
        reference = {}
        for qi, q in enumerate(mixing):
            b_mean, b_sem = mean_sem(per_task[qi + 1])
            reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem,
                            "behavior_success": mean_sem(per_task_mean(success[qi + 1].astype(float), task_of))[0],
                            "behavior_normalized_return": mean_sem((per_task[qi + 1] - uniform)
                                                                   / (expert - uniform))[0],
                            "expert_return": mean_sem(expert)[0], "expert_success": expert_success,
                            "uniform_return": mean_sem(uniform)[0]}
        return {"test_reference": reference,
                "test_reference_per_task": {"uniform_return": uniform.tolist(), "expert_return": expert.tolist()}}

    def config(self) -> dict[str, Any]:
        out = {"family": self.name, "env": "reach-v3", "expert": "tcp", "horizon": self.horizon,
               "n_train_tasks": self.n_train, "n_test_tasks": self.n_test, "seed": self.seed}
        if self.fresh_test_goals:  # only then: the paper's split keeps its config (and its datasets) unchanged
            out["fresh_test_goals"] = self.fresh_test_goals
        return out


class IndependentHandStates(EnvRollouts):
    """Episodes of ``ReachVectorEnv`` whose hands are placed at a fresh uniform point before every step.

    Reset with a seed drawn from ``rng`` (as ``EnvRollouts``), then the positions: before the first step
    and after every step, one draw ``rng.uniform(HAND_LOW, HAND_HIGH, [N, 3])`` and
    ``env.place_hands`` (from the episode's post-reset state, so a placed state does not depend on the
    actions). ``step`` returns the observation the action leads to and its latent reward; the next
    ``observations()`` are the new placement. The box is reach-v3's mocap box (= its hand box), the
    targets ``set_xyz_action`` can reach; the goal box is a small part of it, and its far corners are
    beyond the arm's reach (the hand stops short, see ``place_hands``).
    """

    def __init__(self, env: ReachVectorEnv, rng: np.random.Generator) -> None:
        self.rng = rng
        try:
            super().__init__(env, rng)
            self._obs = self._place()
        except BaseException:
            env.close()
            raise

    def _place(self) -> np.ndarray:
        return self.env.place_hands(self.rng.uniform(HAND_LOW, HAND_HIGH, size=(self.env.num_envs, 3)))

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        observed, reward, *_ = self.env.step(actions)
        self._obs = self._place()
        return observed, reward

    def __enter__(self) -> IndependentHandStates:
        return self
