"""Single-episode Gymnasium env for one DarkRoom goal, for Stable-Baselines3 (the DQN baseline).

The same dynamics, reward and start distribution as ``DarkRoomVectorEnv`` (``families/darkroom/env.py``), one
episode at a time: obs is the agent's (x, y) cell as float32 [2] (the goal is never observed; it is a
constant of the env), ``Discrete(5)`` actions (up, down, left, right, no-op), r = 1 when a move lands
on the goal, truncation at H = 100, and termination on entering the goal only with the family's
``terminate_on_goal`` flag. ``info["success"]`` is true once the agent stands on the goal.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import N_ACTIONS, step_reward, transition


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
        self.state = transition(self.state, np.asarray(action, dtype=np.int64), self.family.size)
        reward = float(step_reward(self.state, self.goal))
        self.t += 1
        terminated = self.family.terminate_on_goal and reward > 0
        return (self.state.astype(np.float32), reward, terminated, self.t >= self.family.horizon,
                {"success": reward > 0})
