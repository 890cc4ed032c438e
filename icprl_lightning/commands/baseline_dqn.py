"""``icprl baseline dqn``: SB3 DQN from scratch on each held-out DarkRoom goal (``baselines/dqn_from_scratch.py``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

import icprl_lightning.baselines.dqn_from_scratch as source
from icprl_lightning.baselines.dqn_from_scratch import DEFAULT_EPISODES, PAPER_EPISODES, run
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.io import write_json_atomic


def main(args: Sequence[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(prog="icprl baseline dqn", description=source.__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                        help=f"training episodes per goal (paper: {PAPER_EPISODES})")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--family-seed", type=int, default=0, help="DarkRoomFamily seed (fixes the 20 test goals)")
    parser.add_argument("--n-goals", type=int, default=None, help="only the first N held-out goals (smoke runs)")
    parser.add_argument("--eval-every", type=int, default=5, help="episodes between checkpoint evaluations")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--test-episodes", type=int, default=50)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest for these MLPs)")
    parser.add_argument("--out", type=Path,
                        default=Path("docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json"))
    ns = parser.parse_args(args)
    torch.set_num_threads(ns.threads)
    family = DarkRoomFamily(seed=ns.family_seed)
    goals = family.test_goals[: ns.n_goals]
    result = run(family, goals, ns.seeds, ns.episodes, ns.eval_every, ns.eval_episodes, ns.test_episodes,
                 progress=True)
    result["family_seed"] = ns.family_seed
    result["command"] = "icprl baseline dqn " + " ".join(
        sys.argv[1:] if args is None else args)
    out = write_json_atomic(ns.out, result)
    print(f"return {result['return']['mean']:.1f} ± {result['return']['sem']:.1f}, success "
          f"{result['success']['mean']:.2f} ± {result['success']['sem']:.2f} -> {out}")
    return out
