"""DarkRoom as a ``TaskFamily`` (paper, appendix "MDP Environment Details"): goal cells of a 10×10 grid,
5 actions, H = 100; 80 goals train and 20 are held out, the split fixed by ``seed``.

Contexts are not episodes: an I-PRL or reward context holds H steps of the behavior process, and with
``terminate_on_goal`` a trajectory that enters the goal continues from a fresh random start (paper:
"every context holds H comparisons"). ``context_rollouts`` is that process, drawing starts from the
dataset's generator; ``independent_state_rollouts`` draws every state uniformly over the grid instead
(label-informative contexts); ``episode_rollouts`` are episodes of ``DarkRoomVectorEnv`` (T-PRL pairs,
references).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.families.calibration import invert_quality_curve
from icprl_lightning.families.darkroom.env import N_ACTIONS, DarkRoomState, DarkRoomVectorEnv, step_reward, transition
from icprl_lightning.families.darkroom.oracle import DarkRoomOracle, optimal_value
from icprl_lightning.metrics import mean_sem, per_task_mean
from icprl_lightning.validation import HyperparameterError, check_bool, check_int


@dataclass(frozen=True)
class DarkRoomFamily(TaskFamily):
    """The task family: grid geometry, horizon and the seeded train/test split of goal cells."""

    size: int = 10
    horizon: int = 100
    n_train_tasks: int = 80
    n_test_tasks: int = 20
    terminate_on_goal: bool = False
    seed: int = 0

    name = "darkroom"
    metric_env = "darkroom"
    task_name = "goals"
    obs_dim = 2
    n_actions = N_ACTIONS
    max_parallel = None  # integer arrays: every trajectory of a split steps at once

    def __post_init__(self) -> None:
        check_int("DarkRoomFamily", "size", self.size, 2)  # one cell has no task to infer
        check_int("DarkRoomFamily", "horizon", self.horizon, 1)
        check_int("DarkRoomFamily", "n_train_tasks", self.n_train_tasks, 1)
        check_int("DarkRoomFamily", "n_test_tasks", self.n_test_tasks, 1)
        check_bool("DarkRoomFamily", "terminate_on_goal", self.terminate_on_goal)
        if self.n_train_tasks + self.n_test_tasks > self.size**2:
            raise HyperparameterError(
                f"DarkRoomFamily: n_train_tasks + n_test_tasks must be <= size**2 = {self.size**2}: "
                f"{self.n_train_tasks} + {self.n_test_tasks} tasks need more than the {self.size**2} goal cells "
                f"of a {self.size}x{self.size} grid")

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=True, size=N_ACTIONS)

    @cached_property
    def oracle(self) -> DarkRoomOracle:
        return DarkRoomOracle(self)

    @cached_property
    def _goal_permutation(self) -> np.ndarray:
        cells = np.stack(np.divmod(np.arange(self.size**2), self.size), axis=-1)
        return cells[np.random.default_rng(self.seed).permutation(len(cells))]

    @property
    def train_goals(self) -> np.ndarray:
        return self._goal_permutation[: self.n_train_tasks].copy()

    @property
    def test_goals(self) -> np.ndarray:
        n = self.n_train_tasks
        return self._goal_permutation[n : n + self.n_test_tasks].copy()

    def tasks(self, split: str) -> np.ndarray:
        if split not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got {split!r}")
        return self.train_goals if split == "train" else self.test_goals

    def sample_starts(self, goals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Uniform start cells for each goal; when episodes end at the goal, never start on it."""
        starts = rng.integers(0, self.size, size=goals.shape)
        if self.terminate_on_goal:
            on_goal = np.all(starts == goals, axis=-1)
            while on_goal.any():
                starts[on_goal] = rng.integers(0, self.size, size=(int(on_goal.sum()), 2))
                on_goal = np.all(starts == goals, axis=-1)
        return starts

    def make_env(self, goals: np.ndarray) -> DarkRoomVectorEnv:
        return DarkRoomVectorEnv(self, goals)

    def context_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> ContinuingRollouts:
        return ContinuingRollouts(self, tasks, rng)

    def independent_state_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> IndependentStates:
        return IndependentStates(self, tasks, rng)

    def reference_groups(self, qualities: tuple[str, ...]) -> list[tuple[str, ...]]:
        """Each quality's references are measured right after its evaluation split (draw order = bytes)."""
        return [(q,) for q in qualities]

    def calibrate(self, targets: Mapping[str, float], episodes: int, seed: int) -> dict[str, dict[str, float]]:
        """Mixing level per target share of the optimal return R(π_p) / R* (``calibrate_mixing``), with
        ``episodes`` per training goal on a grid of 51 levels.

        An exception to the shared calibration (``families/calibration.py``), for one reason: R* is exact here,
        the closed-form V* of each episode's own start, and DarkRoom's scale is R / R* throughout (its
        ``references``, its normalized returns through ``TaskFamily.normalizer``, the paper's DarkRoom tables).
        The shared default simulates the optimal policy and a uniform one and targets (R − R_uniform) /
        (R* − R_uniform); the uniform return is ≈ 1% of R*, so both find the same mixing levels within their
        noise (tested). The datasets' bytes depend on this calibration's draws.
        """
        return calibrate_mixing(self, dict(targets), episodes, seed=seed)

    def references(self, tasks: np.ndarray, mixing: Mapping[str, float], episodes: int,
                   rng: np.random.Generator) -> dict[str, Any]:
        """Behavior (mixed policy) and optimal returns on the held-out goals, mean over goals.

        An exception to the shared ``references_by_simulation``: the optimal return is the closed-form V* of
        each episode's start (exact, no optimal rollout), and with DarkRoom's R / R* scale no uniform reference
        is needed, so none is stored (the normalizer then divides by the optimal return). Its behavior and
        optimal returns agree with the shared simulation's within their noise (tested).
        """
        reference = {}
        for quality, p in mixing.items():
            goals = np.repeat(tasks, episodes, axis=0)
            ret, opt = rollout_returns(self, goals, np.full(len(goals), p), rng)
            task_of = np.repeat(np.arange(len(tasks)), episodes)
            b_mean, b_sem = mean_sem(per_task_mean(ret, task_of))
            o_mean, _ = mean_sem(per_task_mean(opt, task_of))
            reference[quality] = {"behavior_return": b_mean, "behavior_return_sem": b_sem, "optimal_return": o_mean}
        return {"test_reference": reference}

    def config(self) -> dict[str, Any]:
        return {"family": self.name, "size": self.size, "horizon": self.horizon,
                "n_train_tasks": self.n_train_tasks, "n_test_tasks": self.n_test_tasks,
                "terminate_on_goal": self.terminate_on_goal, "seed": self.seed}


class ContinuingRollouts:
    """H steps of the behavior process on N goals: starts from ``rng``; a finished episode restarts."""

    def __init__(self, family: DarkRoomFamily, goals: np.ndarray, rng: np.random.Generator) -> None:
        self.family, self.goals, self.rng = family, np.asarray(goals), rng
        self.states = family.sample_starts(self.goals, rng)
        self.t = 0

    def observations(self) -> np.ndarray:
        return self.states.astype(np.float32)

    def oracle_state(self) -> DarkRoomState:
        return DarkRoomState(self.states, self.goals, self.t)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nxt = transition(self.states, actions, self.family.size)
        reward = step_reward(nxt, self.goals)
        observed = nxt.astype(np.float32)
        if self.family.terminate_on_goal:
            reached = reward > 0
            if reached.any():
                nxt[reached] = self.family.sample_starts(self.goals[reached], self.rng)
        self.states, self.t = nxt, self.t + 1
        return observed, reward

    def __enter__(self) -> ContinuingRollouts:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class IndependentStates(ContinuingRollouts):
    """H steps on N goals whose cell is drawn uniformly over the grid at every step (goal cell included).

    ``step`` reports the cell the action leads to and its reward, then the next state is a new uniform
    draw: the states say nothing about the goal (DPT's DarkRoom data; ``TaskFamily.independent_state_rollouts``).
    """

    def __init__(self, family: DarkRoomFamily, goals: np.ndarray, rng: np.random.Generator) -> None:
        self.family, self.goals, self.rng = family, np.asarray(goals), rng
        self.states = self._draw()
        self.t = 0

    def _draw(self) -> np.ndarray:
        return self.rng.integers(0, self.family.size, size=self.goals.shape)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nxt = transition(self.states, actions, self.family.size)
        reward = step_reward(nxt, self.goals)
        self.states, self.t = self._draw(), self.t + 1
        return nxt.astype(np.float32), reward


def rollout_returns(family: DarkRoomFamily, goals: np.ndarray, p_optimal: np.ndarray,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Returns of the mixed policy with per-episode p, and the optimal return from the same starts."""
    env = family.make_env(goals)
    obs, _ = env.reset(seed=int(rng.integers(2**31)))
    optimal = optimal_value(env.states, goals, family.horizon, family.terminate_on_goal)
    total = np.zeros(len(goals), dtype=np.float64)
    for _ in range(family.horizon):
        a = family.oracle.behavior_actions(env.oracle_state(), p_optimal, rng)
        _, r, _, _, _ = env.step(a)
        total += r
    return total, optimal.astype(np.float64)


def calibrate_mixing(family: DarkRoomFamily, targets: dict[str, float], episodes_per_goal: int = 25,
                     seed: int = 0, grid: int = 51) -> dict[str, dict[str, float]]:
    """Find p per quality so the mixed policy earns ``target`` × optimal return on the training goals.

    Simulates every p of a grid on all training goals at once, makes the return-ratio curve monotone,
    inverts it by interpolation, then re-simulates at the chosen p to report the achieved ratio.
    """
    rng = np.random.default_rng(seed)
    goals = family.train_goals
    ps = np.linspace(0.0, 1.0, grid)
    rep_goals = np.tile(np.repeat(goals, episodes_per_goal, axis=0), (grid, 1))
    rep_p = np.repeat(ps, len(goals) * episodes_per_goal)
    ret, opt = rollout_returns(family, rep_goals, rep_p, rng)
    ratio = (ret.reshape(grid, -1).mean(1) / opt.reshape(grid, -1).mean(1))
    chosen = invert_quality_curve(ps, ratio, targets)
    out: dict[str, dict[str, float]] = {}
    for name, p in chosen.items():
        check_goals = np.repeat(goals, episodes_per_goal, axis=0)
        r, o = rollout_returns(family, check_goals, np.full(len(check_goals), p), rng)
        out[name] = {"target": float(targets[name]), "mixing": p, "achieved": float(r.mean() / o.mean()),
                     "mean_return": float(r.mean()), "optimal_return": float(o.mean())}
    return out
