"""Every loss against numbers computed by hand."""

import math

import pytest
import torch

from icprl_lightning.methods.losses import (
    advantage_weighted_loss,
    dit_value_loss,
    icpo_continuous_loss,
    icpo_loss,
    standardized_advantages,
    supervised_action_loss,
    trajectory_preference_loss,
)


def test_icpo_loss_by_hand():
    lp_plus = torch.tensor([math.log(0.5), math.log(0.8)])
    lp_minus = torch.tensor([math.log(0.25), math.log(0.1)])
    beta, lam = 2.0, 0.5
    # z = β (log p⁺ − λ log p⁻): [2(ln .5 − .5 ln .25), 2(ln .8 − .5 ln .1)] = [0, 2 ln .8 − ln .1]
    z = torch.tensor([0.0, 2 * math.log(0.8) - math.log(0.1)])
    expected = -torch.log(torch.sigmoid(z)).mean()
    assert icpo_loss(lp_plus, lp_minus, beta, lam).item() == pytest.approx(expected.item(), rel=1e-6)
    assert icpo_loss(lp_plus[:1], lp_minus[:1], beta, lam).item() == pytest.approx(math.log(2), rel=1e-6)


def test_supervised_loss_by_hand():
    logits = torch.tensor([[[0.0, 0.0, math.log(2.0)]]])  # p = [.25, .25, .5]
    assert supervised_action_loss(logits, torch.tensor([[2]]), True).item() == pytest.approx(math.log(2))
    assert supervised_action_loss(logits, torch.tensor([[0]]), True).item() == pytest.approx(math.log(4))
    mean = torch.tensor([[0.0, 1.0]])
    assert supervised_action_loss(mean, torch.tensor([[3.0, -1.0]]), False).item() == pytest.approx(13.0)


def test_icpo_continuous_loss_by_hand():
    mu = torch.tensor([[0.0, 0.0]])
    plus, minus = torch.tensor([[3.0, 4.0]]), torch.tensor([[0.0, 1.0]])  # distances 5 and 1
    # default: euclidean, λ on the rejected side: −log σ(β (λ·1 − 5))
    got = icpo_continuous_loss(mu, plus, minus, beta=0.5, lam=2.0).item()
    assert got == pytest.approx(-math.log(1 / (1 + math.exp(-0.5 * (2.0 - 5.0)))), rel=1e-6)
    # λ on the preferred side: −log σ(β (1 − λ·5))
    got = icpo_continuous_loss(mu, plus, minus, beta=0.5, lam=2.0, lambda_on_preferred=True).item()
    assert got == pytest.approx(-math.log(1 / (1 + math.exp(-0.5 * (1.0 - 10.0)))), rel=1e-6)
    # squared distances (the derivation's form): −log σ(β (1 − 25))
    got = icpo_continuous_loss(mu, plus, minus, beta=0.1, squared=True).item()
    assert got == pytest.approx(-math.log(1 / (1 + math.exp(-0.1 * (1.0 - 25.0)))), rel=1e-6)


def test_trajectory_preference_loss_by_hand():
    # y = 1 (ξ_a won), R(ξ_a) − R(ξ_b) = 2: −log σ(2); y = 0 with the same sums: −log σ(−2)
    got = trajectory_preference_loss(torch.tensor([3.0, 3.0]), torch.tensor([1.0, 1.0]), torch.tensor([1.0, 0.0]))
    expected = (math.log(1 + math.exp(-2.0)) + math.log(1 + math.exp(2.0))) / 2
    assert got.item() == pytest.approx(expected, rel=1e-6)


def test_dit_value_loss_by_hand():
    q, v, g = torch.tensor([1.0, 2.0]), torch.tensor([0.0, 0.0]), torch.tensor([1.0, 4.0])
    # mean (Q̂ − G)² = (0 + 4) / 2 = 2, mean (V̂ − G)² = (1 + 16) / 2 = 8.5
    assert dit_value_loss(q, v, g).item() == pytest.approx(10.5)


def test_standardized_advantages_remove_the_offset_only_when_centred():
    q = torch.tensor([5.0, 6.0, 7.0, 8.0])  # Q̂ − V̂ = 5..8: an offset of 6.5, std √(5/3)
    v = torch.zeros(4)
    std = math.sqrt(5 / 3)
    centred = standardized_advantages(q, v)
    assert centred.tolist() == pytest.approx([(x - 6.5) / std for x in (5, 6, 7, 8)], rel=1e-5)
    assert centred.mean().item() == pytest.approx(0.0, abs=1e-6)
    raw = standardized_advantages(q, v, center=False)
    assert raw.tolist() == pytest.approx([x / std for x in (5, 6, 7, 8)], rel=1e-5)
    # uncentred, every weight exp(Â/η) at η = 1 hits a clip of 20 (Â ≥ 3.87 > ln 20): DIT would be cloning
    assert bool((torch.exp(raw) >= 20).all()) and not bool((torch.exp(centred) >= 20).any())


def test_advantage_weighted_loss_by_hand():
    log_likelihood = torch.tensor([-1.0, -2.0, -0.5], requires_grad=True)
    advantages = torch.tensor([0.0, math.log(2.0), 10.0])
    # weights exp(Â / η) at η = 1: [1, 2, e^10 clipped to 20]
    got = advantage_weighted_loss(log_likelihood, advantages, eta=1.0, max_weight=20.0)
    assert got.item() == pytest.approx((1.0 * 1 + 2 * 2 + 20 * 0.5) / 3, rel=1e-6)
    got.backward()  # the weights carry no gradient: d/dℓ = −w / n
    assert log_likelihood.grad.tolist() == pytest.approx([-1 / 3, -2 / 3, -20 / 3], rel=1e-6)
    # η = 0.5 sharpens: exp(2 ln 2) = 4
    assert advantage_weighted_loss(log_likelihood[1:2], advantages[1:2], 0.5, 20.0).item() == pytest.approx(8.0)
