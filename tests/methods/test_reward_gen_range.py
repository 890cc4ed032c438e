"""RewardGen's ``reward_range``: bounded per-step rewards r̂ = low + (high − low) σ(f), kept in the checkpoint and
copied by ICRG; bad ranges name the field."""

from __future__ import annotations

import pytest
import torch

from icprl_lightning.checkpoints import load_module
from icprl_lightning.contexts import TrajectoryPreferenceContext
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError

ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
H = 7

pytestmark = pytest.mark.usefixtures("one_thread")


def _pair(b: int = 4) -> TrajectoryPreferenceContext:
    g = torch.Generator().manual_seed(0)
    return TrajectoryPreferenceContext(torch.rand(b, H, 2, generator=g) * 9, torch.randint(0, 5, (b, H), generator=g),
                                       torch.rand(b, H, 2, generator=g) * 9, torch.randint(0, 5, (b, H), generator=g),
                                       (torch.rand(b, generator=g) > 0.5).float())


@torch.no_grad()
def test_bounded_rewards_are_the_squashed_unbounded_ones():
    torch.manual_seed(0)
    free = RewardGenModule(**ENV, **SIZES).eval()
    bounded = RewardGenModule(**ENV, **SIZES, reward_range=[-2, 3]).eval()
    bounded.load_state_dict(free.state_dict())
    ctx = _pair()
    states, actions = torch.cat([ctx.states_a, ctx.states_b], 1), torch.cat([ctx.actions_a, ctx.actions_b], 1)
    raw, r = free(ctx, states, actions), bounded(ctx, states, actions)
    torch.testing.assert_close(r, -2 + 5 * torch.sigmoid(raw))
    assert r.min() > -2 and r.max() < 3 and bounded.reward.reward_range == (-2.0, 3.0)
    ret_a, ret_b, per_step = bounded.score_pair(ctx, ctx)  # the Bradley–Terry sums are over the bounded rewards
    torch.testing.assert_close(ret_a, per_step[:, :H].sum(1))


@pytest.mark.parametrize("bad, rule", [([1, 0], "low < high"), ([0], "a list"), ("0,1", "a list"),
                                       ([0, float("inf")], "finite"), ([0, "x"], "a number")])
def test_bad_ranges_name_the_field(bad, rule):
    with pytest.raises(HyperparameterError, match=f"RewardGenModule: reward_range must be .*{rule}"):
        RewardGenModule(**ENV, **SIZES, reward_range=bad)


@torch.no_grad()
def test_icrg_copies_the_range_from_the_checkpoint(tmp_path):
    model = RewardGenModule(**ENV, **SIZES, reward_range=[0, 1])
    checkpoint = {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}
    model.on_save_checkpoint(checkpoint)
    path = tmp_path / "reward_gen.ckpt"
    torch.save(checkpoint, path)
    loaded = load_module(path)  # weights_only: a list of two numbers is safe to load
    assert loaded.reward.reward_range == (0.0, 1.0)
    icrg = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(path), value_epochs=0)
    assert icrg.reward_gen.reward_range == (0.0, 1.0)
    ctx = _pair()
    torch.testing.assert_close(icrg.reward_gen(ctx, ctx.states_a, ctx.actions_a),
                               loaded.reward(ctx, ctx.states_a, ctx.actions_a))
    unbounded = RewardGenModule(**ENV, **SIZES)
    assert unbounded.reward.reward_range is None and unbounded.hparams.reward_range is None
