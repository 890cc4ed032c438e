"""Weak regret reg(a, a') = min(R* − R(a), R* − R(a')) and its torchmetrics accumulator."""

from __future__ import annotations

import pytest
import torch

from icprl_lightning.metrics import WeakRegret, weak_regret

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
