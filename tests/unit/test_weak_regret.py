"""Weak regret reg(a, a') = min(R* − R(a), R* − R(a')), strong regret (the average of the two gaps),
the torchmetrics accumulator, and the evaluation's curves."""

from __future__ import annotations

import pytest
import torch

from icprl_lightning.evaluation import curve_mean_sem, regret_curve, summarize_regret
from icprl_lightning.metrics import WeakRegret, strong_regret, weak_regret

REWARDS = torch.tensor([
    [0.0, 1.0, 3.0, 2.0],     # R* = 3
    [-1.0, -0.5, -2.0, 0.5],  # R* = 0.5
    [1.0, 1.0, 1.0, 1.0],     # every arm optimal
])


def test_weak_regret_hand_computed() -> None:
    first = torch.tensor([0, 0, 2])
    second = torch.tensor([1, 2, 1])
    # [min(3, 2), min(1.5, 2.5), 0]
    torch.testing.assert_close(weak_regret(REWARDS, first, second), torch.tensor([2.0, 1.5, 0.0]))


def test_weak_regret_zero_when_either_arm_is_optimal() -> None:
    first = torch.tensor([2, 0, 0])
    second = torch.tensor([0, 3, 0])
    torch.testing.assert_close(weak_regret(REWARDS, first, second), torch.zeros(3))
    # Symmetric in the pair.
    torch.testing.assert_close(weak_regret(REWARDS, second, first), torch.zeros(3))


def test_strong_regret_hand_computed_is_the_average_gap() -> None:
    first = torch.tensor([0, 0, 2])
    second = torch.tensor([1, 2, 1])
    # [(3 + 2) / 2, (1.5 + 2.5) / 2, 0]: the duels of the weak case above
    torch.testing.assert_close(strong_regret(REWARDS, first, second), torch.tensor([2.5, 2.0, 0.0]))
    torch.testing.assert_close(strong_regret(REWARDS, second, first), torch.tensor([2.5, 2.0, 0.0]))
    # zero only when both arms are optimal: an optimal arm beside a worse one costs half the worse one's gap
    torch.testing.assert_close(strong_regret(REWARDS, torch.tensor([2, 3, 0]), torch.tensor([2, 0, 3])),
                               torch.tensor([0.0, 0.75, 0.0]))
    # a self-duel costs its arm's gap: arm 3 of row 0 (3 − 2), arm 1 of row 1 (0.5 − (−0.5))
    torch.testing.assert_close(strong_regret(REWARDS, torch.tensor([3, 1, 1]), torch.tensor([3, 1, 1])),
                               torch.tensor([1.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="outside"):
        strong_regret(REWARDS, torch.tensor([0, 1, 4]), torch.tensor([1, 2, 3]))


def test_metric_accumulates_and_resets() -> None:
    metric = WeakRegret()
    metric.update(REWARDS[:2], torch.tensor([0, 0]), torch.tensor([1, 2]))  # 2.0, 1.5
    metric.update(REWARDS, torch.tensor([0, 1, 2]), torch.tensor([0, 1, 2]))  # 3.0, 1.0, 0.0
    assert metric.compute().item() == pytest.approx((2.0 + 1.5 + 3.0 + 1.0 + 0.0) / 5)
    metric.reset()
    metric.update(REWARDS[:1], torch.tensor([3]), torch.tensor([3]))
    assert metric.compute().item() == pytest.approx(1.0)


def test_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match=r"\[B, A\]"):
        weak_regret(REWARDS[0], torch.tensor([0]), torch.tensor([1]))
    with pytest.raises(ValueError, match=r"\[B=3\]"):
        weak_regret(REWARDS, torch.tensor([0, 1]), torch.tensor([1, 2, 3]))
    with pytest.raises(ValueError, match="integer"):
        weak_regret(REWARDS, torch.tensor([0.0, 1.0, 2.0]), torch.tensor([1, 2, 3]))
    with pytest.raises(ValueError, match="outside"):
        weak_regret(REWARDS, torch.tensor([0, 1, 4]), torch.tensor([1, 2, 3]))


def test_curves_and_their_summary_agree_with_the_metric() -> None:
    """The evaluation's per-h curves [B, H], summarized over problems, equal WeakRegret over the same duels."""
    g = torch.Generator().manual_seed(0)
    rewards = torch.randn(9, 5, generator=g, dtype=torch.float64)
    first, second = torch.randint(0, 5, (9, 7), generator=g), torch.randint(0, 5, (9, 7), generator=g)
    curve = regret_curve(rewards, (first, second))
    assert curve.shape == (9, 7)
    torch.testing.assert_close(curve[:, 3], weak_regret(rewards, first[:, 3], second[:, 3]))
    summary = summarize_regret(curve)
    final, over_h = WeakRegret(), WeakRegret()
    final.update(rewards, first[:, -1], second[:, -1])
    for h in range(7):
        over_h.update(rewards, first[:, h], second[:, h])
    assert summary["weak_regret"] == pytest.approx(final.compute().item(), rel=1e-6)
    assert summary["weak_regret_auc"] == pytest.approx(over_h.compute().item(), rel=1e-6)
    per_problem = curve[:, -1].numpy()
    assert summary["weak_regret_sem"] == pytest.approx(per_problem.std(ddof=1) / 3.0)  # sqrt(9) problems
    mean, sem = curve_mean_sem(curve)
    assert mean.shape == sem.shape == (7,) and mean[-1] == pytest.approx(summary["weak_regret"])
    assert sem[-1] == pytest.approx(summary["weak_regret_sem"])
