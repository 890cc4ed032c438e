"""``icprl analyze reward-bayes``: the command line of ``evaluation/reward_bayes.py``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.reward_bayes as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.reward_bayes import EVIDENCE, reward_bayes
from icprl_lightning.evaluation.reward_quality import MEASURES
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.io import write_json_atomic


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze reward-bayes", source.__doc__)
    parser.add_argument("--data-config", type=Path, required=True,
                        help="a DarkRoom T-PRL data config (a RewardGen run's config.yaml: the same held-out data)")
    parser.add_argument("--data-root", help="override the config's data.init_args.root_dir")
    parser.add_argument("--json", type=Path, help="also write the measures here")
    args = parser.parse_args(argv)
    result = reward_bayes(args.data_config, args.data_root)
    if args.json is not None:
        write_json_atomic(args.json, result)
    out = result["bayes"]
    keys = ("other_pair_accuracy", "reward_correlation", "posterior_on_goal")
    names = {**MEASURES, "posterior_on_goal": "p(true goal)"}
    print(f"Bayes-optimal reward from one pair on the held-out goals (prior {result['prior']}); low / medium / high")
    print("| posterior from | " + " | ".join(names[k] for k in keys) + " |\n|---|" + "---|" * len(keys))
    for e, what in EVIDENCE.items():
        print(f"| {what} | " + " | ".join(" / ".join(f"{out[e][q][k]:.2f}" for q in QUALITIES) for k in keys) + " |")
    if args.json is not None:
        print(f"wrote {args.json}")
    return result
