"""The held-out duels of a dueling bandit: the weak regret min(R* − R(a), R* − R(a')) and the strong regret of the
duel played after each context size h = 1..H, at h = H and averaged over h, per context source (paper, appendix
"Dueling Bandit Experiments"), beside Double Thompson Sampling on the same comparisons, the feature-aware
baselines, the Bayes reference and the contexts' behaviour (``duels.BASELINES``). ``icprl evaluate`` on dueling-
bandit data runs it; the data serve it as ``held_out("duels")``. Every episode seed draws the method's second arm
and DTS anew; several checkpoints of a run are training seeds (``base.over_training_seeds``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from icprl_lightning.evaluation.base import HeldOutEvaluation, Run, over_training_seeds
from icprl_lightning.evaluation.diagnostics import checked_contexts, diagnose_suite
from icprl_lightning.evaluation.duels import (
    BASELINES,
    curve_mean_sem,
    evaluate_duels,
    regret_curve,
    seed_mean_curves,
    summarize_regret,
    summarize_regrets,
)
from icprl_lightning.evaluation.report import regret_markdown, regret_table, show_table, write_figures


def evaluate_run(run: Run, seeds: list[int], baselines: bool, diagnostic: str = "own"
                 ) -> tuple[dict[str, dict[str, dict[str, Any]]], dict[str, dict[str, dict[str, Any]]]]:
    """Per source, per method (the run and, with ``baselines``, ``duels.BASELINES``; the feature-aware ones and
    the Bayes reference when the data's family is a linear dueling bandit): the regret summary
    (``duels.summarize_regrets``) and, per regret, the per-h curve (the mean of the training seeds' curves).
    Returns ``(summaries[method][source], curves[regret][method][source])``."""
    from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily

    family = run.data.family if isinstance(getattr(run.data, "family", None), LinearDuelingBanditFamily) else None
    summaries: dict[str, dict[str, dict[str, Any]]] = {}
    curves: dict[str, dict[str, dict[str, Any]]] = {}
    for suite in run.data.held_out("duels"):
        suite = diagnose_suite(suite, diagnostic, seed=0)
        per_checkpoint = [seed_mean_curves(lambda seed, c=c: run.agent(c, seed), suite, run.name, seeds,
                                           baselines=baselines and i == 0, family=family)
                          for i, c in enumerate(run.checkpoints)]
        for method in per_checkpoint[0]:
            played = [p[method] for p in per_checkpoint if method in p]
            summaries.setdefault(method, {})[suite.source] = over_training_seeds(
                [summarize_regrets(c, with_tasks=True) for c in played])
            for regret in played[0]:
                means = [curve_mean_sem(c[regret]) for c in played]
                mean = np.mean([m for m, _ in means], axis=0)
                sem = (means[0][1] if len(played) == 1
                       else np.std([m for m, _ in means], axis=0, ddof=1) / np.sqrt(len(played)))
                curves.setdefault(regret, {}).setdefault(method, {})[suite.source] = {"mean": mean.tolist(),
                                                                                      "sem": sem.tolist()}
    return summaries, curves


class WeakRegret(HeldOutEvaluation):
    """See the module docstring. ``contexts``: ``own`` and the diagnostics; ``baselines``: False keeps only the
    runs' rows (the baselines take minutes on 1,000 problems); ``reference``: the run whose dataset gives the
    baseline rows (default: the first)."""

    name: ClassVar[str] = "duels"
    held_out_only: ClassVar[bool] = True

    def __init__(self, contexts: list[str] = ("own",), baselines: bool = True, reference: str | None = None) -> None:
        self.contexts, self.baselines, self.reference = checked_contexts(contexts), baselines, reference

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        return super().recognizes(payload) or ("reference_rows_from" in payload and "curves" in payload)

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        reference = self.reference or runs[0].name
        results, curves, diagnostics = {}, {}, {}
        for run in runs:
            summaries, run_curves = evaluate_run(run, seeds, baselines=run.name == reference and self.baselines)
            results.update(summaries)  # the run's own row, and the reference run's baseline rows
            for regret, per_method in run_curves.items():
                curves.setdefault(regret, {}).update(per_method)
            for diagnostic in (c for c in self.contexts if c != "own"):
                diagnosed, _ = evaluate_run(run, seeds, baselines=False, diagnostic=diagnostic)
                diagnostics.setdefault(run.name, {})[diagnostic] = diagnosed[run.name]
        data = next(r.data for r in runs if r.name == reference)
        suite = data.held_out("duels")[0]
        order = [*(r.name for r in runs), *(b for b in BASELINES if b in results)]
        return {"runs": [r.spec for r in runs], "reference_rows_from": reference, "dataset": str(data.path),
                "n_eval_problems": int(suite.expected_rewards.shape[0]),
                "horizon": int(suite.context.preferred.shape[1]), "results": {n: results[n] for n in order},
                "curves": {n: curves["weak"][n] for n in order},
                "strong_curves": {n: curves["strong"][n] for n in order}, "diagnostics": diagnostics}

    @staticmethod
    def during_fit(agent: Any, data: Any, seed: int, method: str = "ICPO", chunk_size: int = 32, **_: Any
                   ) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
        """The weak-regret summaries of the module being trained (``agent``, its row named ``method``) and of the
        baselines per context source (``chunk_size`` problems per forward pass bounds memory), keyed
        ``val/bandit/<source>/<method>``, and the values ``HeldOutCallback`` logs from them."""
        results: dict[str, dict[str, float]] = {}
        for suite in data.held_out("duels"):
            duels = evaluate_duels(agent, suite, method, seed, chunk_size)
            results.update({f"val/bandit/{suite.source}/{name}": summarize_regret(regret_curve(suite.expected_rewards,
                                                                                                pair))
                            for name, pair in duels.items()})
        logged = {f"{prefix}/{k}": float(v) for prefix, summary in results.items() for k, v in summary.items()}
        return results, logged

    @staticmethod
    def show_fit(results: dict[str, Any], when: str) -> None:
        by_source: dict[str, dict[str, dict[str, float]]] = {}
        for prefix, summary in results.items():
            _, _, source, name = prefix.split("/", 3)
            by_source.setdefault(source, {})[name] = summary
        show_table(regret_table(by_source, f"Weak regret on held-out bandit problems{when}"))

    markdown = staticmethod(regret_markdown)

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        write_figures(payload, path.with_suffix(""))  # and <stem>_diagnostics.png with diagnostics
