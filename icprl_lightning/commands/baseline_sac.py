"""``icprl baseline sac``: SB3 SAC from scratch on each held-out Meta-World Reach goal
(``baselines/sac_from_scratch.py``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

import icprl_lightning.baselines.sac_from_scratch as source
from icprl_lightning.baselines.sac_from_scratch import DEFAULT_EPISODES, PAPER_EPISODES, run
from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.env import HORIZON
from icprl_lightning.io import write_json_atomic


def main(args: Sequence[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(prog="icprl baseline sac", description=source.__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                        help=f"training episodes per goal (paper: {PAPER_EPISODES})")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--family-seed", type=int, default=0, help="ReachTaskFamily seed (fixes the 5 test goals)")
    parser.add_argument("--horizon", type=int, default=HORIZON)
    parser.add_argument("--eval-every", type=int, default=2, help="episodes between checkpoint evaluations")
    parser.add_argument("--eval-episodes", type=int, default=2)
    parser.add_argument("--test-episodes", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest for these MLPs)")
    parser.add_argument("--out", type=Path,
                        default=Path("docs/results/sac_from_scratch/sac_from_scratch_metaworld.json"))
    ns = parser.parse_args(args)
    torch.set_num_threads(ns.threads)
    goals = ReachTaskFamily(seed=ns.family_seed).test_goals
    result = run(goals, ns.seeds, ns.episodes, ns.horizon, ns.eval_every, ns.eval_episodes, ns.test_episodes,
                 progress=True)
    result["family_seed"] = ns.family_seed
    result["command"] = "icprl baseline sac " + " ".join(sys.argv[1:] if args is None else args)
    out = write_json_atomic(ns.out, result)
    print(f"return {result['return']['mean']:.2f} ± {result['return']['sem']:.2f}, success "
          f"{result['success']['mean']:.2f} ± {result['success']['sem']:.2f} -> {out}")
    return out
