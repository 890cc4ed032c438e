"""RewardGen's causal reading of its own pair (``pair_source="context_causal"``): step h sees only the context's
steps < h, in training, in ICRG's relabeling and at deployment; its checkpoints keep the rule; and the reward
quality measures (``icprl analyze reward-quality``, ``evaluation/reward_quality.py``) run end to end on a tiny
checkpoint."""

from __future__ import annotations

import json
import pathlib

import lightning as L
import numpy as np
import pytest
import torch
from factories import darkroom_data, darkroom_tprl_config, save_untrained

from icprl_lightning.checkpoints import load_module
from icprl_lightning.commands import main
from icprl_lightning.contexts import ActionSpec, TrajectoryPreferenceContext
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.evaluation import reward_quality
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.estimator import InContextRewardModel
from icprl_lightning.samples import ContextSamples

SETTING = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2,
               reference_episodes=2)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)
H = 6


pytestmark = pytest.mark.usefixtures("one_thread")


def _pair(seed: int = 0, b: int = 3, h: int = H) -> TrajectoryPreferenceContext:
    g = torch.Generator().manual_seed(seed)
    return TrajectoryPreferenceContext(torch.rand(b, h, 2, generator=g) * 9, torch.randint(0, 5, (b, h), generator=g),
                                       torch.rand(b, h, 2, generator=g) * 9, torch.randint(0, 5, (b, h), generator=g),
                                       torch.tensor([1.0, 0.0, 1.0])[:b])


def _altered(ctx: TrajectoryPreferenceContext, steps: slice, seed: int = 1) -> TrajectoryPreferenceContext:
    """``ctx`` with both trajectories' states and actions at ``steps`` redrawn."""
    other = _pair(seed, ctx.batch_size, ctx.states_a.shape[1])
    out = ctx.map(torch.clone)
    for name in ("states_a", "actions_a", "states_b", "actions_b"):
        getattr(out, name)[:, steps] = getattr(other, name)[:, steps]
    return out


def _model(causal: bool) -> InContextRewardModel:
    torch.manual_seed(0)
    return InContextRewardModel(2, ActionSpec(True, 5), **SIZES, max_context=H, causal=causal).eval()


@torch.no_grad()
def test_causal_query_for_step_h_sees_only_the_contexts_steps_before_h():
    model, ctx, query = _model(causal=True), _pair(0), _pair(2)
    states, actions = torch.cat([query.states_a, query.states_b], 1), torch.cat([query.actions_a, query.actions_b], 1)
    r = model(ctx, states, actions)  # (B, 2H): ξ_a's steps then ξ_b's, step i mod H
    assert torch.isfinite(r).all()
    for h in range(H):
        later = model(_altered(ctx, slice(h, None)), states, actions)
        for offset in (0, H):  # the same step of either trajectory
            torch.testing.assert_close(later[:, offset:offset + h + 1], r[:, offset:offset + h + 1])
        if h > 0:  # a token the query for step h sees (step h - 1) moves it
            earlier = model(_altered(ctx, slice(h - 1, h)), states, actions)
            assert not torch.allclose(earlier[:, h], r[:, h]) and not torch.allclose(earlier[:, H + h], r[:, H + h])
    # step 0 sees no context token at all: flipping every label (which swaps the winner/loser slots) leaves it
    flipped = TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, ctx.states_b, ctx.actions_b, 1 - ctx.preferred)
    out = model(flipped, states, actions)
    torch.testing.assert_close(out[:, [0, H]], r[:, [0, H]])
    assert not torch.allclose(out[:, 1:H], r[:, 1:H])
    # the whole-context reading is what the flag changes: there the last step moves step 0's reward
    whole = _model(causal=False)
    assert not torch.allclose(whole(_altered(ctx, slice(H - 1, None)), states, actions)[:, 0],
                              whole(ctx, states, actions)[:, 0])


def test_causal_reading_names_queries_it_cannot_place():
    model, ctx = _model(causal=True), _pair(0)
    torch.testing.assert_close(model(ctx, ctx.states_a[:, :4], ctx.actions_a[:, :4]),  # a prefix: steps 0..3
                               model(ctx, ctx.states_a, ctx.actions_a)[:, :4])
    with pytest.raises(ValueError, match="states: a causal R_ψ .* got 9"):
        model(ctx, torch.cat([ctx.states_a, ctx.states_b[:, :3]], 1),
              torch.cat([ctx.actions_a, ctx.actions_b[:, :3]], 1))
    with pytest.raises(ValueError, match="causal must be a bool"):
        InContextRewardModel(2, ActionSpec(True, 5), **SIZES, max_context=H, causal="yes")


@torch.no_grad()
def test_context_causal_scores_its_own_pair_causally():
    torch.manual_seed(0)
    causal = RewardGenModule(**ENV, **SIZES, pair_source="context_causal").eval()
    leaky = RewardGenModule(**ENV, **SIZES, pair_source="context").eval()
    leaky.load_state_dict(causal.state_dict())
    assert causal.reward.causal and not leaky.reward.causal and causal.hparams.causal and not leaky.hparams.causal
    assert not causal.needs_pairs
    ctx = _pair(0, h=H)
    batch = ContextSamples(ctx)
    h = 2  # redraw ξ_a after step h: the context's tokens > h and ξ_a's own queries > h change
    changed = ContextSamples(ctx.map(torch.clone))
    changed.context.states_a[:, h + 1:] = _pair(5).states_a[:, h + 1:]
    changed.context.actions_a[:, h + 1:] = _pair(5).actions_a[:, h + 1:]
    seen = torch.cat([torch.arange(h + 1), H + torch.arange(h + 1)])  # both trajectories' steps <= h
    before, after = causal.pair_rewards(batch)[2], causal.pair_rewards(changed)[2]
    torch.testing.assert_close(after[:, seen], before[:, seen])
    assert not torch.allclose(leaky.pair_rewards(changed)[2][:, seen], leaky.pair_rewards(batch)[2][:, seen])


@pytest.fixture(scope="module")
def tprl(data_root) -> PreferenceDataModule:
    dm = darkroom_data("trajectory_preference", root_dir=data_root, pairs=True, progress=False, batch_size=8,
                       **SETTING)
    dm.prepare_data()
    return dm


@pytest.fixture(scope="module")
def causal_ckpt(tprl, tmp_path_factory) -> pathlib.Path:
    """RewardGen(pair_source=context_causal) after two Lightning training steps and a validation pass."""
    torch.manual_seed(0)
    trainer = L.Trainer(max_steps=2, val_check_interval=1, limit_val_batches=1, logger=False,
                        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0)
    model = RewardGenModule(**ENV, **SIZES, pair_source="context_causal")
    trainer.fit(model, datamodule=tprl)
    assert trainer.global_step == 2 and torch.isfinite(trainer.callback_metrics["train/loss"])
    assert model.reward.reward_std.item() != 1.0  # the validation pass stored R_ψ's output statistics
    path = tmp_path_factory.mktemp("causal") / "reward_gen.ckpt"
    trainer.save_checkpoint(path)
    return path


def test_causal_checkpoint_round_trips_with_its_reading_rule(causal_ckpt):
    loaded = load_module(causal_ckpt)
    assert isinstance(loaded, RewardGenModule) and loaded.hparams.pair_source == "context_causal"
    assert loaded.reward.causal and loaded.hparams.causal
    raw = torch.load(causal_ckpt, map_location="cpu", weights_only=True)
    assert raw["hyper_parameters"]["causal"] is True
    again = RewardGenModule.load_from_checkpoint(causal_ckpt, weights_only=True)  # Lightning's loader too
    assert again.reward.causal
    torch.testing.assert_close(again.state_dict(), loaded.state_dict())


@torch.no_grad()
def test_icrg_from_a_causal_reward_gen_labels_causally(tprl, causal_ckpt, tmp_path):
    model = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(causal_ckpt), value_epochs=0).eval()
    assert model.reward_gen.causal and model.hparams.reward_gen_hparams["causal"] is True
    batch = next(iter(tprl.train_dataloader()))
    a, b = model.labeled_trajectories(batch)
    h = 40
    # the conditioning pair redrawn from step h on: the labels of steps <= h stay
    later = batch._replace(pair=batch.pair.map(torch.clone))
    for states in (later.pair.states_a, later.pair.states_b):
        states[:, h:] = torch.rand_like(states[:, h:]) * 9
    a2, b2 = model.labeled_trajectories(later)
    torch.testing.assert_close(a2.rewards[:, :h + 1], a.rewards[:, :h + 1])
    torch.testing.assert_close(b2.rewards[:, :h + 1], b.rewards[:, :h + 1])
    assert not torch.allclose(a2.rewards[:, h + 1:], a.rewards[:, h + 1:])
    # deployment: the behavior trajectory's step h sees the pair's steps < h, through the saved ICRG checkpoint
    path = tmp_path / "icrg.ckpt"
    checkpoint = {"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}
    model.on_save_checkpoint(checkpoint)
    torch.save(checkpoint, path)
    agent = load_module(path).make_agent(greedy=True)
    assert agent.reward_model.causal
    ctx = next(s for s in tprl.held_out("rollouts") if s.quality == "low").context
    agent.reset(ctx)
    moved = TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, *_redrawn(ctx.states_b, ctx.actions_b, h),
                                        ctx.preferred, ctx.behavior_states, ctx.behavior_actions)
    first = agent.labeled_context.rewards.clone()
    agent.reset(moved)
    torch.testing.assert_close(agent.labeled_context.rewards[:, :h + 1], first[:, :h + 1])
    assert not torch.allclose(agent.labeled_context.rewards[:, h + 1:], first[:, h + 1:])
    # an architecture without the flag (an ICRG checkpoint saved before it existed) reads the whole context
    old = ICRGModule(**ENV, **SIZES, reward_gen_hparams=dict(backbone=SIZES["backbone"].as_dict(), max_context=100))
    assert not old.reward_gen.causal


def _redrawn(states: torch.Tensor, actions: torch.Tensor, h: int) -> tuple[torch.Tensor, torch.Tensor]:
    states, actions = states.clone(), actions.clone()
    states[:, h:] = torch.rand_like(states[:, h:]) * 9
    actions[:, h:] = (actions[:, h:] + 1) % 5
    return states, actions


def _config(tmp_path: pathlib.Path, data_root: str) -> pathlib.Path:
    return darkroom_tprl_config(tmp_path / "tiny.yaml", data_root, SETTING)


def test_quality_command_end_to_end(tprl, causal_ckpt, data_root, tmp_path, capsys):
    out_json = tmp_path / "quality.json"
    main(["analyze", "reward-quality", "--data-config", str(_config(tmp_path, data_root)), "--ckpt",
          str(causal_ckpt), "--ckpt", str(causal_ckpt), "--json", str(out_json)])
    out = json.loads(out_json.read_text())
    assert out == json.loads(json.dumps(reward_quality.reward_quality(_config(tmp_path, data_root),
                                                                      [causal_ckpt, causal_ckpt])))
    assert out["pair_source"] == "context_causal" and out["causal"] is True
    assert out["checkpoints"] == [str(causal_ckpt)] * 2 and len(out["per_checkpoint"]) == 2
    model = load_module(causal_ckpt)
    pairs = tprl.held_out("pair_accuracy")
    suites = {s.quality: s.context for s in tprl.held_out("rollouts")}
    for q in ("low", "medium", "high"):
        result = out["per_checkpoint"][0][q]
        assert set(result) == {"other_pair_accuracy", "own_pair_accuracy", "reward_correlation"}
        assert all(out["mean"][q][k]["sem"] == 0 for k in result)  # the same checkpoint twice
        # own pair under the model's (causal) rule: what RewardGen(context_causal) trains on
        assert result["own_pair_accuracy"] == pytest.approx(float(model.pair_correct(pairs[q]).float().mean()))
        scored, other = pairs[q].context, pairs[q].pair
        assert not torch.equal(other.states_a, scored.states_a)  # another pair of the task, not the scored one
        ret_a, ret_b, _ = model.score_pair(other, scored)
        assert result["other_pair_accuracy"] == pytest.approx(float(((ret_a > ret_b) == (scored.preferred > 0.5))
                                                                    .float().mean()))
        assert -1.0 <= result["reward_correlation"] <= 1.0
    # the correlation is against the latent rewards of the same behavior trajectories
    rewards = darkroom_data("reward_trajectory", root_dir=data_root, progress=False, **SETTING)
    rewards.prepare_data()
    low = next(s for s in rewards.held_out("rollouts") if s.quality == "low").context
    labels = model.reward.label(suites["low"], suites["low"].behavior_states, suites["low"].behavior_actions)
    expected = np.corrcoef(labels.detach().flatten().numpy(), low.rewards.flatten().numpy())[0, 1]
    assert out["per_checkpoint"][1]["low"]["reward_correlation"] == pytest.approx(expected)
    printed = capsys.readouterr().out
    assert "| quality |" in printed and "causal" in printed


def test_quality_command_refuses_mixed_pair_sources(causal_ckpt, data_root, tmp_path, capsys):
    other = save_untrained(RewardGenModule(**ENV, **SIZES), tmp_path / "other.ckpt")
    with pytest.raises(SystemExit) as info:
        main(["analyze", "reward-quality", "--data-config", str(_config(tmp_path, data_root)), "--ckpt",
              str(causal_ckpt), str(other), "--json", str(tmp_path / "q.json")])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("icprl analyze reward-quality: error: --ckpt") and "mix pair_source values" in err, err
    assert not (tmp_path / "q.json").exists()


def test_a_reward_gen_saved_before_the_reading_rule_reads_the_whole_context():
    from icprl_lightning.checkpoints import hyperparameters
    from icprl_lightning.methods.icrg import build_reward_model, check_stage1

    flat = {"state_dim": 2, "action_dim": 5, "discrete": True, "n_layer": 1, "n_embd": 8, "n_head": 2,
            "max_context": H, "dropout": 0.0}  # no "causal": written before context_causal existed
    old = hyperparameters({"hyper_parameters": flat})  # as the checkpoint reader hands it over
    arch = check_stage1("old.ckpt", old, {"state_dim": 2, "action_dim": 5, "discrete": True})
    assert arch["backbone"] == {"n_layer": 1, "n_embd": 8, "n_head": 2, "dropout": 0.0}
    assert "causal" not in arch
    assert build_reward_model(2, ActionSpec(True, 5), arch).causal is False
    assert check_stage1("new.ckpt", {**old, "causal": True}, {"state_dim": 2})["causal"] is True
