"""DarkRoom (paper, appendix "MDP Environment Details"): a 10×10 grid, 5 actions, H = 100, a random
start and a hidden goal. One task per goal cell; 80 goals train, 20 held out, split fixed by a seed.

Reward convention (``terminate_on_goal=False``, the default): r_h = 1 on every step whose move lands
on the goal cell (staying on the goal counts), as in DPT's DarkRoom. The optimal return is then
H + 1 − max(d, 1) for a start at Manhattan distance d, so behavior policies span a graded range of
returns and the 20/40/80%-of-optimal context qualities are well defined. With ``terminate_on_goal=True``
(the paper's text) the episode ends when the agent enters the goal and the return is 0 or 1, which
makes "20% of the optimal return" a success probability; it is kept as a flag.

``DarkRoomVectorEnv`` steps B environments at once as integer arrays (no Python loop over
environments). Observations are the agent's (x, y) cell as float32; the goal is never observed.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import gymnasium as gym
import numpy as np

# up, down, left, right, no-op. int8: ``transition`` gathers one move per candidate action, [2, N, 2] moves
# per generation step (2.5 MB as int64 at N = 80,000, 320 kB as int8); s + move is still int64
MOVES = np.array([[0, 1], [0, -1], [-1, 0], [1, 0], [0, 0]], dtype=np.int8)
NOOP = 4
N_ACTIONS = len(MOVES)


class RoomRules(Protocol):
    """What the env and the closed-form A* read of a room (``DarkRoomFamily`` is one)."""

    size: int
    horizon: int
    terminate_on_goal: bool

    def sample_starts(self, goals: np.ndarray, rng: np.random.Generator) -> np.ndarray: ...


def transition(states: np.ndarray, actions: np.ndarray, size: int) -> np.ndarray:
    """Deterministic grid move with walls: s' = clip(s + move(a), 0, size − 1); int arrays [..., 2]."""
    # take() along the table's rows is ~10x faster than MOVES[actions], and clipping in place saves a
    # batch-sized allocation: this runs on every step of data generation
    nxt = np.add(states, MOVES.take(actions, axis=0))
    return np.clip(nxt, 0, size - 1, out=nxt)


def step_reward(next_states: np.ndarray, goals: np.ndarray) -> np.ndarray:
    """r(s, a) = 1 when the move lands on the goal."""
    # explicit columns: NumPy reductions over a length-2 axis are several times slower
    return ((next_states[..., 0] == goals[..., 0]) & (next_states[..., 1] == goals[..., 1])).astype(np.float32)


class DarkRoomState(NamedTuple):
    """Privileged state of N trajectories, for the oracle only: cells [N, 2], goals [N, 2], steps taken."""

    states: np.ndarray
    goals: np.ndarray
    t: int


class DarkRoomVectorEnv(gym.vector.VectorEnv):
    """B DarkRoom episodes stepping together; ``goals`` [B, 2] may differ per episode.

    ``reset(seed=...)`` seeds ``self.np_random`` as Gymnasium does; all start cells come from it.
    Episodes last ``horizon`` steps (``truncated`` then); with ``terminate_on_goal`` an episode that
    entered the goal is ``terminated`` and stays frozen with zero reward until the next reset.
    """

    # No autoreset: the batch shares one clock, every episode ends at the horizon, and reset() restarts all.
    metadata = {"autoreset_mode": gym.vector.AutoresetMode.DISABLED}

    def __init__(self, family: RoomRules, goals: np.ndarray) -> None:
        goals = np.asarray(goals, dtype=np.int64)
        if goals.ndim != 2 or goals.shape[1] != 2:
            raise ValueError(f"goals must have shape [B, 2], got {list(goals.shape)}")
        self.family = family
        self.goals = goals
        self.num_envs = len(goals)
        self.single_observation_space = gym.spaces.Box(0, family.size - 1, shape=(2,), dtype=np.float32)
        self.single_action_space = gym.spaces.Discrete(N_ACTIONS)
        self.observation_space = gym.spaces.Box(0, family.size - 1, shape=(self.num_envs, 2), dtype=np.float32)
        self.action_space = gym.spaces.MultiDiscrete(np.full(self.num_envs, N_ACTIONS))
        self.states = np.zeros_like(goals)
        self.done = np.zeros(self.num_envs, dtype=bool)
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if options and "reset_mask" in options:
            raise ValueError(f"{type(self).__name__}.reset: options['reset_mask'] (a partial reset) is not supported: "
                             "the batch shares one clock; call reset() to restart every episode")
        self.states = self.family.sample_starts(self.goals, self.np_random)
        self.done[:] = False
        self.t = 0
        return self.states.astype(np.float32), {}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape [{self.num_envs}], got {list(actions.shape)}")
        if self.t >= self.family.horizon:
            raise RuntimeError("episode is over (horizon reached): call reset()")
        nxt = transition(self.states, actions, self.family.size)
        reward = step_reward(nxt, self.goals)
        reward[self.done] = 0.0
        self.states = np.where(self.done[:, None], self.states, nxt)
        if self.family.terminate_on_goal:
            self.done |= reward > 0
        self.t += 1
        truncated = np.full(self.num_envs, self.t >= self.family.horizon)
        return self.states.astype(np.float32), reward, self.done.copy(), truncated, {}

    def oracle_state(self) -> DarkRoomState:
        """The privileged state (cells, goals, steps taken): for oracles and evaluation only."""
        return DarkRoomState(self.states, self.goals, self.t)
