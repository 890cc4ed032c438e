"""Single-episode Gymnasium env for one DarkRoom goal, for Stable-Baselines3 (the DQN baseline): the dynamics,
reward and starts of ``DarkRoomVectorEnv`` one episode at a time; ``info["success"]`` once the agent stands on
the goal. ``darkroom_env`` and ``darkroom_vector_env`` are the entry points of the Gymnasium id
``icprl/DarkRoom-v0`` (``families/registration.py``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import N_ACTIONS, DarkRoomVectorEnv, step_reward, transition
from icprl_lightning.families.registration import check_num_envs


class DarkRoomGoalEnv(gym.Env):
    """One DarkRoom task (a goal cell [2]) of ``family``; starts drawn from ``self.np_random``."""

    metadata = {"render_modes": []}

    def __init__(self, family: DarkRoomFamily, goal: np.ndarray) -> None:
        goal = np.asarray(goal, dtype=np.int64)
        if goal.shape != (2,) or np.any(goal < 0) or np.any(goal >= family.size):
            raise ValueError(f"goal must be a cell [2] of the {family.size}x{family.size} grid, got {goal}")
        self.family = family
        self.goal = goal
        self.observation_space = gym.spaces.Box(0, family.size - 1, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(N_ACTIONS)
        self.state = np.zeros(2, dtype=np.int64)
        self.t = family.horizon  # no episode until reset()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.state = self.family.sample_starts(self.goal[None], self.np_random)[0]
        self.t = 0
        return self.state.astype(np.float32), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.t >= self.family.horizon:
            raise RuntimeError("episode is over (horizon reached or never reset): call reset()")
        if isinstance(action, bool | np.bool_) or not self.action_space.contains(action):
            raise ValueError(f"action must be an integer move in [0, {self.action_space.n}) (stay, up, down, left, "
                             f"right), got {action!r}")
        self.state = transition(self.state, np.asarray(action, dtype=np.int64), self.family.size)
        reward = float(step_reward(self.state, self.goal))
        self.t += 1
        terminated = self.family.terminate_on_goal and reward > 0
        return (self.state.astype(np.float32), reward, terminated, self.t >= self.family.horizon,
                {"success": reward > 0})


def darkroom_env(goal: np.ndarray | None = None, horizon: int = 100, terminate_on_goal: bool = False
                 ) -> DarkRoomGoalEnv:
    """``gymnasium.make("icprl/DarkRoom-v0", goal=[x, y])``: one task of the paper's 10×10 DarkRoom; without a
    goal, the family's first held-out goal (``DarkRoomFamily().tasks("test")[0]``)."""
    family = DarkRoomFamily(horizon=horizon, terminate_on_goal=terminate_on_goal)
    return DarkRoomGoalEnv(family, _batch_of_cells(family, 1, goal, None)[0])


def darkroom_vector_env(num_envs: int = 1, goal: np.ndarray | None = None, goals: np.ndarray | None = None,
                        horizon: int = 100, terminate_on_goal: bool = False) -> DarkRoomVectorEnv:
    """``gymnasium.make_vec("icprl/DarkRoom-v0", num_envs=N, goal=[x, y])``: N episodes as one batched env.

    ``goal`` [2] gives every episode the same task (what ``make_vec(..., vectorization_mode="sync")`` builds
    from the same kwargs); ``goals`` [N, 2] gives each its own; neither: the first held-out goal.
    """
    family = DarkRoomFamily(horizon=horizon, terminate_on_goal=terminate_on_goal)
    return DarkRoomVectorEnv(family, _batch_of_cells(family, num_envs, goal, goals))


def _batch_of_cells(family: DarkRoomFamily, num_envs: int, goal: np.ndarray | None,
                    goals: np.ndarray | None) -> np.ndarray:
    """The [num_envs, 2] goal cells from at most one of ``goal`` [2] and ``goals`` [num_envs, 2] (neither: the
    family's first held-out goal, the default of ``darkroom_env``)."""
    check_num_envs("icprl/DarkRoom-v0", num_envs, goals)
    if goal is not None and goals is not None:
        raise ValueError("icprl/DarkRoom-v0: pass one of goal=[x, y] (every env) and "
                         f"goals=[[x, y], ...] (one per env, {num_envs} rows), not both")
    if goal is None and goals is None:
        goal = family.tasks("test")[0]
    cells = np.tile(np.asarray(goal), (num_envs, 1)) if goals is None else np.asarray(goals)
    if cells.shape != (num_envs, 2) or not np.issubdtype(cells.dtype, np.integer):
        raise ValueError(f"icprl/DarkRoom-v0: goals must be integer cells of shape [{num_envs}, 2], "
                         f"got {cells.dtype} {list(cells.shape)}")
    if np.any(cells < 0) or np.any(cells >= family.size):
        raise ValueError(f"icprl/DarkRoom-v0: every goal must be a cell of the {family.size}x{family.size} grid "
                         f"(coordinates in [0, {family.size - 1}]), got {cells.tolist()}")
    return cells.astype(np.int64)
