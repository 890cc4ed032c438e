"""``icprl evaluate online``: the command line of ``evaluation/online_command.py`` (its docstring is the --help)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import icprl_lightning.evaluation.online_command as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation import online_mdp
from icprl_lightning.evaluation.online_command import evaluate_online
from icprl_lightning.online import PAIR_RULES


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = command_parser("icprl evaluate online", source.__doc__)
    parser.add_argument("--config", action="append", required=True,
                        help="the checkpoints' dataset config (repeat to stack overlays)")
    parser.add_argument("--ckpt", action="append", default=None,
                        help="an I-PRL checkpoint (repeat: training seeds of one method)")
    parser.add_argument("--ad-ckpt", action="append", default=None,
                        help="bandits: an AD-on-duels checkpoint (configs/ad_bandit.yaml; repeat: training seeds)")
    parser.add_argument("--rule", action="append", choices=sorted(PAIR_RULES), default=None,
                        help="the pair rule the agent asks by (repeat to compare; default action_uniform)")
    parser.add_argument("--labels", choices=online_mdp.LABELS, default="own",
                        help="the online label diagnostic: the answers as given, inverted, or fair coins")
    parser.add_argument("--seeds", type=int, nargs="+", default=None,
                        help="episode seeds (default: 0 1 for MDP families, 0 for dueling bandits)")
    parser.add_argument("--episodes", type=int, default=None,
                        help="MDP: querying episodes in a row, max_context / episodes queries each (default 5)")
    parser.add_argument("--quality", default=None,
                        help="MDP: the suite whose tasks and episodes are played online (default medium)")
    parser.add_argument("--targets", type=float, nargs="*", default=None,
                        help="MDP: returns to reach (default: the offline rows')")
    parser.add_argument("--dqn", default=None, help="MDP: a JSON of `icprl baseline dqn` for its learning curve")
    parser.add_argument("--rounds", type=int, default=None, help="bandits: duels per problem (default 200)")
    parser.add_argument("--n-problems", type=int, default=None,
                        help="bandits: the first N held-out problems (default all)")
    parser.add_argument("--browser-session", default=None,
                        help="MDP: a person answers each comparison in the browser (the page's address is printed); "
                             "the answers are logged in this directory")
    parser.add_argument("--out", help="also write <out>.json, its table <out>.md and the figure <out>.png")
    return parser.parse_args(argv)
def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    result = evaluate_online(args.config, args.ckpt or [], args.rule or ["action_uniform"], args.labels, args.seeds,
                             args.episodes, args.quality, args.targets, args.dqn, args.rounds, args.n_problems,
                             args.out, args.ad_ckpt, args.browser_session)
    print(json.dumps(result, indent=2), flush=True)
    return result
