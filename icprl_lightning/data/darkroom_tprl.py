"""DarkRoom T-PRL data (paper, appendix "Pretraining Data Generation", T-PRL; preference model eq. (t-prl-pref)).

A context D^T = {ξ_a, ξ_b, y}: two rollouts of the same mixed behavior policy (the optimal action with
probability p, else a uniform one) on one task, each from its own random start, and a label drawn from
the Bradley–Terry model on their latent returns,

    P(y = 1) = σ((Σ_h r(s_h, a_h | ξ_a) − Σ_h r(s_h, a_h | ξ_b)) / bt_temperature).

Trajectories hold states and actions only. The per-step rewards are returned apart from them: only the
reward-supervised DIT baseline's dataset stores them, a preference dataset never does. Evaluation
contexts also carry an unlabeled behavior trajectory {s_h, a_h} of the same policy: the one RewardGen
labels when ICRG is deployed (paper, "ICRG Deployment").

Temperature: DarkRoom returns lie in [0, ~95] (reward 1 per step on the goal). At the paper's
temperature of 1 a return gap of 3 already gives 95% agreement, so labels are close to deterministic
except between near-equal returns, and ties (typically two low-quality rollouts that never reach the
goal, both returning 0) are coin flips. The statistics record the agreement rate and the tie fraction.

Rollouts step the vectorized environment, all trajectories of all tasks at once (a loop over time only);
with ``terminate_on_goal`` a finished episode stays frozen with zero reward, as the environment defines.
"""

from __future__ import annotations

import numpy as np
from rich.progress import track

from icprl_lightning.data.tprl import label_trajectory_pairs
from icprl_lightning.envs.darkroom import DarkRoomFamily
from icprl_lightning.oracles.darkroom import mixed_actions


def rollout_mixed_policy(family: DarkRoomFamily, goals: np.ndarray, p_optimal: np.ndarray, rng: np.random.Generator,
                         progress: bool = False, description: str = "rollouts"
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One rollout per row of ``goals`` [N, 2] with mixing probability ``p_optimal`` [N].

    Returns states [N, H, 2] float32 (s_h, before acting), actions [N, H] int8 and rewards [N, H] float32.
    """
    n, horizon = len(goals), family.horizon
    states = np.empty((n, horizon, 2), dtype=np.float32)
    actions = np.empty((n, horizon), dtype=np.int8)
    rewards = np.empty((n, horizon), dtype=np.float32)
    env = family.make_env(goals)
    env.reset(seed=int(rng.integers(2**31)))
    for h in track(range(horizon), description=description, disable=not progress, transient=True):
        states[:, h] = env.states
        actions[:, h] = mixed_actions(env.states, goals, p_optimal, rng)
        _, rewards[:, h], _, _, _ = env.step(actions[:, h])
    return states, actions, rewards


def generate_trajectory_preferences(family: DarkRoomFamily, goals: np.ndarray, p_optimal: np.ndarray,
                                    bt_temperature: float, rng: np.random.Generator, behavior: bool = False,
                                    progress: bool = False, description: str = "T-PRL pairs"
                                    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """One T-PRL context per row of ``goals`` [N, 2] (mixing probability ``p_optimal`` [N]).

    Returns ``(arrays, rewards, stats)`` as ``data.tprl.label_trajectory_pairs``: the reward-free context
    arrays, the per-step latent rewards of each trajectory (oracle only) and the label statistics.
    """
    k = 3 if behavior else 2
    states, actions, rewards = rollout_mixed_policy(family, np.tile(goals, (k, 1)), np.tile(p_optimal, k), rng,
                                                    progress, description)
    return label_trajectory_pairs(states, actions, rewards, len(goals), bt_temperature, rng, behavior)
