"""``icprl oracle train``: train the goal-conditioned SB3 SAC oracle on Reach goals
(``families/metaworld_reach/sac.py``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

import icprl_lightning.families.metaworld_reach.sac as source
from icprl_lightning.commands import command_parser
from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.env import HORIZON
from icprl_lightning.families.metaworld_reach.sac import SACTrainingRun, train_sac_oracle


def main(args: Sequence[str] | None = None) -> Path:
    parser = command_parser("icprl oracle train", source.__doc__.split("\n\n")[0])
    parser.add_argument("--goals", choices=("train", "test", "all"), default="train")
    parser.add_argument("--goal-index", type=int, default=None, help="train on this one goal of the split (per-task)")
    parser.add_argument("--timesteps", type=int, required=True)
    parser.add_argument("--checkpoint-every", type=int, default=None, help="default: timesteps // 20")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--horizon", type=int, default=HORIZON)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--family-seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest for these MLPs)")
    parser.add_argument("--n-envs", type=int, default=1, help="envs collecting at once (n transitions per update)")
    parser.add_argument("--reward-scale", type=float, default=1.0, help="SAC learns from this × the latent reward")
    parser.add_argument("--learning-rate", type=float, default=None, help="default: SB3's 3e-4")
    parser.add_argument("--gradient-steps", type=int, default=None, help="per vector step; default: SB3's 1")
    parser.add_argument("--batch-size", type=int, default=None, help="default: SB3's 256")
    parser.add_argument("--gamma", type=float, default=None, help="discount; default: SB3's 0.99")
    parser.add_argument("--verbose", action="store_true", help="print each evaluation to stderr")
    parser.add_argument("--overwrite", action="store_true")
    parser.add_argument("--out", type=Path, required=True)
    ns = parser.parse_args(args)
    torch.set_num_threads(ns.threads)
    family = ReachTaskFamily(seed=ns.family_seed)
    goals = np.concatenate([family.train_goals, family.test_goals]) if ns.goals == "all" else family.goals(ns.goals)
    if ns.goal_index is not None:
        goals = goals[ns.goal_index : ns.goal_index + 1]
    argv = sys.argv[1:] if args is None else args
    command = "icprl oracle train " + " ".join(argv)
    out = train_sac_oracle(goals, ns.out, ns.timesteps, ns.seed, ns.checkpoint_every, ns.eval_episodes, ns.horizon,
                           overwrite=ns.overwrite, extra={"goal_split": ns.goals, "goal_index": ns.goal_index,
                                                          "family_seed": ns.family_seed, "command": command},
                           n_envs=ns.n_envs, report_splits={"train": family.train_goals, "test": family.test_goals},
                           reward_scale=ns.reward_scale, verbose=int(ns.verbose),
                           sac_kwargs={k: v for k, v in (("learning_rate", ns.learning_rate),
                                                         ("gradient_steps", ns.gradient_steps),
                                                         ("batch_size", ns.batch_size),
                                                         ("gamma", ns.gamma)) if v is not None})
    summary = SACTrainingRun(out).summary
    for name, c in summary["calibration"].items():
        print(f"{name}: step {c['step']}, normalized {c['achieved']:.2f} (target {c['target']}), "
              f"vs expert {c['achieved_vs_expert']:.2f}")
    for name, r in summary["final_by_split"].items():
        print(f"final policy on the {name} goals: success {r['deterministic']['success']:.2f} (mean action), "
              f"{r['stochastic']['success']:.2f} (sampled); return {r['deterministic']['return']:.1f} vs expert "
              f"{r['expert']['return']:.1f}, uniform {r['uniform']['return']:.1f}")
    if not summary["final_beats_uniform"]:
        print("warning: the final policy does not beat uniform actions; train longer", file=sys.stderr)
    return out
