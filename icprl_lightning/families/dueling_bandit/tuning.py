"""Choosing the feature-aware baselines' hyperparameters on training problems only.

A small grid search on the family's *training* problems (the θ's ICPO pretrains on, ``training_problems``),
never on the held-out ones the tables report. The objective is the evaluation's offline protocol
(``linear_baselines.prefix_duels``) on uniform-pair contexts: weak regret averaged over prefixes h = 1..H (the
"AUC"). Every grid point sees the same contexts and learner seed. ``icprl baseline tune-bandit --problems 300
--horizon 50 --seed 0`` prints the grid, the choice, DTS and the Bayes reference on the same contexts.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from icprl_lightning.families.dueling_bandit.bt_thompson import BTThompsonSampling
from icprl_lightning.families.dueling_bandit.dts import DoubleThompsonSampling
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.linear_baselines import (
    Duels,
    LinearDuelingLearner,
    duel_regrets,
    prefix_duels,
)
from icprl_lightning.families.dueling_bandit.maxinp import MaxInP
from icprl_lightning.validation import check_int

# name -> (learner class, grid of constructor arguments); small on purpose (cost: grid size × problems × horizon)
GRIDS: dict[str, tuple[type[LinearDuelingLearner], dict[str, tuple[float, ...]]]] = {
    "maxinp": (MaxInP, {"beta": (0.1, 0.3, 1.0), "prior_var": (0.01, 0.03, 0.1, 0.3)}),
    "bt_thompson": (BTThompsonSampling, {"prior_var": (0.1, 0.3, 1.0), "scale": (0.03, 0.1, 0.3, 1.0)}),
}

# What ``main`` picks with its defaults (300 training problems, uniform contexts of 50 comparisons, seed 0,
# family seed 0). MaxInP's optimum is a ridge in (β, v): (0.3, 0.03) is within 0.0003 ± 0.0055 of this point.
TUNED: dict[str, dict[str, float]] = {
    "maxinp": {"beta": 0.1, "prior_var": 0.01},
    "bt_thompson": {"prior_var": 1.0, "scale": 0.1},
}


def training_problems(family: LinearDuelingBanditFamily, n: int) -> np.ndarray:
    """The first ``n`` training θ's of ``BanditDuels.generate`` for this family (``[n, d]``).

    ``generate`` draws the training θ's first from the first of three streams spawned from the family seed;
    rows are drawn in order, so these are the first ``n`` rows of its ``train_theta`` whatever its size.
    """
    check_int("training_problems", "n", n, 1)
    train_stream = np.random.SeedSequence(family.seed).spawn(3)[0]
    return family.sample_tasks(n, np.random.default_rng(train_stream))


def _sem(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def offline_score(duels: Duels, expected_rewards: np.ndarray) -> dict[str, float]:
    """Weak regret after h comparisons averaged over h ("auc") and at the last h ("final"), ± sem over problems."""
    weak = duel_regrets(expected_rewards, *duels)[0]  # [P, H]
    return {"auc": float(weak.mean()), "auc_sem": _sem(weak.mean(1)), "final": float(weak[:, -1].mean()),
            "final_sem": _sem(weak[:, -1])}


def tune(learner: type[LinearDuelingLearner], grid: dict[str, Sequence[float]], family: LinearDuelingBanditFamily,
         theta: np.ndarray, context: dict[str, np.ndarray], seed: int = 0
         ) -> tuple[dict[str, float], list[dict[str, Any]]]:
    """Score every point of ``grid`` on the training problems ``theta`` and their ``context`` (``[P, H]``).

    Returns the point of lowest AUC and one row per point: its arguments, ``offline_score`` and its AUC's
    excess over the best point's with the standard error of that paired difference (every point sees the
    same contexts, so the pairing removes the problems' own variance).
    """
    if not grid:
        raise ValueError("tune: grid must name at least one argument")
    rewards = family.expected_rewards(theta)
    rows, per_problem = [], []
    for values in itertools.product(*grid.values()):
        params = dict(zip(grid, values, strict=True))
        model = learner(family.features, len(theta), temperature=family.bt_temperature,
                        rng=np.random.default_rng(seed), **params)
        duels = prefix_duels(model, context["arms_first"], context["arms_second"], context["preferred"])
        rows.append({**params, **offline_score(duels, rewards)})
        per_problem.append(duel_regrets(rewards, *duels)[0].mean(1))
    best = int(np.argmin([row["auc"] for row in rows]))
    for row, auc in zip(rows, per_problem, strict=True):
        excess = auc - per_problem[best]
        row["auc_excess"], row["auc_excess_sem"] = float(excess.mean()), _sem(excess)
    return {k: rows[best][k] for k in grid}, rows


def dts_score(family: LinearDuelingBanditFamily, theta: np.ndarray, context: dict[str, np.ndarray],
              seed: int) -> dict[str, float]:
    """DTS on the same contexts, as ``evaluation.duels.dts_duels`` plays it."""
    dts = DoubleThompsonSampling(family.n_arms, len(theta), family.dts_alpha, rng=np.random.default_rng(seed))
    duels = prefix_duels(dts, context["arms_first"], context["arms_second"], context["preferred"])
    return offline_score(duels, family.expected_rewards(theta))
