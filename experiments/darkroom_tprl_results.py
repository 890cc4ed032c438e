"""Question: On DarkRoom T-PRL (60 pairs per training goal), how do DP²T, ICRG and DIT on true rewards compare with the
behavior policy, sampled and greedy, and how good are RewardGen's rewards?

Asked: 2026-11-22 (the first commit of this investigation, then scripts/darkroom_tprl_results.py).

Answer (docs/RESULTS.md, DarkRoom T-PRL ("What we measure, against the paper's claims")):
ICRG does not improve on the behavior policy (sampled: 18.2 / 35.2 / 64.6 against 17.5 / 37.9 / 75.3)
and beats DP²T only at high quality (DP²T 28.6 / 46.2 / 49.0); DIT on true rewards improves on the behavior at
low and medium (27.9 / 48.8 / 74.1), so the reward estimate is the gap: RewardGen orders held-out pairs well
(0.80) but its per-step labels correlate only 0.18 / 0.31 / 0.41 with the latent reward. Greedy actions hurt
both DIT policies at low and medium quality. The table is now `icprl reproduce darkroom_tprl`'s; the reward
measures are `icprl analyze reward-quality` and `icrg-labels`.

A one-off investigation, kept as it was run: not part of the package, untested, imported by nothing.

DarkRoom T-PRL results: deploy trained checkpoints on the held-out goals, write a JSON, a table and a figure.

    python experiments/darkroom_tprl_results.py --dp2t runs/dp2t_darkroom_tprl/checkpoints/last.ckpt \
        --icrg runs/icrg_darkroom/checkpoints/last.ckpt --dit runs/dit_darkroom/checkpoints/last.ckpt \
        --reward-gen runs/reward_gen_darkroom/checkpoints/best.ckpt --data-config configs/icrg_darkroom.yaml

Every method goes through the public API (``load_agent`` -> ``reset(context)`` -> ``act``) on the same held-out
goals and the same trajectories: DP²T and ICRG get the T-PRL context (ICRG with its unlabeled behavior
trajectory), DIT on true rewards gets that behavior trajectory with its latent rewards. Actions are
sampled (the paper's deployment) and, as a second protocol, greedy (the rollout callback's default); each
context is rolled out once per evaluation seed. Returns are
averaged per goal, then reported as mean ± sem over the held-out goals, beside the behavior policy's and
the optimal policy's returns. RewardGen's held-out pair accuracy is measured on the same goals' pairs, and
the correlation of ICRG's labels r̂ with the latent per-step rewards on the behavior trajectories it labels.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib
import numpy as np
import torch

from icprl_lightning import load_agent
from icprl_lightning.checkpoints import load_module
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.evaluation import rollout_in_context
from icprl_lightning.evaluation.trajectory_data import tprl_datamodule
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.metrics import mean_sem, per_task_mean

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

METHODS = {"dp2t": ("DP2T (T-PRL)", "trajectory_preference"), "icrg": ("ICRG", "trajectory_preference"),
           "dit": ("DIT, true rewards (oracle)", "reward_trajectory")}


def datamodule(config: Path, kind: str, root_dir: str | None) -> PreferenceDataModule:
    """The config's T-PRL data as ``kind``, prepared: the same trajectories with labels, or with their true rewards."""
    dm = tprl_datamodule(config, kind, root_dir)
    dm.prepare_data()
    return dm


def evaluate(checkpoint: Path, dm: PreferenceDataModule, seeds: list[int], greedy: bool
             ) -> dict[str, dict[str, float]]:
    agent = load_agent(checkpoint, greedy=greedy, seed=seeds[0])
    out = {}
    for suite in dm.held_out("rollouts"):
        returns = np.mean([rollout_in_context(agent, suite, seed=s)["return"] for s in seeds], axis=0)
        mean, sem = mean_sem(per_task_mean(returns, suite.task_index))
        out[suite.quality] = {"return": mean, "return_sem": sem,
                              "normalized_return": mean / suite.reference["optimal_return"]}
    return out


@torch.no_grad()
def pair_accuracy(checkpoint: Path, dm: PreferenceDataModule) -> dict[str, float]:
    model = load_module(checkpoint)  # weights_only, allow-listed class, checksum verified
    if not isinstance(model, RewardGenModule):
        raise ValueError(f"{checkpoint} is a {type(model).__name__} checkpoint, not RewardGen's")
    model.eval()
    correct = {q: model.pair_correct(batch).float() for q, batch in dm.held_out("pair_accuracy").items()}
    return {**{q: float(c.mean()) for q, c in correct.items()}, "all": float(torch.cat(list(correct.values())).mean())}


@torch.no_grad()
def label_correlation(checkpoint: Path, dms: dict[str, PreferenceDataModule]) -> dict[str, float]:
    """Pearson correlation of ICRG's deployment labels r̂ with the latent per-step rewards, per quality."""
    agent = load_agent(checkpoint)
    out = {}
    for suite, oracle in zip(*(dms[k].held_out("rollouts") for k in ("trajectory_preference", "reward_trajectory")),
                             strict=True):
        agent.reset(suite.context)
        out[suite.quality] = float(np.corrcoef(agent.labeled_context.rewards.flatten().numpy(),
                                               oracle.context.rewards.flatten().numpy())[0, 1])
    return out


def figure(results: dict[str, dict], reference: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4), sharey=True, squeeze=False)
    for ax, (protocol, by_method) in zip(axes[0], results.items(), strict=True):
        bars = [("behavior", "behavior", "0.6")] + [(m, METHODS[m][0], c) for m, c in
                                                     (("dp2t", "tab:blue"), ("icrg", "tab:red"), ("dit", "tab:green"))
                                                     if m in by_method] + [("optimal", "optimal", "0.2")]
        x, width = np.arange(len(QUALITIES)), 0.8 / len(bars)
        for i, (key, label, color) in enumerate(bars):
            if key in ("behavior", "optimal"):
                mean = [reference[q][f"{key}_return"] for q in QUALITIES]
                sem = [reference[q]["behavior_return_sem"] if key == "behavior" else 0.0 for q in QUALITIES]
            else:
                mean = [by_method[key][q]["return"] for q in QUALITIES]
                sem = [by_method[key][q]["return_sem"] for q in QUALITIES]
            ax.bar(x + (i - (len(bars) - 1) / 2) * width, mean, width, yerr=sem, label=label, color=color, capsize=2)
        ax.set_xticks(x, [f"{q} quality" for q in QUALITIES])
        ax.set_title(f"{protocol} actions")
    axes[0][0].set_ylabel("return on held-out goals (mean ± sem, 20 goals)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9)
    fig.suptitle("DarkRoom T-PRL: context quality × method")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=120)


def table(by_method: dict, reference: dict) -> str:
    def row(name: str, cells: dict[str, dict[str, float]], key: str) -> str:
        values = " | ".join(f"{cells[q][key]:.1f} ± {cells[q][key + '_sem']:.1f}" for q in QUALITIES)
        return f"| {name} | {values} |"

    rows = ["| method | " + " | ".join(QUALITIES) + " |", "|---|" + "---|" * len(QUALITIES),
            row("behavior", reference, "behavior_return")]
    rows += [row(METHODS[m][0], r, "return") for m, r in by_method.items()]
    rows.append("| optimal | " + " | ".join(f"{reference[q]['optimal_return']:.1f}" for q in QUALITIES) + " |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for m in METHODS:
        parser.add_argument(f"--{m}", type=Path, help=f"{METHODS[m][0]} checkpoint")
    parser.add_argument("--reward-gen", type=Path, help="RewardGen checkpoint (held-out pair accuracy)")
    parser.add_argument("--data-config", type=Path, default=Path("configs/icrg_darkroom.yaml"))
    parser.add_argument("--data-root", help="override the config's data.init_args.root_dir")
    parser.add_argument("--eval-seeds", type=int, nargs="+", default=[0, 1, 2])
    # not docs/results/darkroom_tprl/darkroom_tprl.json: that is the output of `icprl reproduce darkroom_tprl`
    parser.add_argument("--json", type=Path, default=Path("docs/results/darkroom_tprl_60pairs.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/darkroom_tprl.png"))
    args = parser.parse_args()
    torch.manual_seed(0)
    dms = {kind: datamodule(args.data_config, kind, args.data_root)
           for kind in ("trajectory_preference", "reward_trajectory")}
    info = dms["trajectory_preference"].load().manifest["info"]
    results = {protocol: {m: evaluate(getattr(args, m), dms[kind], args.eval_seeds, protocol == "greedy")
                          for m, (_, kind) in METHODS.items() if getattr(args, m) is not None}
               for protocol in ("sampled", "greedy")}
    out = {"returns": results, "reference": info["test_reference"], "eval_label_statistics": info["eval_statistics"],
           "eval_seeds": args.eval_seeds, "checkpoints": {m: str(getattr(args, m)) for m in results["sampled"]}}
    if args.icrg is not None:
        out["icrg_label_correlation"] = label_correlation(args.icrg, dms)
    if args.reward_gen is not None:
        out["reward_gen_heldout_pair_accuracy"] = pair_accuracy(args.reward_gen, dms["trajectory_preference"])
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2))
    figure(results, info["test_reference"], args.figure)
    for protocol, by_method in results.items():
        print(f"\n{protocol} actions\n" + table(by_method, info["test_reference"]))
    if "icrg_label_correlation" in out:
        print("corr(ICRG's r̂, latent reward), held-out:", json.dumps(out["icrg_label_correlation"]))
    if "reward_gen_heldout_pair_accuracy" in out:
        print("RewardGen held-out pair accuracy:", json.dumps(out["reward_gen_heldout_pair_accuracy"]))


if __name__ == "__main__":
    main()
