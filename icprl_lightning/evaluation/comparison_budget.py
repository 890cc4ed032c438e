"""How many answered comparisons an I-PRL agent needs on held-out tasks: a study to plan a labelling session by
(``docs/labelling.md``).

For every comparison budget k (``budgets``: by default 0, 10%, ..., 100% of the model's ``max_context``), the
agent's normalized return (``EvalSuite.normalize``; DarkRoom: return / optimal return) with the first k answered
comparisons as its context, from two sources of comparisons:

* **online** (one row per pair rule of ``rules``; ``uniform`` = random queries): the agent gathers them itself,
  asking as it acts on the held-out task (``online_mdp.online_episodes``: ``episodes`` episodes in a row,
  ``max_context / episodes`` queries each), answered by a Bradley–Terry teacher at ``temperature`` (the scripted
  person of the labelling page's tests, in process: ``BradleyTerryAnnotator``);
* **offline**: the dataset's fixed context of the ``quality`` suite on the same tasks.

Either context's first k comparisons are then deployed for one greedy (the checkpoint's default) episode per
context with no further queries (``rollout.rollout_in_context``), on the same tasks and episode seeds, so the
two sources differ only in which comparisons fill the context. k = 0 is the empty context (the model's prior),
the same for both. The label diagnostics (``diagnostics``: ``flipped`` / ``random``) repeat the first rule's
online row with the teacher's answers inverted or replaced by coins, and the offline row with the
``flipped_labels`` / ``random_labels`` contexts (``evaluation.diagnostics``): a row that keeps its return there
does not read the labels.

Each row's value at k is the mean over training seeds × held-out tasks of the per-task mean (episode seeds and
contexts averaged), with a 95% percentile bootstrap interval over those (seed, task) cells; ``reach[t]`` is the
first k at which the mean is at least ``t`` of optimal (None: not within the largest budget).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from icprl_lightning.annotators.bradley_terry import BradleyTerryAnnotator
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.evaluation.base import HeldOutEvaluation, Run
from icprl_lightning.evaluation.diagnostics import diagnose_suite
from icprl_lightning.evaluation.online_mdp import LABELS, online_episodes
from icprl_lightning.evaluation.rollout import rollout_in_context, suite_env
from icprl_lightning.io import save_figure
from icprl_lightning.metrics import per_task_mean
from icprl_lightning.online import PAIR_RULES, OnlineAgent

BOOTSTRAP = 2000


def prefix(context: StepPreferenceContext, k: int) -> StepPreferenceContext:
    """The first ``k`` comparisons of every row of ``context``."""
    return context.map(lambda x: x[:, :k])


class PrefixAgent:
    """An ``OnlineAgent`` deployed on the first ``k`` comparisons of whatever context it is given; k = 0 is the empty
    context, which an offline ``Agent`` refuses (its query would sit at position 0)."""

    def __init__(self, agent: OnlineAgent, k: int) -> None:
        self.agent, self.k = agent, k

    def reset(self, context: StepPreferenceContext) -> None:
        self.agent.reset(prefix(context, self.k) if self.k else context.batch_size)

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        return self.agent.act(obs)


def bootstrap(cells: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """95% percentile interval of the mean of ``cells`` (every (training seed, task) value), resampled together."""
    flat = cells.reshape(-1)
    means = np.random.default_rng(seed).choice(flat, (BOOTSTRAP, flat.size)).mean(axis=1)
    low, high = np.quantile(means, [0.025, 0.975])
    return float(low), float(high)


class ComparisonBudget(HeldOutEvaluation):
    """Return vs answered comparisons, online (per pair rule) against offline (module docstring)."""

    name = "comparison_budget"

    def __init__(self, rules: Sequence[str] = ("action_uniform", "top_two", "uniform"),
                 diagnostics: Sequence[str] = ("flipped", "random"), budgets: Sequence[int] | None = None,
                 episodes: int = 5, quality: str = "medium", targets: Sequence[float] = (0.5, 0.8),
                 temperature: float = 1.0) -> None:
        unknown = sorted(set(rules) - set(PAIR_RULES))
        if not rules or unknown:
            raise ValueError(f"rules: give pair rules of {', '.join(sorted(PAIR_RULES))}, got {list(rules)}")
        wrong = sorted(set(diagnostics) - set(LABELS[1:]))
        if wrong:
            raise ValueError(f"diagnostics must be among {', '.join(LABELS[1:])}, got {wrong}")
        if type(episodes) is not int or episodes < 1:
            raise ValueError(f"episodes must be an integer >= 1, got {episodes!r}")
        if budgets is not None and (not budgets or any(type(k) is not int or k < 0 for k in budgets)):
            raise ValueError(f"budgets must be non-negative integers, got {budgets!r}")
        if not targets or any(not 0 < t <= 1 for t in targets):
            raise ValueError(f"targets must be fractions of the optimal return in (0, 1], got {list(targets)}")
        self.rules, self.diagnostics, self.episodes, self.quality = list(rules), list(diagnostics), episodes, quality
        self.budgets = None if budgets is None else sorted(set(budgets))
        self.targets = [float(t) for t in targets]
        self.annotator = BradleyTerryAnnotator(temperature)

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        results = {run.name: self.run_one(run, seeds) for run in runs}
        return {"quality": self.quality, "episodes": self.episodes, "targets": self.targets,
                "annotator": self.annotator.config(), "results": results}

    def run_one(self, run: Run, seeds: list[int]) -> dict[str, Any]:
        """Every row of one trained run: {row: {budget k: mean, interval, per seed}} and the budgets reached."""
        suites = {s.quality: s for s in run.data.held_out("rollouts")}
        if self.quality not in suites:
            raise ValueError(f"quality must be one of {', '.join(suites)}, got {self.quality!r}")
        suite = suites[self.quality]
        policies = {c: OnlineAgent.load(c, greedy=run.greedy) for c in run.checkpoints}
        limit = min(p.policy.transformer.max_context for p in policies.values())
        budgets = self.budgets or list(range(0, limit + 1, max(limit // 10, 1)))
        if budgets[-1] > limit:
            raise ValueError(f"budgets: {budgets[-1]} comparisons exceed the checkpoints' max_context {limit}")
        sources = [(f"online {rule}", rule, "own") for rule in self.rules]
        sources += [(f"online {self.rules[0]}, {labels} labels", self.rules[0], labels) for labels in self.diagnostics]
        sources += [("offline", None, "own")] + [(f"offline, {labels} labels", None, labels)
                                                 for labels in self.diagnostics]
        cells = {name: np.zeros((len(policies), len(budgets), len(np.unique(suite.task_index))))
                 for name, _, _ in sources}
        with suite_env(suite) as env:
            for i, probe in enumerate(policies.values()):
                def agent(seed: int, rule: str | None = None, probe: OnlineAgent = probe) -> OnlineAgent:
                    return OnlineAgent(probe.policy, greedy=probe.greedy, seed=seed, pair_rule=rule)

                played = {name: [] for name, _, _ in sources}
                for seed in seeds:
                    for name, rule, labels in sources:
                        if rule is not None:  # the comparisons the agent asks for, answered by the teacher
                            asker = agent(seed, rule)
                            online_episodes(asker, run.data.family, suite, self.annotator, self.episodes, seed, labels)
                            deployed = replace(suite, context=asker.context)
                        else:
                            deployed = suite if labels == "own" else diagnose_suite(suite, f"{labels}_labels", seed)
                        returns = [rollout_in_context(PrefixAgent(agent(seed), k), deployed, seed, env,
                                                      progress=False)["return"] for k in budgets]
                        played[name].append([suite.normalize(r) for r in returns])
                tasks = np.tile(suite.task_index, len(seeds))
                for name, per_seed in played.items():  # [seeds][budgets] -> per budget, the per-task means
                    for j, column in enumerate(zip(*per_seed, strict=True)):
                        cells[name][i, j] = per_task_mean(np.concatenate(column), tasks)
        rows = {}
        for name, values in cells.items():
            means = values.mean(axis=(0, 2))
            rows[name] = {"mean": means.tolist(), "interval": [bootstrap(values[:, j]) for j in range(len(budgets))],
                          "per_seed": values.mean(axis=2).T.tolist(),
                          "reach": {str(t): next((k for k, m in zip(budgets, means, strict=True) if m >= t), None)
                                    for t in self.targets}}
        return {"budgets": budgets, "checkpoints": list(run.checkpoints), "tasks": int(cells["offline"].shape[2]),
                "optimal_return": suite.reference.get("optimal_return"), "rows": rows}

    @staticmethod
    def markdown(payload: dict[str, Any]) -> str:
        lines = []
        for run, result in payload["results"].items():
            budgets, rows = result["budgets"], result["rows"]
            cells = ", ".join(f"{t:.0%}" for t in payload["targets"])
            lines += [f"**{run}**: answered comparisons to first reach {cells} of the optimal return (mean over "
                      f"{len(result['checkpoints'])} training seeds × {result['tasks']} held-out tasks; teacher: "
                      f"Bradley–Terry at τ = {payload['annotator']['init_args']['temperature']:g}; "
                      f"{payload['quality']} offline context):", "",
                      "| comparisons from | " + " | ".join(f"to {t:.0%}" for t in payload["targets"]) + " |",
                      "|---" * (len(payload["targets"]) + 1) + "|"]
            for name, row in rows.items():
                reached = [row["reach"][str(t)] for t in payload["targets"]]
                lines.append(f"| {name} | " + " | ".join(f"not within {budgets[-1]}" if k is None else str(k)
                                                         for k in reached) + " |")
            lines += ["", "normalized return (fraction of optimal) with the first k comparisons in context, "
                      "mean and 95% bootstrap interval:", "",
                      "| k | " + " | ".join(rows) + " |", "|---" * (len(rows) + 1) + "|"]
            for j, k in enumerate(budgets):
                lines.append(f"| {k} | " + " | ".join(
                    f"{row['mean'][j]:.2f} ({row['interval'][j][0]:.2f}–{row['interval'][j][1]:.2f})"
                    for row in rows.values()) + " |")
            lines.append("")
        return "\n".join(lines)

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        results = payload["results"]
        fig = Figure(figsize=(6.5 * len(results), 4.0), layout="tight")
        for ax, (run, result) in zip(np.atleast_1d(fig.subplots(1, len(results))), results.items(), strict=True):
            for i, (name, row) in enumerate(result["rows"].items()):
                style = "--" if "labels" in name else "-"
                low, high = zip(*row["interval"], strict=True)
                ax.plot(result["budgets"], row["mean"], style, color=f"C{i}", marker=".", label=name)
                ax.fill_between(result["budgets"], low, high, color=f"C{i}", alpha=0.12)
            for t in payload["targets"]:
                ax.axhline(t, color="grey", linewidth=0.8, linestyle=":")
            ax.set_xlabel("answered comparisons in context (k)")
            ax.set_ylabel("return / optimal return")
            ax.set_title(f"{run}: {len(result['checkpoints'])} training seeds × {result['tasks']} held-out tasks "
                         "(95% bootstrap)", fontsize=8)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6)
        save_figure(fig, path, dpi=120)
