"""DarkRoom pretraining and evaluation data (paper, appendix "Pretraining Data Generation", DarkRoom).

I-PRL (``generate_step_preferences``): at every step one action comes from the uniform policy and one
from the mixed policy (optimal with probability p); their slots are shuffled so that position carries
no information. The label is y ~ BT(A*(s, a) − A*(s, a')) with an explicit temperature, and the next
state follows the preferred action. With ``terminate_on_goal`` a context that enters the goal
continues from a fresh random start, so every context holds exactly H comparisons.

Reward contexts (``generate_reward_contexts``, DPT's oracle baseline): rollouts (s, a, r, s') of the
same mixed behavior policies.

Both carry query states drawn uniformly over the grid with their optimal-action labels, used only by
the supervised methods (DPT, DP²T). All generation is vectorized over trajectories: one NumPy step
advances every trajectory of every task at once.
"""

from __future__ import annotations

import numpy as np
from rich.progress import track

from icprl_lightning.envs.darkroom import N_ACTIONS, DarkRoomFamily, step_reward, transition
from icprl_lightning.oracles.darkroom import mixed_actions, optimal_actions, optimal_advantage
from icprl_lightning.preferences import label_agreement, sample_preferences


def _steps(horizon: int, description: str, progress: bool):
    return track(range(horizon), description=description, disable=not progress, transient=True)


def query_labels(family: DarkRoomFamily, goals: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Uniform query states [N, H, 2] and their optimal actions [N, H] for the goals [N, 2]."""
    n, h = len(goals), family.horizon
    states = rng.integers(0, family.size, size=(n, h, 2))
    labels = optimal_actions(states, goals[:, None, :])
    return {"query_states": states.astype(np.float32), "optimal_actions": labels.astype(np.int8)}


def generate_step_preferences(family: DarkRoomFamily, goals: np.ndarray, p_optimal: np.ndarray,
                              bt_temperature: float, rng: np.random.Generator, progress: bool = False,
                              description: str = "I-PRL contexts") -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """One I-PRL context of H comparisons per row of ``goals`` [N, 2], with mixing probability ``p_optimal`` [N].

    Returns the arrays (``states``, ``actions``, ``alt_actions``, ``preferred`` = 1 when ``actions`` won)
    and statistics: the label agreement rate with the true A* ordering and the share of tied pairs.
    """
    n, horizon = len(goals), family.horizon
    # time-major buffers: each step writes one contiguous row; transposed once at the end
    states = np.empty((horizon, n, 2), dtype=np.float32)
    first = np.empty((horizon, n), dtype=np.int8)
    second = np.empty((horizon, n), dtype=np.int8)
    preferred = np.empty((horizon, n), dtype=np.uint8)
    utility = np.empty((2, horizon, n), dtype=np.float32)
    s = family.sample_starts(goals, rng)
    for h in _steps(horizon, description, progress):
        uniform = rng.integers(0, N_ACTIONS, size=n)
        behavior = mixed_actions(s, goals, p_optimal, rng)
        swap = rng.random(n) < 0.5
        pair = np.stack([np.where(swap, behavior, uniform), np.where(swap, uniform, behavior)])  # (2, N)
        utility[:, h] = optimal_advantage(s, pair, goals, horizon - h, family)  # A* of both in one call
        y = sample_preferences(utility[0, h], utility[1, h], bt_temperature, rng)
        states[h], first[h], second[h], preferred[h] = s, pair[0], pair[1], y
        s = transition(s, np.where(y == 1, pair[0], pair[1]), family.size)
        if family.terminate_on_goal:
            reached = (s[:, 0] == goals[:, 0]) & (s[:, 1] == goals[:, 1])
            if reached.any():
                s[reached] = family.sample_starts(goals[reached], rng)
    stats = {"label_agreement": label_agreement(utility[0], utility[1], preferred),
             "tie_fraction": float(np.mean(utility[0] == utility[1]))}
    arrays = {"states": states.transpose(1, 0, 2), "actions": first.T, "alt_actions": second.T,
              "preferred": preferred.T}
    return arrays, stats


def generate_reward_contexts(family: DarkRoomFamily, goals: np.ndarray, p_optimal: np.ndarray,
                             rng: np.random.Generator, progress: bool = False,
                             description: str = "reward contexts") -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """One rollout (s, a, r, s') of the mixed policy per row of ``goals``; DPT's context."""
    n, horizon = len(goals), family.horizon
    states = np.empty((n, horizon, 2), dtype=np.float32)
    next_states = np.empty((n, horizon, 2), dtype=np.float32)
    actions = np.empty((n, horizon), dtype=np.int8)
    rewards = np.empty((n, horizon), dtype=np.float32)
    s = family.sample_starts(goals, rng)
    for h in _steps(horizon, description, progress):
        a = mixed_actions(s, goals, p_optimal, rng)
        nxt = transition(s, a, family.size)
        states[:, h], actions[:, h], next_states[:, h] = s, a, nxt
        rewards[:, h] = step_reward(nxt, goals)
        s = nxt
        if family.terminate_on_goal:
            reached = rewards[:, h] > 0
            if reached.any():
                s[reached] = family.sample_starts(goals[reached], rng)
    arrays = {"states": states, "actions": actions, "rewards": rewards, "next_states": next_states}
    return arrays, {"mean_context_return": float(rewards.sum(1).mean())}
