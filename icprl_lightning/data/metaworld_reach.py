"""Meta-World Reach pretraining and evaluation data (paper, appendix "Pretraining Data Generation", Meta-World).

I-PRL (``generate_step_preferences``): at every step h one action comes from the first policy and one
from the second (pretraining: the 20% and the 80% behavior policy, the paper's pair); their slots are
shuffled so that position carries no information. The label is
y ~ BT((A(s, a) − A(s, a')) / bt_temperature), with the oracle's A estimate (``oracles/metaworld_reach.py``:
A differences are Q^E differences, computed for both actions in one vectorized surrogate rollout),
and the environment steps with the preferred action.

Reward contexts (``generate_reward_contexts``, DPT's oracle baseline): rollouts (s, a, r, s') of one
mixed behavior policy per trajectory, r = −‖tcp − goal‖.

Both carry query labels for the supervised methods (DPT, DP²T): ``query_states`` are the states the
trajectory visited, in a random order per trajectory (so a query's position says nothing about where
its state sits in the context), and ``optimal_actions`` the expert's actions there (float32 [N, H, 4]).

Rollouts run in ``ReachVectorEnv`` (worker processes on both cores), at most ``MAX_ENVS`` episodes at
a time; every trajectory of a chunk steps together.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from rich.progress import track

from icprl_lightning.envs.metaworld_reach import ACTION_DIM, OBS_DIM, ReachTaskFamily
from icprl_lightning.oracles.metaworld_reach import expert_actions, expert_q_values, mixed_actions
from icprl_lightning.preferences import label_agreement, sample_preferences

MAX_ENVS = 1024  # episodes simulated at once; bounds memory (≈0.7 MB per env) for paper-sized datasets


def _chunks(n: int, description: str) -> Iterator[tuple[slice, str]]:
    """Row slices of at most MAX_ENVS trajectories, each with its progress-bar label."""
    starts = range(0, n, MAX_ENVS)
    for i, lo in enumerate(starts):
        label = description if len(starts) == 1 else f"{description} ({i + 1}/{len(starts)})"
        yield slice(lo, min(lo + MAX_ENVS, n)), label


def _steps(horizon: int, description: str, progress: bool) -> Iterator[int]:
    return track(range(horizon), description=description, disable=not progress, transient=True)


def time_permuted_queries(states: np.ndarray, optimal: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Visited states [N, H, S] and expert actions [N, H, A], each trajectory's steps in a random order."""
    order = rng.permuted(np.tile(np.arange(states.shape[1]), (len(states), 1)), axis=1)[..., None]  # [N, H, 1]
    return {"query_states": np.take_along_axis(states, order, axis=1),
            "optimal_actions": np.take_along_axis(optimal, order, axis=1)}


def generate_step_preferences(family: ReachTaskFamily, goals: np.ndarray, p_first: np.ndarray, p_second: np.ndarray,
                              bt_temperature: float, rng: np.random.Generator, num_workers: int = 2,
                              progress: bool = False, description: str = "I-PRL contexts",
                              ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """One I-PRL context of H comparisons per row of ``goals`` [N, 3].

    At each step the pair is (a ~ π_{p_first}, a' ~ π_{p_second}) of the mixed policies (expert with
    probability p, else uniform), one p per row, in shuffled slots. Returns the arrays (``states``,
    ``actions``, ``alt_actions``, ``preferred`` = 1 when ``actions`` won, plus the query labels) and
    statistics: the label agreement with the sign of the A difference and the share of tied pairs.
    """
    n, horizon = len(goals), family.horizon
    states = np.empty((n, horizon, OBS_DIM), dtype=np.float32)
    pair = np.empty((2, n, horizon, ACTION_DIM), dtype=np.float32)
    optimal = np.empty((n, horizon, ACTION_DIM), dtype=np.float32)
    preferred = np.empty((n, horizon), dtype=np.uint8)
    utility = np.empty((2, n, horizon))
    for rows, label in _chunks(n, description):
        m = rows.stop - rows.start
        with family.make_env(goals[rows], num_workers=num_workers) as env:
            obs, _ = env.reset(seed=int(rng.integers(2**31)))
            for h in _steps(horizon, label, progress):
                state = env.oracle_state()
                first = mixed_actions(state, p_first[rows], rng)
                second = mixed_actions(state, p_second[rows], rng)
                swap = (rng.random(m) < 0.5)[:, None]
                both = np.stack([np.where(swap, second, first), np.where(swap, first, second)])  # [2, m, 4]
                q = expert_q_values(state, both, horizon)  # [2, m]: their difference is the A difference
                y = sample_preferences(q[0], q[1], bt_temperature, rng)
                states[rows, h], pair[:, rows, h], optimal[rows, h] = obs, both, expert_actions(state)
                preferred[rows, h], utility[:, rows, h] = y, q
                obs, *_ = env.step(np.where(y[:, None] == 1, both[0], both[1]))
    stats = {"label_agreement": label_agreement(utility[0], utility[1], preferred),
             "tie_fraction": float(np.mean(utility[0] == utility[1]))}
    arrays = {"states": states, "actions": pair[0], "alt_actions": pair[1], "preferred": preferred}
    arrays.update(time_permuted_queries(states, optimal, rng))
    return arrays, stats


def rollout_mixed_policy(family: ReachTaskFamily, goals: np.ndarray, p_expert: np.ndarray, rng: np.random.Generator,
                         num_workers: int = 2, progress: bool = False, description: str = "rollouts"
                         ) -> dict[str, np.ndarray]:
    """One rollout of the mixed policy π_p per row of ``goals`` [N, 3] (p [N]), all rows of a chunk at once.

    Returns ``states`` [N, H, 39] (s_h before acting, goal zeroed), ``actions`` [N, H, 4], the latent
    ``rewards`` [N, H], the observation after the last step ``final_states`` [N, 39] and the expert's
    actions at the visited states ``optimal`` [N, H, 4] (oracle only).
    """
    n, horizon = len(goals), family.horizon
    out = {"states": np.empty((n, horizon, OBS_DIM), dtype=np.float32),
           "actions": np.empty((n, horizon, ACTION_DIM), dtype=np.float32),
           "rewards": np.empty((n, horizon), dtype=np.float32),
           "final_states": np.empty((n, OBS_DIM), dtype=np.float32),
           "optimal": np.empty((n, horizon, ACTION_DIM), dtype=np.float32)}
    for rows, label in _chunks(n, description):
        with family.make_env(goals[rows], num_workers=num_workers) as env:
            obs, _ = env.reset(seed=int(rng.integers(2**31)))
            for h in _steps(horizon, label, progress):
                state = env.oracle_state()
                a = mixed_actions(state, p_expert[rows], rng)
                out["states"][rows, h], out["actions"][rows, h], out["optimal"][rows, h] = obs, a, expert_actions(state)
                obs, out["rewards"][rows, h], *_ = env.step(a)
            out["final_states"][rows] = obs
    return out


def generate_reward_contexts(family: ReachTaskFamily, goals: np.ndarray, p_expert: np.ndarray,
                             rng: np.random.Generator, num_workers: int = 2, progress: bool = False,
                             description: str = "reward contexts") -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """One rollout (s, a, r, s') of the mixed policy π_p per row of ``goals`` [N, 3] (p [N]); DPT's context."""
    roll = rollout_mixed_policy(family, goals, p_expert, rng, num_workers, progress, description)
    states = roll["states"]
    arrays = {"states": states, "actions": roll["actions"], "rewards": roll["rewards"],
              "next_states": np.concatenate([states[:, 1:], roll["final_states"][:, None]], axis=1)}
    arrays.update(time_permuted_queries(states, roll["optimal"], rng))
    return arrays, {"mean_context_return": float(roll["rewards"].sum(1, dtype=np.float64).mean())}
