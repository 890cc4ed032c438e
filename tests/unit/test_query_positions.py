"""``queries_per_context``: a training step scores k of the H query positions; the model is unchanged."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.methods.dpt import DP2TModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError

H = 12


def _batch(b: int = 3) -> ContextSamples:
    g = torch.Generator().manual_seed(0)
    ctx = StepPreferenceContext(torch.randint(0, 5, (b, H, 2), generator=g).float(),
                                torch.randint(0, 5, (b, H), generator=g), torch.randint(0, 5, (b, H), generator=g),
                                torch.randint(0, 2, (b, H), generator=g).float())
    return ContextSamples(ctx, pair=ctx.map(lambda x: x.flip(0)),
                          query_states=torch.randint(0, 5, (b, H, 2), generator=g).float(),
                          optimal_actions=torch.randint(0, 5, (b, H), generator=g))


def _module(cls, **kw):
    torch.manual_seed(0)
    return cls(state_dim=2, action_dim=5, discrete=True, max_context=H,
               backbone=TransformerConfig(n_layer=2, n_embd=16, n_head=2), **kw)


def test_training_draws_k_sorted_positions_and_validation_scores_all():
    module = _module(ICPOModule, queries_per_context=4).train()
    draws = {tuple(module.query_positions(H, torch.device("cpu")).tolist()) for _ in range(20)}
    assert all(len(d) == 4 and list(d) == sorted(set(d)) and d[0] >= 0 and d[-1] < H for d in draws)
    assert len(draws) > 1  # a new draw each step
    assert module.eval().query_positions(H, torch.device("cpu")).tolist() == list(range(H))
    assert _module(ICPOModule).train().query_positions(H, torch.device("cpu")).tolist() == list(range(H))


def test_the_k_query_loss_is_the_full_loss_restricted_to_the_drawn_positions():
    """Queries never see each other, so scoring k of them is exactly the full pass's per-query losses at those
    positions, averaged."""
    batch = _batch()
    module = _module(DP2TModule, queries_per_context=5).train()
    full = module.policy(batch.context, batch.query_states, torch.arange(1, H + 1))
    per_query = F.cross_entropy(full.transpose(1, 2), batch.optimal_actions, reduction="none")  # (B, H)
    torch.manual_seed(7)
    positions = module.query_positions(H, torch.device("cpu"))
    torch.manual_seed(7)
    loss, _ = module.loss(batch)
    assert loss.item() == pytest.approx(per_query[:, positions].mean().item(), rel=1e-5)


def test_icpo_with_k_equal_to_h_is_the_default_loss():
    batch = _batch()
    a, _ = _module(ICPOModule, beta=0.1, lam=1.0).train().loss(batch)
    b, _ = _module(ICPOModule, beta=0.1, lam=1.0, queries_per_context=H).train().loss(batch)
    assert a.item() == pytest.approx(b.item(), rel=1e-6)


@pytest.mark.parametrize("bad", [0, -3, 2.5, "4"])
def test_queries_per_context_is_checked(bad):
    with pytest.raises(HyperparameterError, match="queries_per_context"):
        _module(ICPOModule, queries_per_context=bad)


def test_bf16_autocast_trains_the_same_model():
    """``--trainer.precision bf16-mixed`` on CPU runs the loss under bf16 autocast: finite, close to fp32."""
    batch = _batch()
    module = _module(ICPOModule, beta=0.1, lam=1.0, queries_per_context=6).train()
    torch.manual_seed(3)
    full, _ = module.loss(batch)
    torch.manual_seed(3)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        half, _ = module.loss(batch)
    half.backward()
    assert torch.isfinite(half) and half.item() == pytest.approx(full.item(), rel=0.05)
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in module.parameters() if p.requires_grad)


def test_icpo_scores_the_other_trajectory_in_shuffled_order_by_default():
    """pair_steps: shuffled draws a fresh permutation of the other trajectory's steps per sample (the context's
    length must not tell the time); aligned scores step t at query t."""
    module = _module(ICPOModule)
    draws = [module.scored_steps(3, H, torch.device("cpu")) for _ in range(5)]
    for steps in draws:
        assert steps.shape == (3, H) and all(sorted(row.tolist()) == list(range(H)) for row in steps)
    assert len({tuple(s.flatten().tolist()) for s in draws}) == 5
    assert not all(torch.equal(row, torch.arange(H)) for row in draws[0])
    aligned = _module(ICPOModule, pair_steps="aligned").scored_steps(3, H, torch.device("cpu"))
    assert torch.equal(aligned, torch.arange(H).expand(3, H))


def test_icpo_shuffled_loss_is_the_aligned_loss_on_permuted_pairs():
    """The shuffled loss equals the aligned loss on a batch whose pair was permuted by the same draw."""
    batch = _batch()
    module = _module(ICPOModule, beta=0.5, lam=1.0).train()
    torch.manual_seed(11)
    shuffled, _ = module.loss(batch)
    torch.manual_seed(11)
    steps = module.scored_steps(3, H, torch.device("cpu"))
    rows = torch.arange(3)[:, None]
    permuted = batch._replace(pair=batch.pair.map(lambda x: x[rows, steps]))
    module.hparams.pair_steps = "aligned"
    aligned, _ = module.loss(permuted)
    assert shuffled.item() == pytest.approx(aligned.item(), rel=1e-6)
    assert module.loss(batch)[0].item() != pytest.approx(aligned.item(), rel=1e-6)  # the order matters


def test_pair_steps_is_checked():
    with pytest.raises(HyperparameterError, match="pair_steps"):
        _module(ICPOModule, pair_steps="sorted")
