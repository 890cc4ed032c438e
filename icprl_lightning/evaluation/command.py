"""``icprl evaluate``: deploy trained checkpoints on held-out tasks and write the results table and figure.

    icprl evaluate --title "DarkRoom I-PRL" --seeds 0 1 \
        --run DPT=configs/dpt_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run ICPO=configs/icpo_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --baseline "DQN from scratch=docs/results/dqn_from_scratch_darkroom.json" \
        --out docs/results/darkroom_ipref
    icprl evaluate --title "Linear dueling bandits" --seeds 0 \
        --run ICPO=configs/icpo_bandit.yaml:runs/icprl/<id>/checkpoints/last.ckpt --out docs/results/bandit

Each ``--run`` is NAME=CONFIG:CHECKPOINT. The config's data section names the dataset (generated if
missing) whose held-out contexts the checkpoint is deployed on, through ``load_agent`` exactly as a user
would. The metric is the paper's: for MDP families (DarkRoom, Meta-World Reach; I-PRL and T-PRL) the
latent return of an episode on a held-out task (and success rate where the environment reports it), mean
± sem over held-out tasks per context quality (low / medium / high); for dueling bandits the weak regret
min(R* − R(a), R* − R(a')) of the duel played after each context size h = 1..H (paper, appendix "Dueling
Bandit Experiments"), at h = H and averaged over h, mean ± sem over held-out problems per context source.
Every seed is one more episode per context (new start state, new action samples) or, for bandits, new
draws of the method's second arm and of DTS.

Reference rows come from one run's dataset (``--reference NAME``, default: the first ``--run``; the
outputs name it): the behavior policy of each context quality and the optimal (DarkRoom) or expert
(Reach) policy; for bandits Double Thompson Sampling on the same comparisons and the contexts' behaviour
policy. ``--baseline NAME=JSON`` adds a from-scratch learner's result (``baselines/``; it does not
depend on the context, so the same value is shown for every quality). ``--other-task-contexts`` gives
each episode a context of another held-out task (same quality): the drop in return against the normal
run measures how much a policy uses its context. Writes ``<out>.json`` (all numbers), ``<out>.md`` (the
tables) and ``<out>.png``, and prints the JSON (without the bandits' per-h curves).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.duels import BASELINES, curve_mean_sem, seed_mean_curves, summarize_regret
from icprl_lightning.evaluation.report import baseline_row, reference_rows, write_outputs
from icprl_lightning.evaluation.rollout import episode_stats, other_task_contexts, rollout_seeds

RESERVED = {"behavior", "optimal", "expert", *BASELINES}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="icprl evaluate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="NAME=CONFIG:CHECKPOINT")
    parser.add_argument("--baseline", action="append", default=[], help="NAME=JSON of a from-scratch baseline")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    actions = parser.add_mutually_exclusive_group()
    actions.add_argument("--sample", action="store_true", help="sample a ~ T(a|s,D) for every method")
    actions.add_argument("--greedy", action="store_true", help="argmax / Gaussian mean for every method")
    parser.add_argument("--reference", help="NAME of the --run whose dataset gives the reference rows "
                        "(behavior and optimal/expert; bandits: DTS and behaviour; default: the first)")
    parser.add_argument("--other-task-contexts", action="store_true",
                        help="give each episode a context of another held-out task (does the policy use it?)")
    parser.add_argument("--title", default="held-out tasks", help="figure title")
    parser.add_argument("--out", required=True, help="output path without extension")
    args = parser.parse_args(argv)
    args.runs = {}
    for spec in args.run:
        name, _, rest = spec.partition("=")
        config, _, checkpoint = rest.partition(":")
        if not (name and config and checkpoint):
            parser.error(f"--run {spec!r} is not NAME=CONFIG:CHECKPOINT")
        if name in RESERVED or name in args.runs:
            parser.error(f"--run name {name!r} is taken (reference rows: {', '.join(sorted(RESERVED))}; "
                         "names must be unique)")
        args.runs[name] = (config, checkpoint)
    args.reference = args.reference or next(iter(args.runs))
    if args.reference not in args.runs:
        parser.error(f"--reference {args.reference!r} names no --run (runs: {', '.join(args.runs)})")
    args.parser = parser
    return args


def evaluate_rollouts(dm, checkpoint: str, seeds: list[int], greedy: bool | None,
                      other_task: bool = False) -> dict[str, dict[str, Any]]:
    """Per quality: mean and sem over held-out tasks of return, normalized return and success (if reported).

    Each row also holds the suite's ``reference`` (behavior, optimal/expert) for ``reference_rows``.
    """
    out: dict[str, dict[str, Any]] = {}
    for suite in dm.evaluation_suites():
        if other_task:
            suite = other_task_contexts(suite)
        episodes = rollout_seeds(lambda seed: load_agent(checkpoint, greedy=greedy, seed=seed), suite, seeds)
        out[suite.quality] = {**episode_stats(suite, episodes), "reference": suite.reference}
    return out


def evaluate_bandit(dm, checkpoint: str, name: str, seeds: list[int], greedy: bool | None, baselines: bool
                    ) -> tuple[dict[str, dict[str, dict[str, float]]], dict[str, dict[str, dict[str, list]]]]:
    """Per source, per method (``name``, and DTS and behaviour with ``baselines``): summary and per-h curve."""
    summaries: dict[str, dict[str, dict[str, float]]] = {}
    curves: dict[str, dict[str, dict[str, list]]] = {}
    for suite in dm.bandit_suites():
        per_method = seed_mean_curves(lambda seed: load_agent(checkpoint, greedy=greedy, seed=seed), suite, name,
                                      seeds, baselines=baselines)
        for method, curve in per_method.items():
            summaries.setdefault(method, {})[suite.source] = summarize_regret(curve)
            mean, sem = curve_mean_sem(curve)
            curves.setdefault(method, {})[suite.source] = {"mean": mean.tolist(), "sem": sem.tolist()}
    return summaries, curves


def _is_bandit(dm) -> bool:
    """Bandit DataModules evaluate by weak regret (``bandit_suites``) and offer no rollout suites."""
    return hasattr(dm, "bandit_suites") and not dm.evaluation_suites()


def bandit_payload(args: argparse.Namespace, datamodules: dict, greedy: bool | None) -> dict[str, Any]:
    """Weak-regret summaries and curves of every run, with DTS and behaviour rows from the reference's dataset."""
    results, curves = {}, {}
    for name, (_, checkpoint) in args.runs.items():
        summaries, run_curves = evaluate_bandit(datamodules[name], checkpoint, name, args.seeds, greedy,
                                                baselines=name == args.reference)
        results.update(summaries)  # the run's own row, and the reference run's DTS and behaviour rows
        curves.update(run_curves)
    dm = datamodules[args.reference]
    suite = dm.bandit_suites()[0]
    order = [*args.runs, *BASELINES]
    return {"runs": args.run, "reference_rows_from": args.reference, "dataset": str(dm.path),
            "n_eval_problems": int(suite.expected_rewards.shape[0]), "horizon": int(suite.context.preferred.shape[1]),
            "results": {n: results[n] for n in order}, "curves": {n: curves[n] for n in order}}


def rollout_payload(args: argparse.Namespace, datamodules: dict, greedy: bool | None) -> dict[str, Any]:
    """Per-quality rows of every run, the reference run's behavior and optimal/expert rows, the baselines."""
    results = {name: evaluate_rollouts(datamodules[name], checkpoint, args.seeds, greedy, args.other_task_contexts)
               for name, (_, checkpoint) in args.runs.items()}
    references = reference_rows(results[args.reference])
    for rows in results.values():
        for row in rows.values():
            row.pop("reference")
    results.update(references)
    qualities = list(results[args.reference])
    for spec in args.baseline:
        name, _, path = spec.partition("=")
        results[name] = baseline_row(path, qualities)
    return {"other_task_contexts": args.other_task_contexts, "runs": args.run, "baselines": args.baseline,
            "reference_rows_from": args.reference, "results": results}


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    greedy = False if args.sample else True if args.greedy else None  # None: each method's own default
    datamodules = {}
    for name, (config, _) in args.runs.items():
        datamodules[name] = datamodule_from_config(config)
        datamodules[name].prepare_data()
    kinds = {name: _is_bandit(dm) for name, dm in datamodules.items()}
    if len(set(kinds.values())) > 1:
        args.parser.error("runs mix dueling bandits with MDP families: "
                          + ", ".join(f"{n} ({'bandit' if b else 'MDP'})" for n, b in kinds.items()))
    bandit = kinds[args.reference]
    if bandit and (args.other_task_contexts or args.baseline):
        args.parser.error("--other-task-contexts and --baseline apply to MDP families, not dueling bandits")
    actions_used = "sampled" if args.sample else "greedy" if args.greedy else "each method's default"
    payload: dict[str, Any] = {"title": args.title, "seeds": args.seeds, "actions": actions_used}
    payload.update((bandit_payload if bandit else rollout_payload)(args, datamodules, greedy))
    write_outputs(payload, args.out)
    print(json.dumps({k: v for k, v in payload.items() if k != "curves"}, indent=2))
    return payload
