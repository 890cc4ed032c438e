"""``icprl analyze dit-weights``: the command line of ``evaluation/dit_weights.py``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.dit_weights as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.dit_weights import MEASURES, dit_weights
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.io import write_json_atomic


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze dit-weights", source.__doc__)
    parser.add_argument("--ckpt", type=Path, action="append", required=True,
                        help="a DIT or ICRG checkpoint (repeat: seeds)")
    parser.add_argument("--json", type=Path, help="also write the per-checkpoint measures and their summary")
    args = parser.parse_args(argv)
    out = dit_weights(args.ckpt)
    print(f"| measure ({len(out['checkpoints'])} checkpoints, mean ± sem) | " + " | ".join(QUALITIES) + " |")
    print("|---|" + "---|" * len(QUALITIES))
    for m in MEASURES:
        cells = []
        for q in QUALITIES:
            mean, sem = out["summary"][q][m]
            cells.append("–" if mean is None else f"{mean:.3f}" + (f" ± {sem:.3f}" if sem is not None else ""))
        print(f"| {m} | " + " | ".join(cells) + " |")
    if args.json is not None:
        write_json_atomic(args.json, out)
    return out
