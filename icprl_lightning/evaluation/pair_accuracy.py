"""Held-out T-PRL pairs: how often a reward model's summed rewards order an unseen task's trajectory pair as its
label does (RewardGen, R_ψ of the paper's ICRG), each pair conditioned on another pair of its task, per context
quality. Chance is 0.5; tied returns carry coin-flip labels, so the ceiling is below 1. The data serve it as
``held_out("pair_accuracy")`` (T-PRL data); the fit-time numbers come from ``HeldOutPairAccuracyCallback``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import torch

from icprl_lightning.evaluation.base import HeldOutEvaluation, Run
from icprl_lightning.metrics import mean_sem


class PairAccuracy(HeldOutEvaluation):
    """See the module docstring: per run and quality, the accuracy's mean ± sem over the run's checkpoints
    (training seeds) and each seed's value. Pairs are scored once; ``seeds`` play no part (nothing is sampled)."""

    name: ClassVar[str] = "pair_accuracy"

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        from icprl_lightning.evaluation.reward_quality import load_reward_gen

        results: dict[str, dict[str, Any]] = {}
        for run in runs:
            per_seed: dict[str, list[float]] = {}
            for checkpoint in run.checkpoints:
                model = load_reward_gen(checkpoint)
                with torch.no_grad():
                    for quality, batch in run.data.held_out("pair_accuracy").items():
                        per_seed.setdefault(quality, []).append(float(model.pair_correct(batch).float().mean()))
            results[run.name] = {q: dict(zip(("accuracy", "accuracy_sem"), mean_sem(v), strict=True), per_seed=v)
                                 for q, v in per_seed.items()}
        return {"runs": [r.spec for r in runs], "results": results}

    @staticmethod
    def during_fit(module: Any, data: Any, **_: Any) -> tuple[dict[str, float], dict[str, float]]:
        """Whether the module being trained orders each held-out pair as its label (scored on the CPU): what
        ``HeldOutCallback`` logs, ``val/<env>/<quality>/pair_accuracy`` and ``val/<env>/heldout_pair_accuracy``
        (all qualities), and as results also the pairs per quality (``val/<env>/<quality>/pairs``)."""
        from lightning.fabric.utilities.apply_func import move_data_to_device

        correct = {}
        for quality, batch in data.held_out("pair_accuracy").items():
            batch = move_data_to_device(batch, module.device)  # typed samples, moved field by field
            correct[quality] = module.pair_correct(batch).float().cpu()
        env = data.metric_env
        logged = {f"val/{env}/{q}/pair_accuracy": float(c.mean()) for q, c in correct.items()}
        logged[f"val/{env}/heldout_pair_accuracy"] = float(torch.cat(list(correct.values())).mean())
        return {**logged, **{f"val/{env}/{q}/pairs": len(c) for q, c in correct.items()}}, logged

    @staticmethod
    def show_fit(results: dict[str, Any], when: str) -> None:
        import sys

        qualities = [key.split("/")[2] for key in results if key.endswith("/pairs")]
        env = next(iter(results)).split("/")[1]
        shown = ", ".join(f"{q} {results[f'val/{env}/{q}/pair_accuracy']:.3f} (n={results[f'val/{env}/{q}/pairs']})"
                          for q in qualities)
        every = results[f"val/{env}/heldout_pair_accuracy"]
        print(f"Held-out pair accuracy{f' ({when[2:]})' if when else ''}: {shown}; all {every:.3f}", file=sys.stderr)

    @staticmethod
    def markdown(payload: dict[str, Any]) -> str:
        qualities = list(next(iter(payload["results"].values())))
        lines = ["Held-out pair accuracy (chance 0.5), mean ± sem over training seeds:", "",
                 "| run | " + " | ".join(qualities) + " |", "|---|" + "---|" * len(qualities)]
        for name, rows in payload["results"].items():
            lines.append(f"| {name} | " + " | ".join(f"{rows[q]['accuracy']:.3f} ± {rows[q]['accuracy_sem'] or 0:.3f}"
                                                       for q in qualities) + " |")
        return "\n".join(lines) + "\n"

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        return None
