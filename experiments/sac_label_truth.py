"""Question: Do the SAC critic's I-PRL labels order actions as the task does?

Asked: 2026-12-02 (the first commit of this investigation, then scripts/sac_label_truth.py).

Answer (docs/RESULTS.md, "Meta-World Reach I-PRL on the paper's recipe: the SAC oracle"):
Mostly. On 150 (20%, 80%) action pairs of training goals the critic's sign agrees with the MuJoCo ground
truth on 83% of the pairs (correlation of the gaps 0.84), the scripted recipe's surrogate on 92%; a third of
the critic's gap (median 32%) comes from the gripper action a[3], which does not move the TCP. With T = 0.01
the labels agree with the true ordering on ≈ 70% of the pairs, against ≈ 80% in the scripted recipe.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

Do the SAC critic's I-PRL labels order actions as the task does? (issue 13, point 2)

The paper's Meta-World labels compare Q̂(s, a) − Q̂(s, a') of a converged SAC's critic. Their agreement with
Q̂ itself is what ``StepPreferences`` reports; this script measures what matters for a learner: how often
the sign of Q̂(s, a) − Q̂(s, a') agrees with the sign of the true difference, estimated in MuJoCo by
taking each action and then following the scripted expert to the horizon (``simulated_q_values``, the
return of a near-optimal continuation), and the same for the scripted recipe's surrogate ``expert_q_values``.

States: episodes on training goals where each step follows the 80%-checkpoint's or the 20%-checkpoint's
action (a fair coin), as the I-PRL data's states do; at every ``every``-th step the pair (a ~ π_20%,
a' ~ π_80%) is scored by both.

    python experiments/sac_label_truth.py --episodes 10 --every 10
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.oracle import expert_q_values, simulated_q_values
from icprl_lightning.families.metaworld_reach.sac_family import DEFAULT_ORACLE
from icprl_lightning.families.metaworld_reach.sac_weights import ExportedSAC


def measure(episodes: int, every: int, seed: int, oracle_dir=DEFAULT_ORACLE) -> dict:
    weights = ExportedSAC(oracle_dir)
    goals = ReachTaskFamily(seed=0).train_goals
    env = ReachGoalEnv(goals, goal_visible=True)
    rng = np.random.default_rng(seed)
    sac_gap, true_gap, surrogate_gap, grip_share = [], [], [], []
    for ep in range(episodes):
        env.reset(seed=int(rng.integers(2**31)), options={"goal_index": ep % len(goals)})
        for t in range(env.horizon):
            state = env.oracle_state()
            pair = np.stack([weights.sample_actions(state.obs, level, rng.standard_normal((1, 4)))[0]
                             for level in (0.2, 0.8)])
            if t % every == 0:
                q_sac = weights.q_values(np.repeat(state.obs, 2, axis=0), pair)
                q_true = simulated_q_values(env._env, pair, env.horizon)
                q_surrogate = expert_q_values(state, pair[:, None, :])[:, 0]
                sac_gap.append(q_sac[0] - q_sac[1])
                true_gap.append(q_true[0] - q_true[1])
                surrogate_gap.append(q_surrogate[0] - q_surrogate[1])
                # how much of Q̂'s gap the gripper dimension alone makes (it does not move the TCP)
                same_grip = pair.copy()
                same_grip[:, 3] = pair[1, 3]
                q_grip = weights.q_values(np.repeat(state.obs, 2, axis=0), same_grip)
                gap = q_sac[0] - q_sac[1]
                grip_share.append(abs(gap - (q_grip[0] - q_grip[1])) / max(abs(gap), 1e-9))
            env.step(pair[int(rng.random() < 0.5)])
    sac_gap, true_gap, surrogate_gap = map(np.asarray, (sac_gap, true_gap, surrogate_gap))
    strict = true_gap != 0
    return {"pairs": int(len(true_gap)), "episodes": episodes, "every": every, "seed": seed,
            "sac_sign_agreement_with_true": float(np.mean(np.sign(sac_gap[strict]) == np.sign(true_gap[strict]))),
            "surrogate_sign_agreement_with_true": float(np.mean(np.sign(surrogate_gap[strict])
                                                                == np.sign(true_gap[strict]))),
            "sac_true_correlation": float(np.corrcoef(sac_gap, true_gap)[0, 1]),
            "median_abs_true_gap": float(np.median(np.abs(true_gap))),
            "median_abs_sac_gap": float(np.median(np.abs(sac_gap))),
            "true_prefers_80_percent": float(np.mean(true_gap < 0)),
            "sac_prefers_80_percent": float(np.mean(sac_gap < 0)),
            "median_grip_share_of_sac_gap": float(np.median(grip_share))}


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--every", type=int, default=10, help="score the pair at every k-th step")
    parser.add_argument("--seed", type=int, default=0)
    ns = parser.parse_args(args)
    print(json.dumps(measure(ns.episodes, ns.every, ns.seed), indent=2))


if __name__ == "__main__":
    main()
