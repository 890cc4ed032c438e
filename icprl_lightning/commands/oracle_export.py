"""``icprl oracle export``: a SAC training run's weights as a checksummed, pickle-free oracle directory
(``families/metaworld_reach/sac_weights.py``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import icprl_lightning.families.metaworld_reach.sac_weights as source
from icprl_lightning.families.metaworld_reach.sac_weights import DEFAULT_TARGETS, ExportedSAC, export_sac_oracle


def main(args: Sequence[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(prog="icprl oracle export", description=source.__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="a training run of `icprl oracle train`")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--targets", type=float, nargs="+", default=list(DEFAULT_TARGETS))
    parser.add_argument("--overwrite", action="store_true")
    ns = parser.parse_args(args)
    out = export_sac_oracle(ns.run_dir, ns.out, ns.targets, ns.overwrite)
    oracle = ExportedSAC(out)
    for level in oracle.levels:
        p = oracle.policy_info(level)
        print(f"level {level}: step {p['step']}, eval return {p['eval_return']:.2f}, success {p['eval_success']:.2f}, "
              f"normalized {p['normalized_return']:.2f}", file=sys.stderr)
    return out
