"""Single-episode Gymnasium env for Meta-World Reach, for Stable-Baselines3 (SAC oracle and baseline).

``ReachGoalEnv`` is one stock ``reach-v3`` with the conventions of ``env.py`` (latent reward, success radius, no
early termination). At each reset it draws one goal of ``goals`` [G, 3] (or ``options={"goal_index": i}``) and
the puck from ``self.np_random``, so ``reset(seed=s)`` and an action sequence fix every step.
``goal_visible=True`` writes the goal into obs[36:39] for the goal-conditioned SAC oracle only: privileged, it
never reaches a preference learner. ``reach_env`` and ``reach_vector_env`` are the entry points of the
Gymnasium id ``icprl/MetaWorldReach-v0`` (``families/registration.py``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from metaworld.envs.sawyer_reach_v3 import SawyerReachEnvV3

from icprl_lightning.families.metaworld_reach.env import (
    ACTION_DIM,
    GOAL_HIGH,
    GOAL_LOW,
    GOAL_SLICE,
    HORIZON,
    OBS_DIM,
    SUCCESS_RADIUS,
    ReachOracleState,
    ReachVectorEnv,
    latent_reward,
    reach_task,
    sample_puck_positions,
)
from icprl_lightning.families.registration import check_num_envs

DEFAULT_GOAL = (GOAL_LOW + GOAL_HIGH) / 2  # the goal of gymnasium.make("icprl/MetaWorldReach-v0") alone


class ReachGoalEnv(gym.Env):
    """One reach-v3 episode at a time on a goal drawn from ``goals`` [G, 3]; obs float32 [39], action [4]."""

    metadata = {"render_modes": []}

    def __init__(self, goals: np.ndarray, horizon: int = HORIZON, goal_visible: bool = False) -> None:
        goals = np.array(goals, dtype=np.float64)
        if goals.ndim == 1:
            goals = goals[None]
        if goals.ndim != 2 or goals.shape[1] != 3 or len(goals) == 0:
            raise ValueError(f"goals must have shape [G, 3] (or [3]) with G ≥ 1, got {list(goals.shape)}")
        if not 1 <= horizon <= SawyerReachEnvV3.max_path_length:
            raise ValueError(f"horizon must be in [1, {SawyerReachEnvV3.max_path_length}], got {horizon}")
        self.goals = goals
        self.horizon = horizon
        self.goal_visible = goal_visible
        # Unbounded: metaworld's own bounds exclude the zeros that hide the goal.
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(ACTION_DIM,), dtype=np.float32)
        self._env = SawyerReachEnvV3()
        self._env.max_path_length = horizon
        self.goal = goals[0].copy()
        self._raw_obs = np.zeros(OBS_DIM)
        self.t = horizon  # no episode until reset()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        index = (options or {}).get("goal_index")
        if index is None:
            index = int(self.np_random.integers(len(self.goals)))
        self.goal = self.goals[index].copy()
        puck = sample_puck_positions(self.goal[None], self.np_random)[0]
        self._env.set_task(reach_task(goal=self.goal, puck=puck))
        obs, _ = self._env.reset()
        self._raw_obs = obs
        self.t = 0
        return self._observe(obs), {"goal_index": int(index)}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self.t >= self.horizon:
            raise RuntimeError("episode is over (horizon reached or never reset): call reset()")
        move = np.asarray(action, dtype=np.float64)
        if move.shape != self.action_space.shape or not np.isfinite(move).all():
            raise ValueError(f"action must be {self.action_space.shape[0]} finite numbers (clipped to [-1, 1]), "
                             f"got {action!r}")
        obs, *_ = self._env.step(np.clip(move, -1.0, 1.0))
        self._raw_obs = obs
        self.t += 1
        reward = float(latent_reward(self._env.tcp_center, self.goal))
        info = {"success": bool(-reward <= SUCCESS_RADIUS), "distance": -reward}
        return self._observe(obs), reward, False, self.t >= self.horizon, info

    def oracle_state(self) -> ReachOracleState:
        """Hand, previous hand, TCP, mocap and goal as a batch of one: for oracles and evaluation only."""
        raw = self._raw_obs
        return ReachOracleState(hand=raw[None, 0:3].copy(), prev_hand=raw[None, 18:21].copy(),
                                tcp=self._env.tcp_center[None].copy(), mocap=self._env.data.mocap_pos[0][None].copy(),
                                goal=self.goal[None].copy(), t=self.t,
                                obs=np.concatenate([raw[:36], self.goal]).astype(np.float32)[None])

    def _observe(self, obs: np.ndarray) -> np.ndarray:
        obs = obs.astype(np.float32)
        obs[GOAL_SLICE] = self.goal if self.goal_visible else 0.0
        return obs


def reach_env(goal: np.ndarray | None = None, horizon: int = HORIZON, goal_visible: bool = False) -> ReachGoalEnv:
    """``gymnasium.make("icprl/MetaWorldReach-v0", goal=[x, y, z])``: one reach-v3 task; without a goal,
    ``DEFAULT_GOAL``, the centre of reach-v3's goal box."""
    return ReachGoalEnv(_batch_of_goals(1, goal, None)[0], horizon=horizon, goal_visible=goal_visible)


def reach_vector_env(num_envs: int = 1, goal: np.ndarray | None = None, goals: np.ndarray | None = None,
                     horizon: int = HORIZON, num_workers: int = 2, goal_visible: bool = False) -> ReachVectorEnv:
    """``gymnasium.make_vec("icprl/MetaWorldReach-v0", num_envs=N, goal=[x, y, z])``: ``ReachVectorEnv``.

    ``goal`` [3] gives every episode the same task (what ``make_vec(..., vectorization_mode="sync")`` builds
    from the same kwargs); ``goals`` [N, 3] gives each its own; neither: ``DEFAULT_GOAL``. ``num_workers``
    worker processes (0: this process) step the envs; workers need the caller's script under
    ``if __name__ == "__main__":``.
    """
    if goal_visible:
        # the batched env serves learners: its observations always hide the goal
        raise ValueError("icprl/MetaWorldReach-v0: goal_visible=True is for the single env (gymnasium.make); the "
                         "vector env always hides the goal (its oracle_state().obs shows it)")
    return ReachVectorEnv(_batch_of_goals(num_envs, goal, goals), horizon=horizon, num_workers=num_workers)


def _batch_of_goals(num_envs: int, goal: np.ndarray | None, goals: np.ndarray | None) -> np.ndarray:
    """The [num_envs, 3] finite goals from at most one of ``goal`` [3] and ``goals`` [num_envs, 3] (neither:
    ``DEFAULT_GOAL``)."""
    check_num_envs("icprl/MetaWorldReach-v0", num_envs, goals)
    if goal is not None and goals is not None:
        raise ValueError("icprl/MetaWorldReach-v0: pass one of goal=[x, y, z] (every env) and "
                         f"goals=[[x, y, z], ...] (one per env, {num_envs} rows), not both")
    if goal is None and goals is None:
        goal = DEFAULT_GOAL
    points = np.tile(np.asarray(goal, dtype=np.float64), (num_envs, 1)) if goals is None \
        else np.asarray(goals, dtype=np.float64)
    if points.shape != (num_envs, 3) or not np.all(np.isfinite(points)):
        raise ValueError(f"icprl/MetaWorldReach-v0: goals must be finite points of shape [{num_envs}, 3], "
                         f"got shape {list(points.shape)}")
    return points
