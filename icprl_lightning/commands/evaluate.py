"""``icprl evaluate``: deploy trained checkpoints on held-out tasks and write the results table and figure.

    icprl evaluate --title "DarkRoom I-PRL" --seeds 0 1 \
        --run DPT=configs/dpt_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run ICPO=configs/icpo_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --baseline "DQN from scratch=docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json"
    icprl evaluate --title "Linear dueling bandits" --seeds 0 \
        --run ICPO=configs/icpo_bandit.yaml:runs/icprl/<id>/checkpoints/last.ckpt --out results/bandit
    icprl evaluate online --config CONFIG --ckpt CHECKPOINT ...   (asked online: icprl evaluate online --help)
    icprl evaluate ad --run NAME=CONFIG:CKPT ... --episodes 20 --out PATH   (AD's learning curve: --help there)
    icprl evaluate --evaluation NAME --run ... [--option KEY=VALUE ...]   (any registered evaluation)

Every kind of held-out evaluation is one registered ``HeldOutEvaluation`` (``evaluation/base.py``): ``rollouts``
(MDP families), ``duels`` (dueling bandits), ``pair_accuracy`` (RewardGen on held-out T-PRL pairs), ``online`` and
``online_duels`` (asked as it acts), ``ad`` (Algorithm Distillation across episodes), and a user's own. Without
``--evaluation`` the data choose: ``duels`` on a dueling bandit, else ``rollouts``, with the options below.

Each ``--run`` is NAME=CONFIG:CHECKPOINT[,CHECKPOINT...]: several checkpoints are *training seeds* of one
method on the same data, and each row is then the mean ± sem over training seeds of each seed's
held-out mean (each seed's numbers under ``per_seed`` in the JSON); with one checkpoint the ± is the sem
over held-out tasks. The config's data section names the dataset (generated if missing) whose held-out
contexts the checkpoints are deployed on, through ``load_agent`` exactly as a user would. The metric is
the paper's: for MDP families (DarkRoom, Meta-World Reach; I-PRL and T-PRL) the latent return of an
episode on a held-out task (and success rate where the environment reports it), per context quality
(low / medium / high); for dueling bandits the weak regret min(R* − R(a), R* − R(a')) of the duel played
after each context size h = 1..H (paper, appendix "Dueling Bandit Experiments"), at h = H and averaged
over h, per context source. Every ``--seeds`` value is one more episode per context (new start state, new
action samples) or, for bandits, new draws of the method's second arm and of DTS.

Reference rows come from one run's dataset (``--reference NAME``, default: the first ``--run``; the
outputs name it): the behavior policy of each context quality and the optimal (DarkRoom) or expert
(Reach) policy; for bandits Double Thompson Sampling on the same comparisons and the contexts' behaviour
policy. ``--baseline NAME=JSON`` adds a from-scratch learner's result (``baselines/``; it does not
depend on the context, so the same value is shown for every quality).

``--contexts`` adds the context diagnostics of ``evaluation.diagnostics`` beside each run's own-context
row: ``flipped_labels`` (every label inverted), ``random_labels`` (fair coins), ``other_task`` (another
held-out task's context), ``shuffled_order`` (the same steps in a random order). The label diagnostics
apply to runs whose contexts have labels (preference methods), ``shuffled_order`` to contexts of steps
(I-PRL, DPT's reward contexts, bandit duels); ``other_task`` to every run. Writes ``<out>.json`` (all
numbers; the diagnostics under ``diagnostics``), ``<out>.md`` (the tables) and ``<out>.png``, and prints the
tables (columns aligned) to stdout. ``--out`` defaults to ``<run dir>/eval/<date-time>`` beside the first
checkpoint (its run directory: the parent of ``checkpoints/``), so a quick evaluation never writes into the
repository's ``docs/``.

Everything a user passes is checked before any dataset is generated or any episode run, each problem one
line naming the option: the ``--run`` and ``--baseline`` syntax, every ``--baseline`` file (JSON of a
``baselines/`` result), every config's data section, and every checkpoint (read as untrusted,
``checkpoints.py``) against its config's data: a policy (not a RewardGen reward model) trained on that
data's context kind, state size, action space and context length, so a bandit checkpoint with an MDP config
(or the reverse) is refused up front.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS
from icprl_lightning.evaluation.duels import BASELINES
from icprl_lightning.evaluation.pairing import is_bandit_data, run_datamodule
from icprl_lightning.evaluation.report import aligned_tables, read_baseline

RESERVED = {"behavior", "optimal", "expert", *BASELINES}


def default_out(checkpoint: str) -> Path:
    """``<run dir>/eval/<date-time>``: the run directory holds ``checkpoints/`` (Lightning's layout), else it is
    the checkpoint's own directory; a model directory or a shipped model's name (never written into) gives
    ``runs/eval/<its name>/<date-time>``. A name already taken gets ``-2``, ``-3``, ..."""
    path = Path(checkpoint)
    if path.suffix != ".ckpt":
        run_dir = Path("runs") / "eval" / path.name
    else:
        run_dir = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    out = base = run_dir / "eval" / time.strftime("%Y%m%d-%H%M%S")
    k = 1
    while out.with_suffix(".json").exists():
        k += 1
        out = base.with_name(f"{base.name}-{k}")
    return out


def fail(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """Exit 2 with one line on stderr: a file or a pairing is wrong, not the command's syntax (no usage text)."""
    parser.exit(2, f"{parser.prog}: error: {message}\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="icprl evaluate", description=__doc__,
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
    for spec in args.baseline:
        name, _, path = spec.partition("=")
        if not (name and path):
            parser.error(f"--baseline {spec!r} is not NAME=JSON")
        if name in RESERVED or name in args.runs or name in args.baselines:
            parser.error(f"--baseline name {name!r} is taken (a --run, another --baseline or a reference row)")
        try:  # read now: a bad file fails here, not after the datasets are built
            read_baseline(path)
        except ValueError as e:
            fail(parser, str(e))
        args.baselines[name] = path
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
    return run_evaluation(args, datamodules, greedy, builtin_options(args, datamodules))


def builtin_options(args: argparse.Namespace, datamodules: dict[str, Any]) -> dict[str, Any]:
    """Without ``--evaluation``: the data's own kind (``duels`` on a dueling bandit, else ``rollouts``) and its
    options from the flags, every pairing checked."""
    if args.evaluation:
        return {}
    kinds = {name: is_bandit_data(dm) for name, dm in datamodules.items()}
    if len(set(kinds.values())) > 1:
        fail(args.parser, "runs mix dueling bandits with MDP families: "
                          + ", ".join(f"{n} ({'bandit' if b else 'MDP'})" for n, b in kinds.items()))
    bandit = kinds[args.reference]
    if bandit and args.baseline:
        fail(args.parser, "--baseline applies to MDP families, not dueling bandits")
    for name, dm in datamodules.items():
        if not bandit and "rollouts" not in dm.offers:
            fail(args.parser, f"--run {name}: the data of {args.runs[name][0]} has no held-out rollouts to "
                              "evaluate on (recorded data has no simulator); use a task family's config")
    args.evaluation = "duels" if bandit else "rollouts"
    options = {"contexts": ["own", *args.diagnostics], "reference": args.reference}
    options["baselines"] = not args.no_baselines if bandit else args.baselines
    return options


def run_evaluation(args: argparse.Namespace, datamodules: dict[str, Any], greedy: bool | None,
                   options: dict[str, Any]) -> dict[str, Any]:
    """The registered evaluation run on every ``--run``, its payload written with its own table and figure
    (``evaluation/base.py``): ``<out>.json`` (never through a link), ``<out>.md``, ``<out>.png``."""
    import yaml

    from icprl_lightning.evaluation.base import KIND, Run
    from icprl_lightning.registry import EVALUATIONS

    explicit = not options
    for spec in args.option:
        key, sep, value = spec.partition("=")
        if not (key and sep):
            fail(args.parser, f"--option {spec!r} is not KEY=VALUE")
        options[key] = yaml.safe_load(value)
    try:
        kind = EVALUATIONS.get(args.evaluation)
        evaluation = kind(**options)
    except (ValueError, TypeError) as e:
        fail(args.parser, f"--evaluation {args.evaluation}: {e}" if explicit else str(e))
    for dm in datamodules.values():  # only the held-out splits where the kind reads nothing else and they can be
        (getattr(dm, "prepare_heldout", dm.prepare_data) if kind.held_out_only else dm.prepare_data)()
    runs = [Run(name, datamodules[name], tuple(checkpoints), greedy, config)
            for name, (config, checkpoints) in args.runs.items()]
    actions = "sampled" if args.sample else "greedy" if args.greedy else "each method's default"
    payload = {KIND: kind.name, "title": args.title, "seeds": args.seeds, "actions": actions,
               **({"data_overlays": args.data} if args.data else {}), "options": options,
               **evaluation.run(runs, list(args.seeds))}
    written = kind.write(payload, args.out)
    print(aligned_tables(kind.markdown(payload)), flush=True)
    print(f"wrote {', '.join(map(str, written))}", flush=True)
    return payload
