"""``icprl analyze dit-advantages``: the command line of ``evaluation/dit_advantages.py``."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import icprl_lightning.evaluation.dit_advantages as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.dit_advantages import dit_advantages


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze dit-advantages", source.__doc__)
    parser.add_argument("--dit", required=True, help="CONFIG:CHECKPOINT of DIT on true rewards")
    parser.add_argument("--icrg", help="CONFIG:CHECKPOINT of ICRG (optional: without it, DIT's correlations only)")
    parser.add_argument("--oracle", action="store_true",
                        help="also correlate with the SAC oracle's A*(s, a) (Meta-World Reach, SAC recipe)")
    args = parser.parse_args(argv)
    out = dit_advantages(args.dit, args.icrg, args.oracle)
    print(json.dumps(out, indent=2))
    return out
