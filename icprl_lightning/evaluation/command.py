"""``icprl evaluate``: deploy trained checkpoints on held-out tasks and write the results table and figure.

    icprl evaluate --title "DarkRoom I-PRL" --seeds 0 1 \
        --run DPT=configs/dpt_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run ICPO=configs/icpo_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --baseline "DQN from scratch=docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json"
    icprl evaluate --title "Linear dueling bandits" --seeds 0 \
        --run ICPO=configs/icpo_bandit.yaml:runs/icprl/<id>/checkpoints/last.ckpt --out results/bandit
    icprl evaluate online --config CONFIG --ckpt CHECKPOINT ...   (asked online: icprl evaluate online --help)
    icprl evaluate ad --run NAME=CONFIG:CKPT ... --episodes 20 --out PATH   (AD's learning curve: --help there)

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

import time
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.diagnostics import applicable, diagnose_suite
from icprl_lightning.evaluation.duels import BASELINES, curve_mean_sem, seed_mean_curves, summarize_regrets
from icprl_lightning.evaluation.report import (
    baseline_row,
    reference_rows,
)
from icprl_lightning.evaluation.rollout import episode_stats, rollout_seeds, suite_env
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.metrics import mean_sem

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


def over_training_seeds(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """One row from each training seed's held-out means: mean ± sem over seeds, and the seeds' values.

    With a single seed the row is that seed's (its ± is the sem over held-out tasks). A seed row's
    ``per_task`` (metric -> per-task values) becomes the row's ``per_task``: metric -> [seed][task], the
    seeds × tasks matrix that ``reproduce.statistics`` bootstraps.
    """
    tasks = [seed_row.get("per_task") for seed_row in per_seed]
    per_seed = [{k: v for k, v in seed_row.items() if k != "per_task"} for seed_row in per_seed]
    if len(per_seed) == 1:
        row: dict[str, Any] = dict(per_seed[0])
    else:
        row = {"training_seeds": len(per_seed), "per_seed": {}}
        for key in (k for k in per_seed[0] if not k.endswith("_sem")):
            values = [seed_row[key] for seed_row in per_seed]
            row[key], row[f"{key}_sem"] = mean_sem(values)
            row["per_seed"][key] = values
    if all(t is not None for t in tasks):
        row["per_task"] = {metric: [t[metric] for t in tasks] for metric in tasks[0]}
    return row


def held_out_means(suite, diagnostic: str, checkpoint: str, seeds: list[int], greedy: bool | None,
                   env: Any = None) -> dict[str, float]:
    """One checkpoint's means over held-out tasks on ``suite`` with its context changed as ``diagnostic`` states.

    The random labels of episode seed s are drawn from s, so every checkpoint sees the same contexts. ``env``:
    the suite's env to reuse (``evaluation.rollout.suite_env``), else a fresh one.
    """
    episodes = rollout_seeds(lambda seed: load_agent(checkpoint, greedy=greedy, seed=seed), suite, seeds,
                             lambda seed: diagnose_suite(suite, diagnostic, seed), env=env)
    return episode_stats(suite, episodes, with_tasks=True)


def evaluate_rollouts(dm, checkpoints: list[str], seeds: list[int], greedy: bool | None,
                      diagnostics: list[str] = ()) -> tuple[dict[str, dict[str, Any]], dict[str, dict]]:
    """Per quality, the own-context row (mean over held-out tasks, over training seeds as ``over_training_seeds``)
    and per applicable diagnostic the same; the own rows hold the suite's ``reference`` for ``reference_rows``.
    """
    own: dict[str, dict[str, Any]] = {}
    diagnosed: dict[str, dict[str, dict[str, Any]]] = {}
    for suite in dm.evaluation_suites():
        with suite_env(suite) as env:  # one env per suite: every checkpoint, context and seed resets it
            for diagnostic in ["own", *applicable(suite.context, diagnostics)]:
                row = over_training_seeds([held_out_means(suite, diagnostic, c, seeds, greedy, env)
                                           for c in checkpoints])
                if diagnostic == "own":
                    own[suite.quality] = {**row, "reference": suite.reference}
                else:
                    diagnosed.setdefault(diagnostic, {})[suite.quality] = row
    return own, diagnosed


def evaluate_bandit(dm, checkpoints: list[str], name: str, seeds: list[int], greedy: bool | None, baselines: bool,
                    diagnostic: str = "own"
                    ) -> tuple[dict[str, dict[str, dict[str, Any]]], dict[str, dict[str, dict[str, Any]]]]:
    """Per source, per method (``name`` and, with ``baselines``, ``duels.BASELINES``: DTS, the feature-aware
    baselines and the Bayes reference when ``dm.family`` is a ``LinearDuelingBanditFamily``, behaviour): the
    weak- and strong-regret summary (``duels.summarize_regrets``) and, per regret, the per-h curve.

    Several checkpoints (training seeds): each summary is the mean ± sem over seeds of each seed's
    mean over problems (``over_training_seeds``), the curve the mean of the seeds' curves. Returns
    ``(summaries[method][source], curves[regret][method][source])``.
    """
    family = dm.family if isinstance(getattr(dm, "family", None), LinearDuelingBanditFamily) else None
    summaries: dict[str, dict[str, dict[str, Any]]] = {}
    curves: dict[str, dict[str, dict[str, Any]]] = {}
    for suite in dm.bandit_suites():
        suite = diagnose_suite(suite, diagnostic, seed=0)
        per_checkpoint = [seed_mean_curves(lambda seed, c=c: load_agent(c, greedy=greedy, seed=seed), suite, name,
                                           seeds, baselines=baselines and i == 0, family=family)
                          for i, c in enumerate(checkpoints)]
        for method in per_checkpoint[0]:
            runs = [p[method] for p in per_checkpoint if method in p]
            summaries.setdefault(method, {})[suite.source] = over_training_seeds(
                [summarize_regrets(c, with_tasks=True) for c in runs])
            for regret in runs[0]:
                means = [curve_mean_sem(c[regret]) for c in runs]
                mean = np.mean([m for m, _ in means], axis=0)
                sem = (means[0][1] if len(runs) == 1
                       else np.std([m for m, _ in means], axis=0, ddof=1) / np.sqrt(len(runs)))
                curves.setdefault(regret, {}).setdefault(method, {})[suite.source] = {"mean": mean.tolist(),
                                                                                      "sem": sem.tolist()}
    return summaries, curves


def bandit_payload(args: Any, datamodules: dict, greedy: bool | None) -> dict[str, Any]:
    """Weak- and strong-regret summaries and curves of every run, with the ``BASELINES`` rows (DTS, MaxInP,
    BT Thompson sampling, the Bayes reference, behaviour) from the reference's dataset."""
    results, curves, diagnostics = {}, {}, {}
    for name, (_, checkpoints) in args.runs.items():
        summaries, run_curves = evaluate_bandit(datamodules[name], checkpoints, name, args.seeds, greedy,
                                                baselines=name == args.reference and not args.no_baselines)
        results.update(summaries)  # the run's own row, and the reference run's baseline rows
        for regret, per_method in run_curves.items():
            curves.setdefault(regret, {}).update(per_method)
        for diagnostic in args.diagnostics:
            diagnosed, _ = evaluate_bandit(datamodules[name], checkpoints, name, args.seeds, greedy,
                                           baselines=False, diagnostic=diagnostic)
            diagnostics.setdefault(name, {})[diagnostic] = diagnosed[name]
    dm = datamodules[args.reference]
    suite = dm.bandit_suites()[0]
    order = [*args.runs, *(b for b in BASELINES if b in results)]
    return {"runs": args.run, "reference_rows_from": args.reference, "dataset": str(dm.path),
            "n_eval_problems": int(suite.expected_rewards.shape[0]), "horizon": int(suite.context.preferred.shape[1]),
            "results": {n: results[n] for n in order}, "curves": {n: curves["weak"][n] for n in order},
            "strong_curves": {n: curves["strong"][n] for n in order}, "diagnostics": diagnostics}


def rollout_payload(args: Any, datamodules: dict, greedy: bool | None) -> dict[str, Any]:
    """Per-quality rows of every run, the reference run's behavior and optimal/expert rows, the baselines."""
    results, diagnostics = {}, {}
    for name, (_, checkpoints) in args.runs.items():
        results[name], diagnosed = evaluate_rollouts(datamodules[name], checkpoints, args.seeds, greedy,
                                                     args.diagnostics)
        if diagnosed:
            diagnostics[name] = diagnosed
    references = reference_rows(results[args.reference])
    for rows in results.values():
        for row in rows.values():
            row.pop("reference")
    results.update(references)
    qualities = list(results[args.reference])
    for name, result in args.baselines.items():
        results[name] = baseline_row(result, qualities)
    return {"contexts": ["own", *args.diagnostics], "runs": args.run, "baselines": args.baseline,
            "reference_rows_from": args.reference, "results": results, "diagnostics": diagnostics}
