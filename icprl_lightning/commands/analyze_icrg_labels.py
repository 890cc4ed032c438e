"""``icprl analyze icrg-labels``: the command line of ``evaluation/icrg_labels.py``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.icrg_labels as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.icrg_labels import icrg_labels
from icprl_lightning.io import write_json_atomic


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = command_parser("icprl analyze icrg-labels", source.__doc__)
    parser.add_argument("--ckpt", type=Path, nargs="+", action="extend", required=True, help="ICRG checkpoint(s)")
    parser.add_argument("--config", type=Path, required=True, help="the ICRG runs' data config (their config.yaml)")
    parser.add_argument("--data-root", help="override the config's data.init_args.root_dir")
    parser.add_argument("--rows", type=int, default=2000, help="training rows whose labels are scored")
    parser.add_argument("--seed", type=int, default=0, help="draws the training rows and their other pairs")
    parser.add_argument("--json", type=Path, help="also write the correlations here")
    args = parser.parse_args(argv)
    if args.rows < 1:
        parser.error(f"--rows must be >= 1, got {args.rows}")
    out = icrg_labels(args.config, args.ckpt, args.rows, args.seed, args.data_root)
    if args.json is not None:
        write_json_atomic(args.json, out)
    print("| checkpoint | labels | training goals | held-out low | medium | high |\n|---|---|---|---|---|---|")
    for path, r in out["correlation"].items():
        d = r["deployment"]
        print(f"| {path} | {'cross-fitted' if r['cross_fitted'] else 'in-sample'} | {r['training']:.3f} | "
              f"{d['low']:.3f} | {d['medium']:.3f} | {d['high']:.3f} |")
    return out
