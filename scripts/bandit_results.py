"""Dueling-bandit results: weak regret vs context size of ICPO, DTS and the behaviour policy.

Paper, appendix "Dueling Bandit Experiments" (figure "Performance Comparison for Dueling Bandit
Problems"): on held-out problems, for contexts from uniform, Dirichlet and DTS behaviour policies,
ICPO plays (argmax_a T_θ(a | D_{1:h}), uniform) and DTS plays its own duel after the same h comparisons;
the score is the weak regret reg(a, a') = min(R* − R(a), R* − R(a')) (see ``bandit_evaluation``).

    python scripts/bandit_results.py --ckpt runs/icprl/<run>/checkpoints/last.ckpt [--seed 0]

The DataModule (and so the held-out problems) is rebuilt from the checkpoint's saved hyperparameters
and generated if missing. Prints JSON (final and mean-over-h weak regret ± sem per source and method)
and writes the figure, one panel per source with standard-error bands.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from icprl_lightning.bandit_evaluation import (  # noqa: E402
    METHODS,
    curve_mean_sem,
    evaluate_duels,
    regret_curve,
    summarize_regret,
)
from icprl_lightning.data.bandit_datamodule import DuelingBanditDataModule  # noqa: E402
from icprl_lightning.deploy import load_agent  # noqa: E402

LABELS = {"icpo": "ICPO", "dts": "DTS", "behavior": "behaviour policy"}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ckpt", required=True, help="checkpoint of a model trained on DuelingBanditDataModule")
    parser.add_argument("--seed", type=int, default=0, help="seeds ICPO's second arm and DTS's sampling")
    parser.add_argument("--root-dir", default=None, help="override the DataModule's root_dir (dataset location)")
    parser.add_argument("--figure", default="docs/figures/bandit_weak_regret.png")
    parser.add_argument("--json", default=None, help="also write the JSON here")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    start = time.perf_counter()
    hparams = torch.load(args.ckpt, map_location="cpu", weights_only=False).get("datamodule_hyper_parameters")
    if hparams is None:
        raise SystemExit(f"{args.ckpt} has no datamodule hyperparameters; train with DuelingBanditDataModule")
    # LightningCLI adds bookkeeping entries (``_class_path``, ``_instantiator``) to the saved hyperparameters.
    hparams = {k: v for k, v in hparams.items() if not k.startswith("_")}
    if args.root_dir is not None:
        hparams = {**hparams, "root_dir": args.root_dir, "data_dir": None}
    datamodule = DuelingBanditDataModule(**{**hparams, "progress": False})
    datamodule.prepare_data()
    policy = load_agent(args.ckpt).policy

    results: dict = {"checkpoint": str(args.ckpt), "seed": args.seed, "dataset": str(datamodule.path),
                     "n_eval_problems": datamodule.n_problems["test"], "horizon": datamodule.context_length,
                     "sources": {}}
    suites = datamodule.bandit_suites()
    fig, axes = plt.subplots(1, len(suites), figsize=(4.5 * len(suites), 3.6), sharey=True, squeeze=False)
    for ax, suite in zip(axes[0], suites, strict=True):
        duels = evaluate_duels(policy, suite, seed=args.seed)
        results["sources"][suite.source] = {}
        for method in METHODS:
            curve = regret_curve(suite.expected_rewards, duels[method])
            results["sources"][suite.source][method] = summarize_regret(curve)
            mean, sem = curve_mean_sem(curve)
            h = range(1, len(mean) + 1)
            ax.plot(h, mean, label=LABELS[method])
            ax.fill_between(h, mean - sem, mean + sem, alpha=0.25)
        ax.set_title(f"{suite.source} contexts")
        ax.set_xlabel("context size h")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel(f"weak regret (mean ± sem, {results['n_eval_problems']} problems)")
    axes[0, 0].legend()
    fig.tight_layout()
    Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.figure, dpi=120)
    results["figure"] = args.figure
    results["seconds"] = round(time.perf_counter() - start, 1)
    text = json.dumps(results, indent=2)
    print(text)
    if args.json is not None:
        Path(args.json).write_text(text + "\n")
    return results


if __name__ == "__main__":
    main()
