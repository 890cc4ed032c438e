"""``icprl baseline sac``: SB3 SAC from scratch on each held-out Meta-World Reach goal
(``baselines/sac_from_scratch.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import icprl_lightning.baselines.sac_from_scratch as source
from icprl_lightning.baselines.sac_from_scratch import DEFAULT_EPISODES, PAPER_EPISODES, run
from icprl_lightning.commands import baseline_parser, run_baseline
from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.env import HORIZON


def main(args: Sequence[str] | None = None) -> Path:
    parser = baseline_parser("icprl baseline sac", source.__doc__, PAPER_EPISODES, DEFAULT_EPISODES,
                             "ReachTaskFamily seed (fixes the 5 test goals)",
                             2, 2, 10, "docs/results/sac_from_scratch/sac_from_scratch_metaworld.json")
    parser.add_argument("--horizon", type=int, default=HORIZON)
    ns = parser.parse_args(args)
    return run_baseline("icprl baseline sac", ns, args, 2, lambda: run(
        ReachTaskFamily(seed=ns.family_seed).test_goals, ns.seeds, ns.episodes, ns.horizon, ns.eval_every,
        ns.eval_episodes, ns.test_episodes, progress=True))
