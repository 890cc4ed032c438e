"""DarkRoom oracle: optimal actions, the closed-form optimal advantage A*, and mixed behavior policies.

Privileged: it sees the goal. Only data generation and evaluation use it; no model receives its output
except DPT/DP²T's optimal-action labels (the paper's supervised baselines).

Closed form (finite horizon, k = steps left including the current one, d = Manhattan distance to the
goal, r(s, a) = 1[s' = goal]):

* without termination   V*_k(s) = max(0, k + 1 − max(d, 1))     (walk d steps, then stay on the goal)
* with termination      V*_k(s) = 1[1 ≤ d ≤ k]                   (the goal cell itself is terminal)

and Q*_k(s, a) = r(s, a) + V*_{k−1}(s') (no continuation after entering a terminal goal),
A*_k(s, a) = Q*_k(s, a) − V*_k(s). Tested against brute-force backward induction.

Mixed behavior policy (appendix "Pretraining Data Generation"): with probability p the optimal action,
otherwise a uniformly random one. p is calibrated by simulation so the policy earns a target share
(20/40/80%) of the optimal return on the training goals.
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.families.base import Oracle
from icprl_lightning.families.darkroom.env import N_ACTIONS, NOOP, DarkRoomState, RoomRules, step_reward, transition

# OPTIMAL_BY_SIGN[3 · sign(dx) + sign(dy)] (negative codes index from the end): the action that closes
# the x gap first, then the y gap, then stays (NOOP on the goal). One lookup instead of a chain of
# np.where over the batch: data generation calls this on every step and on [N, H] query states.
OPTIMAL_BY_SIGN = np.array([NOOP, 0, 3, 3, 3, 2, 2, 2, 1], dtype=np.int64)
QUERY_BLOCK_CELLS = 2**15  # query cells drawn and labeled at once in ``DarkRoomOracle.query_labels``


def optimal_actions(states: np.ndarray, goals: np.ndarray) -> np.ndarray:
    """A deterministic optimal action: close the x gap first, then the y gap, then stay (int64)."""
    sign = np.sign(goals - states)
    code = sign[..., 0] * 3
    code += sign[..., 1]
    return OPTIMAL_BY_SIGN[code]


def optimal_value(states: np.ndarray, goals: np.ndarray, steps_left: np.ndarray | int,
                  terminate_on_goal: bool) -> np.ndarray:
    """V*_k(s) in closed form (see the module docstring); float32 of the batch shape."""
    d = np.abs(states[..., 0] - goals[..., 0]) + np.abs(states[..., 1] - goals[..., 1])
    k = np.asarray(steps_left)
    if terminate_on_goal:
        return ((d >= 1) & (d <= k)).astype(np.float32)
    return np.maximum(0, k + 1 - np.maximum(d, 1)).astype(np.float32)


def optimal_advantage(states: np.ndarray, actions: np.ndarray, goals: np.ndarray, steps_left: np.ndarray | int,
                      family: RoomRules) -> np.ndarray:
    """A*_k(s, a) = r(s, a) + V*_{k−1}(s') − V*_k(s), vectorized over any batch shape."""
    nxt = transition(states, actions, family.size)
    r = step_reward(nxt, goals)
    k = np.asarray(steps_left)
    cont = optimal_value(nxt, goals, k - 1, family.terminate_on_goal)
    if family.terminate_on_goal:
        cont = np.where(r > 0, 0.0, cont)
    return (r + cont - optimal_value(states, goals, k, family.terminate_on_goal)).astype(np.float32, copy=False)


class DarkRoomOracle(Oracle):
    """The ``Oracle`` of ``families/base.py`` for a DarkRoom family (closed-form A*, see the module docstring)."""

    def __init__(self, family: RoomRules) -> None:
        self.family = family

    def uniform_actions(self, state: DarkRoomState, rng: np.random.Generator) -> np.ndarray:
        return rng.integers(0, N_ACTIONS, size=len(state.states))

    def optimal_actions(self, state: DarkRoomState) -> np.ndarray:
        return optimal_actions(state.states, state.goals)

    def utility(self, state: DarkRoomState, actions: np.ndarray) -> np.ndarray:
        """A*_k(s, a) of K candidates [K, N] with k = H − t steps left (exact, not up to a constant)."""
        return optimal_advantage(state.states, actions, state.goals, self.family.horizon - state.t, self.family)

    def query_labels(self, tasks: np.ndarray, visited_states: np.ndarray, visited_optimal: np.ndarray,
                     horizon: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Query states uniform over the grid [N, H, 2] (not the visited ones) and their optimal actions.

        Drawn and labeled in blocks of rows, so that no int64 temporary spans all N × H cells (128 MB
        each at paper scale, N = 80,000). ``Generator.integers`` takes the cells one by one from the stream:
        the blocks' draws are those of one draw of all cells, in the same order (the dataset's bytes).
        """
        states = np.empty((len(tasks), horizon, 2), dtype=np.float32)
        labels = np.empty((len(tasks), horizon), dtype=np.int8)
        block = max(1, QUERY_BLOCK_CELLS // horizon)
        for lo in range(0, len(tasks), block):
            cells = rng.integers(0, self.family.size, size=states[lo:lo + block].shape)
            states[lo:lo + block] = cells
            labels[lo:lo + block] = optimal_actions(cells, tasks[lo:lo + block, None, :])
        return {"query_states": states, "optimal_actions": labels}
