"""``icprl analyze reward-quality``: the command line of ``evaluation/reward_quality.py``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.reward_quality as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.reward_quality import reward_quality, table
from icprl_lightning.io import write_json_atomic


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze reward-quality", source.__doc__)
    parser.add_argument("--ckpt", type=Path, nargs="+", action="extend", required=True,
                        help="RewardGen checkpoint(s) of one configuration (repeat or list: training seeds)")
    parser.add_argument("--data-config", type=Path, required=True,
                        help="the checkpoints' T-PRL data config (its held-out evaluation splits are scored)")
    parser.add_argument("--data-root", help="override the config's data.init_args.root_dir")
    parser.add_argument("--json", type=Path, help="also write the measures here")
    args = parser.parse_args(argv)
    out = reward_quality(args.data_config, args.ckpt, args.data_root)
    if args.json is not None:
        write_json_atomic(args.json, out)
    print(f"RewardGen (pair_source={out['pair_source']}) on held-out tasks, mean ± sem over "
          f"{len(out['checkpoints'])} checkpoint(s)")
    print(table(out["mean"]))
    print(f"own pair read with: {out['own_pair_reading']}")
    if args.json is not None:
        print(f"wrote {args.json}")
    return out
