"""Evaluate trained DarkRoom checkpoints on the held-out goals and write the results table and figure.

    python scripts/evaluate_darkroom.py --setting ipref \
        --run DPT=configs/dpt_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run DP2T=configs/dp2t_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --run ICPO=configs/icpo_darkroom.yaml:runs/icprl/<id>/checkpoints/last.ckpt \
        --seeds 0 1 2 --out docs/results/darkroom_ipref

Each run is NAME=CONFIG:CHECKPOINT; the config's data section gives the dataset whose held-out contexts
(low / medium / high quality) the checkpoint is deployed on through ``load_agent``. Every seed is one
more episode per context (a new start cell and new action samples). Writes ``<out>.json`` (all numbers),
``<out>.md`` (mean ± sem over held-out goals) and ``<out>.png``, and prints the JSON.
"""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import matplotlib
import numpy as np
import yaml

from icprl_lightning import load_agent
from icprl_lightning.evaluation import mean_sem, per_task_mean, rollout_in_context

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

QUALITIES = ("low", "medium", "high")


def datamodule_from_config(path: str):
    data = yaml.safe_load(Path(path).read_text())["data"]
    module, _, name = data["class_path"].rpartition(".")
    return getattr(importlib.import_module(module), name)(**data.get("init_args", {}))


def evaluate(config: str, checkpoint: str, seeds: list[int], greedy: bool) -> dict[str, dict[str, float]]:
    dm = datamodule_from_config(config)
    dm.prepare_data()
    out: dict[str, dict[str, float]] = {}
    for suite in dm.evaluation_suites():
        returns = []
        for seed in seeds:
            agent = load_agent(checkpoint, greedy=greedy, seed=seed)
            returns.append(rollout_in_context(agent, suite, seed=seed)["return"])
        per_task = per_task_mean(np.concatenate(returns), np.tile(suite.task_index, len(seeds)))
        mean, sem = mean_sem(per_task)
        out[suite.quality] = {"return": mean, "return_sem": sem, "normalized_return": mean / suite.reference[
            "optimal_return"], **suite.reference}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="NAME=CONFIG:CHECKPOINT")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--sample", action="store_true", help="sample actions from T(a|s,D) instead of argmax")
    parser.add_argument("--setting", default="ipref", help="label used in the title and file names")
    parser.add_argument("--out", required=True, help="output path without extension")
    args = parser.parse_args()
    results: dict[str, dict] = {}
    for spec in args.run:
        name, _, rest = spec.partition("=")
        config, _, checkpoint = rest.partition(":")
        results[name] = evaluate(config, checkpoint, args.seeds, greedy=not args.sample)
    first = next(iter(results.values()))
    results["behavior"] = {q: {"return": first[q]["behavior_return"], "return_sem": first[q]["behavior_return_sem"]}
                           for q in QUALITIES}
    results["optimal"] = {q: {"return": first[q]["optimal_return"], "return_sem": 0.0} for q in QUALITIES}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"setting": args.setting, "seeds": args.seeds, "greedy": not args.sample, "results": results}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=2))
    lines = ["| method | " + " | ".join(QUALITIES) + " |", "|---|" + "---|" * len(QUALITIES)]
    for name, res in results.items():
        cells = [f"{res[q]['return']:.1f} ± {res[q]['return_sem']:.1f}" for q in QUALITIES]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(7, 3.5))
    width = 0.8 / len(results)
    for i, (name, res) in enumerate(results.items()):
        xs = np.arange(len(QUALITIES)) + i * width
        ax.bar(xs, [res[q]["return"] for q in QUALITIES], width, yerr=[res[q]["return_sem"] for q in QUALITIES],
               label=name, capsize=2)
    ax.set_xticks(np.arange(len(QUALITIES)) + width * (len(results) - 1) / 2, QUALITIES)
    ax.set_xlabel("context quality")
    ax.set_ylabel("return on held-out goals")
    ax.set_title(f"DarkRoom ({args.setting}), mean ± sem over held-out goals")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=120)
    print(json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
