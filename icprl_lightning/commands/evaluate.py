"""``icprl evaluate``: the command line of ``evaluation/command.py`` (its docstring is this command's --help);
``online`` and ``ad`` go to ``evaluate_online.py`` and ``evaluate_ad.py``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, NoReturn

import icprl_lightning.evaluation.command as source
from icprl_lightning.evaluation.command import RESERVED, bandit_payload, default_out, rollout_payload
from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS
from icprl_lightning.evaluation.pairing import is_bandit_data, run_datamodule
from icprl_lightning.evaluation.report import aligned_tables, markdown_tables, read_baseline, write_outputs


def fail(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """Exit 2 with one line on stderr: a file or a pairing is wrong, not the command's syntax (no usage text)."""
    parser.exit(2, f"{parser.prog}: error: {message}\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="icprl evaluate", description=source.__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True,
                        help="NAME=CONFIG:CHECKPOINT[,CHECKPOINT...] (several: training seeds of one method)")
    parser.add_argument("--baseline", action="append", default=[], help="NAME=JSON of a from-scratch baseline")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    actions = parser.add_mutually_exclusive_group()
    actions.add_argument("--sample", action="store_true", help="sample a ~ T(a|s,D) for every method")
    actions.add_argument("--greedy", action="store_true", help="argmax / Gaussian mean for every method")
    parser.add_argument("--reference", help="NAME of the --run whose dataset gives the reference rows "
                        "(behavior and optimal/expert; bandits: DTS and behaviour; default: the first)")
    parser.add_argument("--contexts", nargs="+", choices=DIAGNOSTICS, default=["own"],
                        help="context diagnostics beside the own-context rows: flipped_labels, random_labels, "
                        "other_task, shuffled_order (evaluation.diagnostics)")
    parser.add_argument("--no-baselines", action="store_true", help="dueling bandits: only the runs' rows, "
                        "without DTS, MaxInP, BT Thompson sampling, the Bayes reference and behaviour (minutes on "
                        "200 problems)")
    parser.add_argument("--data", action="append", default=[], metavar="FILE",
                        help="a YAML data section stacked on every run's config (e.g. configs/eval/"
                        "reach_fresh_goals.yaml: other held-out tasks); the checkpoints are unchanged")
    parser.add_argument("--evaluation", help="a registered evaluation of your own (evaluation/base.py, "
                        "docs/extending_evaluations.md) instead of the built-in tables")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="--evaluation: a keyword of its constructor (VALUE read as YAML)")
    parser.add_argument("--title", default="held-out tasks", help="figure title")
    parser.add_argument("--out", help="output path without extension (default: <run dir>/eval/<date-time> of the "
                        "first checkpoint)")
    args = parser.parse_args(argv)
    args.runs = {}
    for spec in args.run:
        name, _, rest = spec.partition("=")
        config, _, checkpoints = rest.partition(":")
        checkpoint = [c for c in checkpoints.split(",") if c]
        if not (name and config and checkpoint):
            parser.error(f"--run {spec!r} is not NAME=CONFIG:CHECKPOINT[,CHECKPOINT...]")
        if name in RESERVED or name in args.runs:
            parser.error(f"--run name {name!r} is taken (reference rows: {', '.join(sorted(RESERVED))}; "
                         "names must be unique)")
        args.runs[name] = (config, checkpoint)
    for path in args.data:
        if not Path(path).is_file():
            fail(parser, f"--data {path}: no such file")
    args.diagnostics = [d for d in dict.fromkeys(args.contexts) if d != "own"]
    args.reference = args.reference or next(iter(args.runs))
    if args.reference not in args.runs:
        parser.error(f"--reference {args.reference!r} names no --run (runs: {', '.join(args.runs)})")
    args.baselines = {}
    for spec in args.baseline:  # read now: a bad file fails here, not after the whole evaluation
        name, _, path = spec.partition("=")
        if not (name and path):
            parser.error(f"--baseline {spec!r} is not NAME=JSON")
        if name in RESERVED or name in args.runs or name in args.baselines:
            parser.error(f"--baseline name {name!r} is taken (a --run, another --baseline or a reference row)")
        try:
            args.baselines[name] = read_baseline(path)
        except ValueError as e:
            fail(parser, str(e))
    args.out = args.out or str(default_out(next(iter(args.runs.values()))[1][0]))
    args.parser = parser
    return args


def main(argv: list[str] | None = None) -> dict:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["online"]:  # the online mode: its own options (evaluation/online_command.py)
        from icprl_lightning.commands.evaluate_online import main as online_main

        return online_main(argv[1:])
    if argv[:1] == ["ad"]:  # Algorithm Distillation across episodes: its own options (evaluation/ad_command.py)
        from icprl_lightning.commands.evaluate_ad import main as ad_main

        return ad_main(argv[1:])
    args = parse_args(argv)
    greedy = False if args.sample else True if args.greedy else None  # None: each method's own default
    datamodules = {}
    for name, (config, checkpoints) in args.runs.items():  # every check before any dataset is generated
        try:
            datamodules[name] = run_datamodule(name, config, checkpoints, args.data)
        except ValueError as e:
            fail(args.parser, str(e))
    if args.evaluation:
        return run_registered(args, datamodules, greedy)
    kinds = {name: is_bandit_data(dm) for name, dm in datamodules.items()}
    if len(set(kinds.values())) > 1:
        fail(args.parser, "runs mix dueling bandits with MDP families: "
                          + ", ".join(f"{n} ({'bandit' if b else 'MDP'})" for n, b in kinds.items()))
    bandit = kinds[args.reference]
    if bandit and args.baseline:
        fail(args.parser, "--baseline applies to MDP families, not dueling bandits")
    for name, dm in datamodules.items():
        getattr(dm, "prepare_heldout", dm.prepare_data)()  # only the held-out data, when it can
        if not bandit and not dm.evaluation_suites():
            fail(args.parser, f"--run {name}: the data of {args.runs[name][0]} has no held-out rollouts to "
                              "evaluate on (recorded data has no simulator); use a task family's config")
    actions_used = "sampled" if args.sample else "greedy" if args.greedy else "each method's default"
    payload: dict[str, Any] = {"title": args.title, "seeds": args.seeds, "actions": actions_used}
    if args.data:
        payload["data_overlays"] = args.data
    payload.update((bandit_payload if bandit else rollout_payload)(args, datamodules, greedy))
    write_outputs(payload, args.out)
    print(aligned_tables(markdown_tables(payload)), flush=True)
    print(f"wrote {args.out}.json, {args.out}.md, {args.out}.png", flush=True)
    return payload


def run_registered(args: argparse.Namespace, datamodules: dict[str, Any], greedy: bool | None) -> dict[str, Any]:
    """``--evaluation NAME``: the registered evaluation run on every ``--run``, its payload written with its own
    table and figure (``evaluation/base.py``)."""
    import yaml

    from icprl_lightning.evaluation.base import KIND, Run
    from icprl_lightning.io import write_atomic, write_json_atomic
    from icprl_lightning.registry import EVALUATIONS

    options = {}
    for spec in args.option:
        key, sep, value = spec.partition("=")
        if not (key and sep):
            fail(args.parser, f"--option {spec!r} is not KEY=VALUE")
        options[key] = yaml.safe_load(value)
    try:
        kind = EVALUATIONS.get(args.evaluation)
        evaluation = kind(**options)
    except (ValueError, TypeError) as e:
        fail(args.parser, f"--evaluation {args.evaluation}: {e}")
    for dm in datamodules.values():  # a registered evaluation may read any split: the whole dataset
        dm.prepare_data()
    runs = [Run(name, datamodules[name], tuple(checkpoints), greedy)
            for name, (_, checkpoints) in args.runs.items()]
    payload = {KIND: kind.name, "title": args.title, "seeds": args.seeds, "options": options,
               **evaluation.run(runs, list(args.seeds))}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out.with_suffix(".json"), payload)  # never through a link (io.write_atomic)
    write_atomic(out.with_suffix(".md"), kind.markdown(payload))
    kind.figure(payload, out.with_suffix(".png"))
    print(kind.markdown(payload), flush=True)
    print(f"wrote {out}.json, {out}.md" + (f", {out}.png" if out.with_suffix(".png").exists() else ""), flush=True)
    return payload
