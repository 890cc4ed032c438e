"""I-PRL and reward-context generation: semantics, determinism, statistics, the reward-free invariant."""

import numpy as np
import pytest
from factories import darkroom_data, served_fields, step_contexts  # noqa: E402

from icprl_lightning.data.store import DatasetError
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import transition
from icprl_lightning.families.darkroom.oracle import optimal_advantage

# Anything that would let a preference method see the task: rewards, goals, A*, Q*, V*.
FORBIDDEN = ("reward", "goal", "advantage", "q_value", "value", "return")


def test_state_follows_the_preferred_action_and_labels_follow_bt():
    fam = DarkRoomFamily()
    goals = np.repeat(fam.train_goals, 50, axis=0)
    arrays, stats = step_contexts(fam, goals, 0.5, 1.0, np.random.default_rng(0))
    s, a, a2, y = (arrays[k] for k in ("states", "actions", "alt_actions", "preferred"))
    winner = np.where(y == 1, a, a2).astype(np.int64)
    nxt = transition(s[:, :-1].astype(np.int64), winner[:, :-1], fam.size)
    np.testing.assert_array_equal(nxt, s[:, 1:])
    # label rate against the formula, pooled by A* difference (fixed seed, 4 binomial sds)
    k = fam.horizon - np.arange(fam.horizon)[None, :]
    u1 = optimal_advantage(s.astype(np.int64), a, goals[:, None], k, fam)
    u2 = optimal_advantage(s.astype(np.int64), a2, goals[:, None], k, fam)
    for diff in (-2, -1, 0, 1, 2):
        sel = (u1 - u2) == diff
        p = 1 / (1 + np.exp(-diff))
        n = sel.sum()
        assert n > 1000
        assert abs(y[sel].mean() - p) < 4 * np.sqrt(p * (1 - p) / n), diff
    assert 0.7 < stats["label_agreement"] < 0.95
    # the agreement BT labels would have at each temperature: at the data's own (1) it is what was drawn
    expected = stats["expected_agreement_by_bt_temperature"]
    assert abs(expected["1.0"] - stats["label_agreement"]) < 0.01
    assert list(expected.values()) == sorted(expected.values()) and expected["0.01"] > 0.999  # gaps are ≥ 1
    assert stats["median_utility_gap"] == 1.0


def test_same_seed_same_bytes(tmp_path):
    kw = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=1,
              calibration_episodes=2, progress=False)
    digests = []
    for name in ("a", "b"):
        dm = darkroom_data(data_dir=str(tmp_path / name), **kw)
        dm.prepare_data()
        digests.append(sorted((k, v["sha256"]) for k, v in dm.load().manifest["files"].items()))
    assert digests[0] == digests[1]
    other = darkroom_data(data_dir=str(tmp_path / "c"), **{**kw, "seed": 1})
    other.prepare_data()
    assert sorted((k, v["sha256"]) for k, v in other.load().manifest["files"].items()) != digests[0]


def test_manifest_records_calibration_agreement_and_references(tiny_ipref):
    info = tiny_ipref.load().manifest["info"]
    assert set(info["calibration"]) == {"low", "medium", "high"}
    assert 0.5 < info["train_statistics"]["label_agreement"] < 1.0
    ref = info["test_reference"]
    assert ref["low"]["behavior_return"] < ref["medium"]["behavior_return"] < ref["high"]["behavior_return"]
    assert ref["high"]["behavior_return"] < ref["high"]["optimal_return"]


def test_preference_batches_carry_no_reward_goal_or_advantage(tiny_ipref):
    """The reward-free invariant: an I-PRL batch holds comparisons, states and (for DP²T) action labels only."""
    batch = next(iter(tiny_ipref.train_dataloader()))
    served = served_fields(batch)
    assert served == {"context.states", "context.actions", "context.alt_actions", "context.preferred", "query_states",
                      "optimal_actions", "pair.states", "pair.actions", "pair.alt_actions", "pair.preferred", "task"}
    for key in served:
        assert not any(word in key for word in FORBIDDEN), key
    for suite in tiny_ipref.held_out("rollouts"):
        assert not any(any(w in f for w in FORBIDDEN) for f in vars(suite.context)), suite.quality


def test_icpo_batches_without_labels_have_no_optimal_actions(tiny_ipref, tiny_kwargs):
    dm = darkroom_data(root_dir=tiny_ipref.root_dir, pairs=True, query_labels=False, **tiny_kwargs)
    batch = next(iter(dm.train_dataloader()))
    assert batch.optimal_actions is None and batch.query_states is None


def test_pairs_come_from_another_trajectory_of_the_same_task(tiny_ipref):
    data = tiny_ipref.load()["train"]
    batch = next(iter(tiny_ipref.train_dataloader()))
    states = np.asarray(data["states"])
    for ctx, pair in zip(batch.context.states.numpy(), batch.pair.states.numpy(), strict=True):
        i = int(np.flatnonzero((states == ctx).all(axis=(1, 2)))[0])
        j = int(np.flatnonzero((states == pair).all(axis=(1, 2)))[0])
        assert i != j and data["task_index"][i] == data["task_index"][j]


def test_config_mismatch_names_the_key_and_the_fix(tiny_ipref, tiny_kwargs):
    dm = darkroom_data(data_dir=str(tiny_ipref.path), bt_temperature=2.0, **tiny_kwargs)
    with pytest.raises(DatasetError, match=r"bt_temperature: on disk 1.0, requested 2.0") as err:
        dm.prepare_data()
    assert "icprl generate" in str(err.value)


def test_reward_contexts_from_a_pretraining_policy(tmp_path):
    from icprl_lightning.data.settings import RewardContexts
    from icprl_lightning.validation import HyperparameterError

    with pytest.raises(HyperparameterError, match="pretraining_target"):
        RewardContexts(train_policy="pretraining")
    with pytest.raises(HyperparameterError, match="pretraining_target"):
        RewardContexts(pretraining_target=1.0)
    with pytest.raises(HyperparameterError, match="pretraining_target"):
        RewardContexts(pretraining_target=1.5, train_policy="pretraining")
    setting = RewardContexts(pretraining_target=1.0, train_policy="pretraining", trajectories_per_task=2,
                             val_trajectories_per_task=1, eval_contexts_per_task=1, calibration_episodes=2,
                             reference_episodes=2)
    splits, info = setting.generate(DarkRoomFamily(), progress=False)
    assert info["calibration"]["pretraining"]["mixing"] == pytest.approx(1.0, abs=0.05)
    assert np.all(splits["train"]["quality"] == 3) and np.all(splits["eval_low"]["quality"] == 0)
    assert setting.config()["pretraining_target"] == 1.0


def test_reward_contexts_hold_true_rewards(tiny_reward):
    data = tiny_reward.load()["train"]
    goals = np.asarray(tiny_reward.load()["tasks"]["train_goals"])[np.asarray(data["task_index"])]
    on_goal = np.all(np.asarray(data["next_states"]) == goals[:, None], axis=-1)
    np.testing.assert_array_equal(np.asarray(data["rewards"]), on_goal.astype(np.float32))
