"""``icprl baseline dqn``: SB3 DQN from scratch on each held-out DarkRoom goal (``baselines/dqn_from_scratch.py``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import icprl_lightning.baselines.dqn_from_scratch as source
from icprl_lightning.baselines.dqn_from_scratch import DEFAULT_EPISODES, PAPER_EPISODES, run
from icprl_lightning.commands import baseline_parser, run_baseline
from icprl_lightning.families.darkroom import DarkRoomFamily


def main(args: Sequence[str] | None = None) -> Path:
    parser = baseline_parser("icprl baseline dqn", source.__doc__, PAPER_EPISODES, DEFAULT_EPISODES,
                             "DarkRoomFamily seed (fixes the 20 test goals)",
                             5, 10, 50, "docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json")
    parser.add_argument("--n-goals", type=int, default=None, help="only the first N held-out goals (smoke runs)")
    ns = parser.parse_args(args)

    def play() -> dict:
        family = DarkRoomFamily(seed=ns.family_seed)
        return run(family, family.test_goals[: ns.n_goals], ns.seeds, ns.episodes, ns.eval_every, ns.eval_episodes,
                   ns.test_episodes, progress=True)

    return run_baseline("icprl baseline dqn", ns, args, 1, play)
