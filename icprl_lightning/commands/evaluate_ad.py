"""``icprl evaluate ad``: the command line of ``evaluation/ad_command.py`` (its docstring is the --help)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import icprl_lightning.evaluation.ad_command as source
from icprl_lightning.commands import command_parser
from icprl_lightning.evaluation.ad_command import ADInputError, ad_markdown, evaluate_ad, parse_run


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = command_parser("icprl evaluate ad", source.__doc__)
    parser.add_argument("--run", action="append", required=True,
                        help="NAME=CONFIG:CHECKPOINT[,CHECKPOINT...]: an AD run (several checkpoints: training seeds)")
    parser.add_argument("--episodes", type=int, default=20, help="consecutive episodes per held-out goal")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="episode seeds")
    parser.add_argument("--out", required=True, help="output path without extension: <out>.json, .md, .png")
    parser.add_argument("--title", default="AD on held-out goals", help="figure title")
    parser.add_argument("--against", action="append", default=[],
                        help="NAME=JSON of `icprl evaluate online` on the same goals: its per-episode curve beside AD")
    args = parser.parse_args(argv)
    args.parser = parser
    return args
def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    try:
        runs: dict[str, tuple[str, list[str]]] = {}
        for spec in args.run:
            name, config, checkpoints = parse_run(spec)
            if name in runs:
                raise ADInputError(f"--run name {name!r} is given twice: names must be unique")
            runs[name] = (config, checkpoints)
        against = {}
        for spec in args.against:
            name, _, path = spec.partition("=")
            if not (name and path) or name in against:
                raise ADInputError(f"--against {spec!r} is not NAME=JSON with a name of its own")
            against[name] = path
        if not Path(args.out).parent.is_dir():
            raise ADInputError(f"--out {args.out}: its folder {Path(args.out).parent} does not exist")
        payload = evaluate_ad(runs, args.episodes, args.seeds, args.out, args.title, against)
    except ADInputError as e:
        args.parser.exit(2, f"{args.parser.prog}: error: {e}\n")
    print(ad_markdown(payload), end="", flush=True)
    print(f"wrote {args.out}.json, {args.out}.md, {args.out}.png", flush=True)
    return payload
