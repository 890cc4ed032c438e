"""Evaluation metrics: weak regret (a torchmetrics ``Metric``) and mean ± standard error over tasks.

Weak regret (paper, appendix "Dueling Bandit Experiments"): for a duel (a, a') in problem τ,

    reg(a, a') = min(R*_τ − R_τ(a), R*_τ − R_τ(a')),

where R*_τ = max_a R_τ(a) is the optimal expected reward. It is zero as soon as either arm of the duel
is optimal. ``WeakRegret`` averages it over every duel it sees. Strong regret charges both arms,

    reg_strong(a, a') = ((R*_τ − R_τ(a)) + (R*_τ − R_τ(a'))) / 2,

zero only when both arms are optimal: the regret of Double Thompson Sampling (Wu & Liu 2016) and Saha 2021's
average regret, Yue et al. 2012's strong regret halved to one arm's scale, never below the weak regret (Chen &
Frazier 2017, "Dueling Bandits with Weak Regret", ICML, contrast the two).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor
from torchmetrics import Metric


def weak_regret(expected_rewards: Tensor, first: Tensor, second: Tensor) -> Tensor:
    """reg(a, a') per problem: ``expected_rewards [B, A]`` float, ``first``/``second [B]`` long -> ``[B]``."""
    gap_first, gap_second = _duel_gaps(expected_rewards, first, second)
    return torch.minimum(gap_first, gap_second)


def strong_regret(expected_rewards: Tensor, first: Tensor, second: Tensor) -> Tensor:
    """reg_strong(a, a') per problem, the average of the two gaps; shapes as ``weak_regret``."""
    gap_first, gap_second = _duel_gaps(expected_rewards, first, second)
    return (gap_first + gap_second) / 2


def _duel_gaps(expected_rewards: Tensor, first: Tensor, second: Tensor) -> tuple[Tensor, Tensor]:
    """(R* − R(a), R* − R(a')) per problem, after checking shapes, dtypes and arm indices."""
    if expected_rewards.dim() != 2 or not expected_rewards.is_floating_point():
        raise ValueError(f"expected_rewards must be a float tensor of shape [B, A], "
                         f"got {expected_rewards.dtype} {list(expected_rewards.shape)}")
    batch, n_arms = expected_rewards.shape
    for name, arms in (("first", first), ("second", second)):
        if arms.shape != (batch,) or arms.is_floating_point():
            raise ValueError(f"{name} must be an integer tensor of shape [B={batch}], "
                             f"got {arms.dtype} {list(arms.shape)}")
        if arms.numel() and (arms.min() < 0 or arms.max() >= n_arms):
            raise ValueError(f"{name} holds arm indices outside [0, {n_arms})")
    best = expected_rewards.max(dim=-1).values
    reward_first = expected_rewards.gather(-1, first.long().unsqueeze(-1)).squeeze(-1)
    reward_second = expected_rewards.gather(-1, second.long().unsqueeze(-1)).squeeze(-1)
    return best - reward_first, best - reward_second


class WeakRegret(Metric):
    """Mean weak regret over all duels passed to ``update``."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    total: Tensor
    count: Tensor

    def __init__(self) -> None:
        super().__init__()
        self.add_state("total", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("count", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(self, expected_rewards: Tensor, first: Tensor, second: Tensor) -> None:
        regret = weak_regret(expected_rewards, first, second)
        self.total += regret.double().sum()
        self.count += regret.numel()

    def compute(self) -> Tensor:
        # Accumulated in float64 so long evaluations do not drift; reported as float32 like other metrics.
        return (self.total / self.count).float()


def mean_sem(values: np.ndarray) -> tuple[float, float]:
    values = np.asarray(values, dtype=np.float64)
    sem = values.std(ddof=1) / np.sqrt(len(values)) if len(values) > 1 else float("nan")
    return float(values.mean()), float(sem)


def mean_sem_or_none(values) -> tuple[float, float | None]:
    """``mean_sem``, with the sem ``None`` for a single value (no spread to report; JSON has no NaN)."""
    mean, sem = mean_sem(values)
    return mean, (sem if len(np.atleast_1d(values)) > 1 else None)


def per_task_mean(values: np.ndarray, task_index: np.ndarray) -> np.ndarray:
    tasks, inverse = np.unique(task_index, return_inverse=True)
    return np.bincount(inverse, weights=values) / np.bincount(inverse)
