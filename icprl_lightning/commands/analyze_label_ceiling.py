"""``icprl analyze label-ceiling``: the command line of ``evaluation/label_ceiling.py``."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.label_ceiling as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.label_ceiling import label_ceiling
from icprl_lightning.io import write_json_atomic


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze label-ceiling", source.__doc__)
    parser.add_argument("--config", action="append", required=True,
                        help="a DarkRoom I-PRL config (repeat to stack overlays)")
    parser.add_argument("--json", type=Path, help="also write the result here")
    args = parser.parse_args(argv)
    out = label_ceiling(args.config)
    if args.json is not None:
        write_json_atomic(args.json, out)
    print(json.dumps(out, indent=2))
    return out
