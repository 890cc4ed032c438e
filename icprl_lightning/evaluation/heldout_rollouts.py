"""The held-out rollouts of an MDP family: the latent return (and success where the environment reports it) of an
in-context episode on each held-out task, per context quality, beside the behavior and the optimal/expert policy
(the paper's metric for DarkRoom and Meta-World Reach, I-PRL and T-PRL), with the context diagnostics of
``evaluation.diagnostics`` (flipped or random labels, another task's context, shuffled order) beside each run's
own-context row. ``icprl evaluate`` on an MDP family's data runs it; the data serve it as ``held_out("rollouts")``.

Several checkpoints of a run are training seeds: a row is the mean ± sem over seeds of each seed's held-out mean
(``base.over_training_seeds``), with one checkpoint the sem over held-out tasks. Every episode seed is one more
episode per context (new start state, new action samples).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from icprl_lightning.evaluation.base import HeldOutEvaluation, Run, over_training_seeds
from icprl_lightning.evaluation.diagnostics import applicable, checked_contexts, diagnose_suite
from icprl_lightning.evaluation.report import (
    baseline_row,
    read_baseline,
    reference_rows,
    results_table,
    rollout_markdown,
    show_table,
    write_figures,
)
from icprl_lightning.evaluation.rollout import episode_stats, rollout_in_context, rollout_seeds, suite_env, summarize


def held_out_means(suite, diagnostic: str, run: Run, checkpoint: str, seeds: list[int], env: Any = None
                   ) -> dict[str, float]:
    """One checkpoint's means over held-out tasks on ``suite`` with its context changed as ``diagnostic`` states.

    The random labels of episode seed s are drawn from s, so every checkpoint sees the same contexts. ``env``:
    the suite's env to reuse (``evaluation.rollout.suite_env``), else a fresh one.
    """
    episodes = rollout_seeds(lambda seed: run.agent(checkpoint, seed), suite, seeds,
                             lambda seed: diagnose_suite(suite, diagnostic, seed), env=env)
    return episode_stats(suite, episodes, with_tasks=True)


def evaluate_run(run: Run, seeds: list[int], diagnostics: list[str]) -> tuple[dict[str, dict], dict[str, dict]]:
    """Per quality, the own-context row and per applicable diagnostic the same; the own rows hold the suite's
    ``reference`` for ``report.reference_rows``."""
    own: dict[str, dict[str, Any]] = {}
    diagnosed: dict[str, dict[str, dict[str, Any]]] = {}
    for suite in run.data.held_out("rollouts"):
        with suite_env(suite) as env:  # one env per suite: every checkpoint, context and seed resets it
            for diagnostic in ["own", *applicable(suite.context, diagnostics)]:
                row = over_training_seeds([held_out_means(suite, diagnostic, run, c, seeds, env)
                                           for c in run.checkpoints])
                if diagnostic == "own":
                    own[suite.quality] = {**row, "reference": suite.reference}
                else:
                    diagnosed.setdefault(diagnostic, {})[suite.quality] = row
    return own, diagnosed


class HeldOutRollouts(HeldOutEvaluation):
    """See the module docstring. ``contexts``: ``own`` and the diagnostics; ``baselines``: name -> the JSON of a
    from-scratch learner (``baselines/``), shown for every quality; ``reference``: the run whose dataset gives the
    behavior and optimal/expert rows (default: the first)."""

    name: ClassVar[str] = "rollouts"
    held_out_only: ClassVar[bool] = True

    def __init__(self, contexts: list[str] = ("own",), baselines: dict[str, str] | None = None,
                 reference: str | None = None) -> None:
        self.contexts = checked_contexts(contexts)
        self.baseline_files = dict(baselines or {})
        self.baselines = {name: read_baseline(path) for name, path in self.baseline_files.items()}  # fail now
        self.reference = reference

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        return super().recognizes(payload) or ("reference_rows_from" in payload and "curves" not in payload
                                               and "kind" not in payload and isinstance(payload.get("results"), dict))

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        diagnostics = [d for d in self.contexts if d != "own"]
        reference = self.reference or runs[0].name
        results, diagnosed_rows = {}, {}
        for run in runs:
            results[run.name], diagnosed = evaluate_run(run, seeds, diagnostics)
            if diagnosed:
                diagnosed_rows[run.name] = diagnosed
        references = reference_rows(results[reference])
        for rows in results.values():
            for row in rows.values():
                row.pop("reference")
        results.update(references)
        qualities = list(results[reference])
        for name, result in self.baselines.items():
            results[name] = baseline_row(result, qualities)
        return {"contexts": ["own", *diagnostics], "runs": [r.spec for r in runs],
                "baselines": [f"{n}={p}" for n, p in self.baseline_files.items()], "reference_rows_from": reference,
                "results": results, "diagnostics": diagnosed_rows}

    @staticmethod
    def during_fit(agent: Any, data: Any, seed: int, diagnostics: tuple[str, ...] = (), **_: Any
                   ) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
        """The held-out results of the module being trained (``agent``) per suite and diagnostic, keyed
        ``val/<env>/<quality>[/<diagnostic>]``, and the values ``HeldOutCallback`` logs from them (a diagnostic's
        without the reference rows)."""
        results: dict[str, dict[str, float]] = {}
        logged: dict[str, float] = {}
        for suite in data.held_out("rollouts"):
            with suite_env(suite) as env:  # the own context and every diagnostic reset the same env
                prefix = f"val/{suite.env_name}/{suite.quality}"
                results[prefix] = summarize(suite, rollout_in_context(agent, suite, seed=seed, env=env))
                logged.update({f"{prefix}/{k}": float(v) for k, v in results[prefix].items()})
                for diagnostic in applicable(suite.context, diagnostics):
                    changed = diagnose_suite(suite, diagnostic, seed=seed)
                    result = summarize(changed, rollout_in_context(agent, changed, seed=seed, env=env))
                    results[f"{prefix}/{diagnostic}"] = result
                    logged.update({f"{prefix}/{diagnostic}/{k}": float(v) for k, v in result.items()
                                   if not k.startswith(("behavior", "optimal", "expert"))})
        return results, logged

    @staticmethod
    def show_fit(results: dict[str, Any], when: str) -> None:
        show_table(results_table(results, f"In-context rollouts on held-out tasks{when}"))

    markdown = staticmethod(rollout_markdown)

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        write_figures(payload, path.with_suffix(""))  # and <stem>_diagnostics.png with diagnostics
