"""Meta-World Reach T-PRL data (paper, appendix "Pretraining Data Generation", Meta-World T-PRL;
preference model eq. (t-prl-pref)).

A context D^T = {ξ_a, ξ_b, y}: two rollouts of the same behavior policy on one goal (pretraining: the
policy at 50% of the expert's normalized return, the paper's "SAC checkpoints with 50% return"; here
the oracle's expert/uniform mixture, ``oracles/metaworld_reach.py``) and a label drawn from the
Bradley–Terry model on their latent returns R = Σ_h −‖tcp_h − goal‖,

    P(y = 1) = σ((R(ξ_a) − R(ξ_b)) / bt_temperature).

Trajectories hold states (goal zeroed) and actions only; the per-step rewards are returned apart from
them (``data/tprl.py``): only the DIT baseline's dataset stores them. Evaluation contexts also carry an
unlabeled behavior trajectory {s_h, a_h} of the same policy, the one RewardGen labels when ICRG is
deployed (paper, "ICRG Deployment"). Query labels for DP²T: H states drawn without replacement from the
2H states the pair visited, in random order, with the expert's actions there (float32 [N, H, 4]).

Temperature. Two rollouts of one policy on one goal start from the same arm pose, but most of the 50%
policy's actions are uniform noise (p_expert = 0.140 in the default dataset), so their returns (mean
−25.3 over 150 steps) differ by several units, far more than the per-step differences of I-PRL.
``DEFAULT_TPRL_BT_TEMPERATURE`` keeps the paper's 1: the labels carry signal and stay noisy between
near-equal returns, as the BT model means them to. The manifest of
``icprl generate --config configs/reward_gen_metaworld.yaml`` reports label agreement 0.918 with the
true return ordering on the 450 training pairs (``train_statistics``); returns are continuous, so
``tie_fraction`` is 0.

Rollouts run in ``ReachVectorEnv`` chunks (``data/metaworld_reach.py``): every trajectory of a chunk,
ξ_a, ξ_b and the behavior trajectory of all rows alike, steps together.
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.data.metaworld_reach import rollout_mixed_policy
from icprl_lightning.data.tprl import label_trajectory_pairs
from icprl_lightning.envs.metaworld_reach import ReachTaskFamily

DEFAULT_TPRL_BT_TEMPERATURE = 1.0


def generate_trajectory_preferences(family: ReachTaskFamily, goals: np.ndarray, p_expert: np.ndarray,
                                    bt_temperature: float, rng: np.random.Generator, behavior: bool = False,
                                    num_workers: int = 2, progress: bool = False, description: str = "T-PRL pairs"
                                    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """One T-PRL context per row of ``goals`` [N, 3] (mixing probability ``p_expert`` [N]).

    Returns ``(arrays, rewards, stats)``: the reward-free context arrays (``states_a`` [N, H, 39],
    ``actions_a`` [N, H, 4], ``states_b``, ``actions_b``, ``preferred`` [N] uint8, with ``behavior`` also
    ``behavior_states`` and ``behavior_actions``; and the query labels ``query_states`` [N, H, 39] and
    ``optimal_actions`` [N, H, 4]), the per-step latent rewards of each trajectory (oracle only) and the
    label statistics of ``data.tprl.label_trajectory_pairs``.
    """
    n = len(goals)
    k = 3 if behavior else 2
    roll = rollout_mixed_policy(family, np.tile(goals, (k, 1)), np.tile(p_expert, k), rng, num_workers, progress,
                                description)
    arrays, rewards, stats = label_trajectory_pairs(roll["states"], roll["actions"], roll["rewards"], n,
                                                    bt_temperature, rng, behavior)
    arrays.update(pair_queries(roll["states"], roll["optimal"], n, rng))
    return arrays, rewards, stats


def pair_queries(states: np.ndarray, optimal: np.ndarray, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """H of the 2H states pair i visited (rows i and n + i of ``states`` [kN, H, S]), without replacement and
    in random order, with the expert's actions there (``optimal`` [kN, H, A]): DP²T's query labels."""
    horizon = states.shape[1]
    step = rng.permuted(np.tile(np.arange(2 * horizon), (n, 1)), axis=1)[:, :horizon]  # [N, H] into ξ_a ++ ξ_b
    rows = np.arange(n)[:, None] + np.where(step < horizon, 0, n)
    return {"query_states": states[rows, step % horizon], "optimal_actions": optimal[rows, step % horizon]}
