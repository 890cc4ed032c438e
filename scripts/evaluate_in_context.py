"""Deploy trained checkpoints on a task family's held-out tasks and write the results table and figure.

    python scripts/evaluate_in_context.py --title "DarkRoom I-PRL" --seeds 0 1 \
        --run DPT=configs/dpt_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run ICPO=configs/icpo_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --baseline "DQN from scratch=docs/results/dqn_from_scratch_darkroom.json" \
        --out docs/results/darkroom_ipref

Each ``--run`` is NAME=CONFIG:CHECKPOINT. The config's data section names the dataset whose held-out
contexts (low / medium / high quality) the checkpoint is deployed on, through ``load_agent`` exactly as a
user would. Every seed is one more episode per context (new start state, new action samples). Works
for any DataModule with ``evaluation_suites()`` (DarkRoom, Meta-World Reach; I-PRL and T-PRL).

``--other-task-contexts`` gives each episode a context of another held-out task (same quality): the
drop in return against the normal run measures how much a policy uses its context.

Rows added from a dataset's manifest: the behavior policy that produced each context quality and the
optimal (DarkRoom) or expert (Reach) policy. Runs on different datasets (DPT's reward contexts, the
I-PRL data) have their own calibrated behavior policies; ``--reference NAME`` picks whose dataset the
rows come from (default: the first ``--run``), and the outputs name it. ``--baseline NAME=JSON`` adds
a from-scratch learner's result (``baselines/``; it does not depend on the context, so the same value
is shown for every quality). Writes ``<out>.json`` (all numbers), ``<out>.md`` (mean ± sem over
held-out tasks of return, and of success rate when the environment reports it) and ``<out>.png``, and
prints the JSON.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import matplotlib
import numpy as np
import torch

from icprl_lightning import load_agent
from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.evaluation import datamodule_from_config, rollout_in_context
from icprl_lightning.metrics import mean_sem, per_task_mean

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

QUALITIES = ("low", "medium", "high")
METRICS = ("return", "normalized_return", "success")


def other_task_contexts(suite: EvalSuite) -> EvalSuite:
    """The suite with each episode given a context of the *next* held-out task (same quality).

    Rows are task-major with the same number of episodes per task, so rolling every context field by that
    number moves each task's contexts to the following task. A policy that uses its context should lose
    return; one that ignores it should not.
    """
    per_task = int(np.bincount(suite.task_index).max())
    if np.any(np.roll(suite.task_index, per_task) == suite.task_index):
        raise ValueError("other-task contexts need task-major rows with the same count per task")
    return replace(suite, context=suite.context.map(lambda x: torch.roll(x, per_task, dims=0)))


def evaluate(config: str, checkpoint: str, seeds: list[int], greedy: bool | None,
             other_task: bool = False) -> dict[str, dict[str, float]]:
    """Per quality: mean and sem over held-out tasks of return, normalized return and success (if reported)."""
    dm = datamodule_from_config(config)
    dm.prepare_data()
    out: dict[str, dict[str, float]] = {}
    for suite in dm.evaluation_suites():
        if other_task:
            suite = other_task_contexts(suite)
        episodes: dict[str, list[np.ndarray]] = {}
        for seed in seeds:
            agent = load_agent(checkpoint, greedy=greedy, seed=seed)
            result = rollout_in_context(agent, suite, seed=seed)
            if suite.normalize is not None:
                result["normalized_return"] = suite.normalize(result["return"])
            for name, values in result.items():
                episodes.setdefault(name, []).append(values)
        tasks = np.tile(suite.task_index, len(seeds))
        row: dict[str, float] = {}
        for name, values in episodes.items():
            row[name], row[f"{name}_sem"] = mean_sem(per_task_mean(np.concatenate(values), tasks))
        out[suite.quality] = {**row, "reference": suite.reference}
    return out


def reference_rows(first: dict[str, dict]) -> dict[str, dict[str, dict[str, float]]]:
    """The behavior and optimal/expert policies' numbers from the dataset manifest, per quality."""
    behavior, best = {}, {}
    for q in QUALITIES:
        ref = first[q]["reference"]
        behavior[q] = {"return": ref["behavior_return"], "return_sem": ref.get("behavior_return_sem", 0.0)}
        if "behavior_success" in ref:
            behavior[q]["success"] = ref["behavior_success"]
        if "behavior_normalized_return" in ref:
            behavior[q]["normalized_return"] = ref["behavior_normalized_return"]
        if "optimal_return" in ref:
            best[q] = {"return": ref["optimal_return"], "return_sem": 0.0, "normalized_return": 1.0}
            behavior[q]["normalized_return"] = ref["behavior_return"] / ref["optimal_return"]
        else:
            best[q] = {"return": ref["expert_return"], "return_sem": 0.0, "normalized_return": 1.0,
                       "success": ref["expert_success"]}
    return {"behavior": behavior, "optimal" if "optimal_return" in first["low"]["reference"] else "expert": best}


def baseline_row(path: str) -> dict[str, dict[str, float]]:
    """A from-scratch baseline's JSON (``baselines/``) as the same row for every quality."""
    result = json.loads(Path(path).read_text())
    row = {}
    for metric in METRICS:
        if metric in result:
            row[metric], row[f"{metric}_sem"] = result[metric]["mean"], result[metric]["sem"]
    return {q: dict(row) for q in QUALITIES}


def cell(res: dict[str, float], metric: str, digits: int) -> str:
    if metric not in res:
        return "–"
    sem = res.get(f"{metric}_sem")
    return f"{res[metric]:.{digits}f}" + (f" ± {sem:.{digits}f}" if sem else "")


def write_outputs(payload: dict, out: Path) -> None:
    results = payload["results"]
    deployed = [results[spec.partition("=")[0]] for spec in payload["runs"]]
    metrics = [m for m in METRICS if any(m in res[q] for res in deployed for q in QUALITIES)]
    lines = []
    for metric in metrics:
        digits = 1 if metric == "return" else 2
        lines += [f"{metric.replace('_', ' ')}:", "", "| method | " + " | ".join(QUALITIES) + " |",
                  "|---|" + "---|" * len(QUALITIES)]
        lines += [f"| {name} | " + " | ".join(cell(res[q], metric, digits) for q in QUALITIES) + " |"
                  for name, res in results.items()]
        lines.append("")
    lines.append(f"Behavior and {'optimal' if 'optimal' in results else 'expert'} rows: the dataset of "
                 f"{payload['reference_rows_from']}. Seeds {payload['seeds']}, actions: {payload['actions']}."
                 + (" Contexts from another held-out task." if payload["other_task_contexts"] else ""))
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    shown = [m for m in ("return", "success") if m in metrics]
    fig, axes = plt.subplots(1, len(shown), figsize=(5.5 * len(shown) + 2.5, 3.6), squeeze=False)
    width = 0.8 / len(results)
    for ax, metric in zip(axes[0], shown, strict=True):
        for i, (name, res) in enumerate(results.items()):
            xs = np.arange(len(QUALITIES)) + i * width
            ax.bar(xs, [res[q].get(metric, np.nan) for q in QUALITIES], width,
                   yerr=[res[q].get(f"{metric}_sem", 0.0) or 0.0 for q in QUALITIES], label=name, capsize=2)
        ax.set_xticks(np.arange(len(QUALITIES)) + width * (len(results) - 1) / 2, QUALITIES)
        ax.set_xlabel("context quality")
        ax.set_ylabel(f"{metric.replace('_', ' ')} on held-out tasks")
    axes[0][0].set_title(f"{payload['title']}: mean ± sem over held-out tasks", fontsize=9)
    axes[0][-1].legend(fontsize=7, bbox_to_anchor=(1.02, 1), loc="upper left")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="NAME=CONFIG:CHECKPOINT")
    parser.add_argument("--baseline", action="append", default=[], help="NAME=JSON of a from-scratch baseline")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    actions = parser.add_mutually_exclusive_group()
    actions.add_argument("--sample", action="store_true", help="sample a ~ T(a|s,D) for every method")
    actions.add_argument("--greedy", action="store_true", help="argmax / Gaussian mean for every method")
    parser.add_argument("--reference", help="NAME of the --run whose dataset gives the behavior and "
                        "optimal/expert rows (default: the first)")
    parser.add_argument("--other-task-contexts", action="store_true",
                        help="give each episode a context of another held-out task (does the policy use it?)")
    parser.add_argument("--title", default="held-out tasks", help="figure title")
    parser.add_argument("--out", required=True, help="output path without extension")
    args = parser.parse_args()
    greedy = False if args.sample else True if args.greedy else None  # None: each method's own default
    results: dict[str, dict] = {}
    for spec in args.run:
        name, _, rest = spec.partition("=")
        config, _, checkpoint = rest.partition(":")
        results[name] = evaluate(config, checkpoint, args.seeds, greedy, args.other_task_contexts)
    reference = args.reference or next(iter(results))
    if reference not in results:
        parser.error(f"--reference {reference!r} names no --run (runs: {', '.join(results)})")
    references = reference_rows(results[reference])
    for name in results:
        for q in QUALITIES:
            results[name][q].pop("reference")
    results.update(references)
    for spec in args.baseline:
        name, _, path = spec.partition("=")
        results[name] = baseline_row(path)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    actions_used = "sampled" if args.sample else "greedy" if args.greedy else "each method's default"
    payload = {"title": args.title, "seeds": args.seeds, "actions": actions_used,
               "other_task_contexts": args.other_task_contexts, "runs": args.run, "baselines": args.baseline,
               "reference_rows_from": reference, "results": results}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=2))
    write_outputs(payload, out)
    print(json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
