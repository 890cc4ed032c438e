"""T-PRL data on DarkRoom: BT label rates, trajectory semantics, the reward-free invariant, the typed context."""

import numpy as np
import pytest
import torch
from factories import served_fields, trajectory_pairs  # noqa: E402

from icprl_lightning import TrajectoryPreferenceContext
from icprl_lightning.contexts import ActionSpec, context_from_fields
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import step_reward, transition
from icprl_lightning.models.tokenizers import TrajectoryPreferenceTokenizer

FORBIDDEN = ("reward", "goal", "advantage", "q_value", "value", "return")




def test_labels_follow_bt_on_return_differences():
    fam = DarkRoomFamily()
    goals = np.repeat(fam.train_goals, 40, axis=0)
    p = np.random.default_rng(1).uniform(0.05, 0.5, len(goals))  # spread of return gaps
    temperature = 8.0  # large enough that labels are not deterministic on DarkRoom's 0–95 returns
    arrays, rewards, stats = trajectory_pairs(fam, goals, p, temperature, np.random.default_rng(0))
    diff = rewards["rewards_a"].sum(1) - rewards["rewards_b"].sum(1)
    y = arrays["preferred"]
    for lo, hi in ((-12, -6), (-6, -1), (-1, 1), (1, 6), (6, 12)):
        sel = (diff >= lo) & (diff < hi)
        expected = (1 / (1 + np.exp(-diff[sel] / temperature))).mean()
        n = sel.sum()
        assert n > 150, (lo, hi)
        assert abs(y[sel].mean() - expected) < 4 * np.sqrt(expected * (1 - expected) / n), (lo, hi)
    sharp = trajectory_pairs(fam, goals, p, 1.0, np.random.default_rng(0))[2]
    assert 0.5 < stats["label_agreement"] < sharp["label_agreement"] <= 1.0
    assert stats["tie_fraction"] == sharp["tie_fraction"]  # same seed, same trajectories


def test_trajectories_follow_the_dynamics_and_hold_no_rewards():
    fam = DarkRoomFamily()
    goals = np.repeat(fam.train_goals[:5], 4, axis=0)
    arrays, rewards, _ = trajectory_pairs(fam, goals, np.full(len(goals), 0.5), 1.0,
                                                         np.random.default_rng(0), behavior=True)
    assert set(arrays) == {"states_a", "actions_a", "states_b", "actions_b", "preferred", "behavior_states",
                           "behavior_actions"}
    assert set(rewards) == {"rewards_a", "rewards_b", "behavior_rewards"}
    for side in ("a", "b"):
        s, a = arrays[f"states_{side}"].astype(np.int64), arrays[f"actions_{side}"].astype(np.int64)
        assert s.shape == (20, fam.horizon, 2) and a.shape == (20, fam.horizon)
        nxt = transition(s, a, fam.size)
        np.testing.assert_array_equal(nxt[:, :-1], s[:, 1:])
        np.testing.assert_array_equal(rewards[f"rewards_{side}"], step_reward(nxt, goals[:, None]))
    assert arrays["preferred"].shape == (20,) and set(np.unique(arrays["preferred"])) <= {0, 1}


def test_batches_and_eval_contexts_carry_no_reward(tprl):
    """The reward-free invariant: T-PRL batches hold states, actions, labels (and DP²T's action labels) only."""
    batch = next(iter(tprl.train_dataloader()))
    pair = ("states_a", "actions_a", "states_b", "actions_b", "preferred")
    served = served_fields(batch)
    assert served == {*(f"context.{k}" for k in pair), *(f"pair.{k}" for k in pair), "query_states",
                      "optimal_actions", "task"}
    assert batch.context.states_a.shape == (8, 100, 2) and batch.context.preferred.shape == (8,)
    for key in served:
        assert not any(word in key for word in FORBIDDEN), key
    assert not any("reward" in f for f in tprl.load().manifest["files"])  # nothing on disk either
    for suite in tprl.held_out("rollouts"):
        ctx = suite.context
        assert isinstance(ctx, TrajectoryPreferenceContext) and ctx.behavior_states.shape == (40, 100, 2)
        assert not any(any(w in f for w in FORBIDDEN) for f in vars(ctx)), suite.quality


def test_manifest_records_agreement_ties_and_references(tprl):
    info = tprl.load().manifest["info"]
    assert info["calibration"]["high"]["mixing"] > info["calibration"]["low"]["mixing"]
    for stats in (info["train_statistics"], *info["eval_statistics"].values()):
        assert 0.5 < stats["label_agreement"] <= 1.0 and 0.0 <= stats["tie_fraction"] < 0.5
    ref = info["test_reference"]
    assert ref["low"]["behavior_return"] < ref["medium"]["behavior_return"] < ref["high"]["behavior_return"]
    assert tprl.generator_config()["setting"] == "TrajectoryPairs" and "trajectory_preference" in tprl.path.name


def test_reward_kind_holds_the_same_trajectories_with_true_rewards(tprl, tprl_rewards):
    pref, rew = tprl.load(), tprl_rewards.load()
    for split in ("train", "eval_low"):
        np.testing.assert_array_equal(pref[split]["states_a"], rew[split]["states_a"])
        np.testing.assert_array_equal(pref[split]["actions_b"], rew[split]["actions_b"])
    goals = np.asarray(rew["tasks"]["train_goals"])[np.asarray(rew["train"]["task_index"])]
    s = np.asarray(rew["train"]["states_a"]).astype(np.int64)
    nxt = transition(s, np.asarray(rew["train"]["actions_a"]).astype(np.int64), 10)
    np.testing.assert_array_equal(rew["train"]["rewards_a"], step_reward(nxt, goals[:, None]))
    batch = next(iter(tprl_rewards.train_dataloader()))
    assert served_fields(batch) == {f"trajectory_{side}.{k}" for side in "ab" for k in ("states", "actions", "rewards")
                                    } | {"task"}
    suite = tprl_rewards.held_out("rollouts")[0]
    np.testing.assert_array_equal(suite.context.states.numpy(), rew["eval_low"]["behavior_states"])


def test_other_pairs_and_heldout_pairs_come_from_the_same_task(tprl):
    data = tprl.load()["train"]
    states = np.asarray(data["states_a"])
    batch = next(iter(tprl.train_dataloader()))
    for ctx, other in zip(batch.context.states_a.numpy(), batch.pair.states_a.numpy(), strict=True):
        i = int(np.flatnonzero((states == ctx).all(axis=(1, 2)))[0])
        j = int(np.flatnonzero((states == other).all(axis=(1, 2)))[0])
        assert i != j and data["task_index"][i] == data["task_index"][j]
    held = tprl.held_out("pair_accuracy")["medium"]
    split = tprl.load()["eval_medium"]
    np.testing.assert_array_equal(held.context.states_b.numpy(), split["states_b"])
    np.testing.assert_array_equal(held.pair.states_b[0].numpy(), split["states_b"][1])  # next context, same goal
    np.testing.assert_array_equal(held.pair.states_b[1].numpy(), split["states_b"][0])
    assert split["task_index"][0] == split["task_index"][1]


def test_settings_refuse_unknown_policies_and_bad_temperatures():
    from icprl_lightning.data.settings import StepPreferences, TrajectoryPairs

    with pytest.raises(ValueError, match="train_policy must be one of"):
        StepPreferences(train_policy="pretraining")  # only T-PRL calibrates a pretraining policy
    with pytest.raises(ValueError, match="first_policy"):
        StepPreferences(first_policy="expert")
    with pytest.raises(ValueError, match="next_state_follows"):
        StepPreferences(next_state_follows="goal")
    with pytest.raises(ValueError, match="bt_temperature"):
        TrajectoryPairs(bt_temperature=0.0)


def _pair(b: int = 3, h: int = 5) -> TrajectoryPreferenceContext:
    g = torch.Generator().manual_seed(0)
    return TrajectoryPreferenceContext(torch.rand(b, h, 2, generator=g), torch.randint(0, 5, (b, h), generator=g),
                                       torch.rand(b, h, 2, generator=g), torch.randint(0, 5, (b, h), generator=g),
                                       torch.tensor([1.0, 0.0, 1.0]))


def test_context_validation_names_the_expected_shape():
    spec = ActionSpec(discrete=True, size=5)
    ctx = _pair()
    ctx.validate(2, spec)
    with pytest.raises(ValueError, match=r"preferred must have shape \[B=3\]"):
        TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, ctx.states_b, ctx.actions_b,
                                    torch.ones(3, 5)).validate(2, spec)
    with pytest.raises(ValueError, match=r"states_b must have shape \[B=3, H=5, S=2\]"):
        TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, ctx.states_b[:, :4], ctx.actions_b,
                                    ctx.preferred).validate(2, spec)
    pair = (ctx.states_a, ctx.actions_a, ctx.states_b, ctx.actions_b, ctx.preferred)
    with pytest.raises(ValueError, match="both or neither"):
        TrajectoryPreferenceContext(*pair, behavior_states=ctx.states_a).validate(2, spec)
    with pytest.raises(ValueError, match="behavior_actions holds action indices outside"):
        TrajectoryPreferenceContext(*pair, ctx.states_a, ctx.actions_a + 5).validate(2, spec)


def test_context_from_fields_takes_optional_behavior_fields_when_present():
    ctx = _pair()
    fields = {k: v for k, v in vars(ctx).items() if v is not None}
    assert context_from_fields("trajectory_preference", fields).behavior_states is None
    fields.update(behavior_states=ctx.states_a, behavior_actions=ctx.actions_a)
    assert context_from_fields("trajectory_preference", fields).behavior_states is ctx.states_a
    assert context_from_fields("trajectory_preference", fields).to("cpu").behavior_actions.shape == (3, 5)


def test_pair_tokens_encode_the_label_by_order():
    """Swapping (ξ_a, ξ_b) and flipping y gives the same tokens; flipping y alone does not."""
    torch.manual_seed(0)
    tok = TrajectoryPreferenceTokenizer(2, ActionSpec(True, 5), 8)
    ctx = _pair()
    swapped = TrajectoryPreferenceContext(ctx.states_b, ctx.actions_b, ctx.states_a, ctx.actions_a, 1 - ctx.preferred)
    flipped = TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, ctx.states_b, ctx.actions_b, 1 - ctx.preferred)
    torch.testing.assert_close(tok(ctx), tok(swapped))
    assert not torch.allclose(tok(ctx), tok(flipped))
    assert tok(ctx).shape == (3, 5, 8)  # one token per step of the pair
