"""Every loss against numbers computed by hand."""

import math

import pytest
import torch

from icprl_lightning.methods.losses import icpo_continuous_loss, icpo_loss, supervised_action_loss


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
