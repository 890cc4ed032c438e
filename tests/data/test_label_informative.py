"""Label-informative I-PRL contexts: where the states come from and which action they follow."""

from __future__ import annotations

import numpy as np
import pytest
from factories import reward_contexts, step_contexts

from icprl_lightning.data.settings import RewardContexts, StepPreferences
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import transition
from icprl_lightning.validation import HyperparameterError

FAMILY = DarkRoomFamily()


def _contexts(n=200, p=0.9, **kw):
    goals = np.repeat(FAMILY.train_goals[:4], n // 4, axis=0)
    arrays, stats = step_contexts(FAMILY, goals, p, 1.0, np.random.default_rng(0), **kw)
    return goals, arrays, stats


def _distance(states, goals):
    return np.abs(states - goals[:, None, :]).sum(-1)


def test_uniform_states_cover_the_grid_and_say_nothing_about_the_goal():
    goals, arrays, _ = _contexts(state_source="uniform")
    states = arrays["states"].astype(int)
    counts = np.bincount((states[..., 0] * FAMILY.size + states[..., 1]).ravel(), minlength=FAMILY.size ** 2)
    expected = states.shape[0] * states.shape[1] / FAMILY.size ** 2
    assert counts.min() > 0.7 * expected and counts.max() < 1.3 * expected  # 200 per cell on average
    # a high-quality rollout walks to the goal; uniform states stay as far from it as random cells are
    _, rollout, _ = _contexts(state_source="rollout")
    uniform_d, rollout_d = _distance(arrays["states"], goals).mean(), _distance(rollout["states"], goals).mean()
    random_d = _distance(np.random.default_rng(1).integers(0, FAMILY.size, states.shape), goals).mean()
    assert abs(uniform_d - random_d) < 0.1 and rollout_d < 0.5 * uniform_d


def test_uniform_states_do_not_depend_on_the_labels_or_actions():
    _, a, _ = _contexts(state_source="uniform", next_state_follows="preferred")
    _, b, _ = _contexts(state_source="uniform", next_state_follows="rejected")
    np.testing.assert_array_equal(a["states"], b["states"])  # same draws, only the label's side differs
    np.testing.assert_array_equal(a["preferred"], b["preferred"])


@pytest.mark.parametrize("follows", ["preferred", "rejected", "behavior", "first"])
def test_rollout_states_follow_the_stated_action(follows):
    _, arrays, stats = _contexts(n=40, p=0.5, next_state_follows=follows)
    s, nxt = arrays["states"][:, :-1].astype(np.int64), arrays["states"][:, 1:].astype(np.int64)
    won = arrays["preferred"][:, :-1] == 1
    a, alt = arrays["actions"][:, :-1].astype(np.int64), arrays["alt_actions"][:, :-1].astype(np.int64)
    follows_a = np.all(transition(s, a, FAMILY.size) == nxt, -1)
    follows_alt = np.all(transition(s, alt, FAMILY.size) == nxt, -1)
    assert np.all(follows_a | follows_alt)
    distinct = np.any(transition(s, a, FAMILY.size) != transition(s, alt, FAMILY.size), -1)
    followed_preferred = np.where(won, follows_a, follows_alt)[distinct]
    if follows == "preferred":
        assert followed_preferred.all()
    elif follows == "rejected":
        assert not followed_preferred.any()
    else:  # a policy's proposal whatever the label: the preferred one about as often as the labels favour it
        assert 0.3 < followed_preferred.mean() < 0.9
    assert 0.5 < stats["label_agreement"] <= 1.0


def test_dpt_reward_contexts_take_the_same_state_source():
    goals = np.repeat(FAMILY.train_goals[:2], 50, axis=0)
    roll = RewardContexts(state_source="uniform").contexts(
        FAMILY, goals, np.zeros(len(goals), dtype=int), np.array([0.9]), np.random.default_rng(0), False, False, "")[0]
    states, actions = roll["states"].astype(np.int64), roll["actions"].astype(np.int64)
    np.testing.assert_array_equal(transition(states, actions, FAMILY.size), roll["next_states"])
    assert not np.array_equal(roll["next_states"][:, :-1], roll["states"][:, 1:])  # the next state is a new draw
    default = reward_contexts(FAMILY, goals, np.full(len(goals), 0.9), np.random.default_rng(0))[0]
    np.testing.assert_array_equal(default["next_states"][:, :-1], default["states"][:, 1:])  # rollout: continues


def test_unknown_state_source_and_unsupported_families_are_clear_errors():
    with pytest.raises(HyperparameterError, match="state_source"):
        StepPreferences(state_source="grid")
    with pytest.raises(HyperparameterError, match="next_state_follows"):
        StepPreferences(next_state_follows="second")

    class NoIndependentStates(DarkRoomFamily):
        independent_state_rollouts = DarkRoomFamily.__mro__[1].independent_state_rollouts

    family = NoIndependentStates()
    with pytest.raises(NotImplementedError, match="independent_state_rollouts"):
        StepPreferences(state_source="uniform").contexts(
            family, family.train_goals[:2], np.array([0, 0]), np.array([0.5]), np.random.default_rng(0), False,
            False, "")


def test_overlays_stack_on_every_darkroom_per_step_config(tmp_path):
    from factories import REPO

    from icprl_lightning.data.config import datamodule_from_config

    overlays = [str(REPO / f"configs/overlays/{name}.yaml") for name in ("uniform_states", "decisive_teacher")]
    for config in ("icpo_darkroom", "dp2t_darkroom"):
        dm = datamodule_from_config(str(REPO / f"configs/{config}.yaml"), *overlays, root_dir=str(tmp_path))
        assert (dm.setting.state_source, dm.setting.bt_temperature) == ("uniform", 0.25)
    dpt = datamodule_from_config(str(REPO / "configs/dpt_darkroom.yaml"), overlays[0], root_dir=str(tmp_path))
    assert dpt.setting.state_source == "uniform"
