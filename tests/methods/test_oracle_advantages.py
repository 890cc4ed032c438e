"""DIT's advantage stage swapped for its oracle: A*(s_h, a_h) stored with the reward trajectories
(``RewardTrajectories(oracle_advantages=True)``) and read by ``DITModule(advantage="oracle")``; never by ICRG."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from factories import darkroom_data  # noqa: E402

from icprl_lightning.families.darkroom.oracle import optimal_advantage
from icprl_lightning.methods.dit import DITModule, swap_roles
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.losses import advantage_weighted_loss, standardized_advantages
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError, check_pairing

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2,
            progress=False, batch_size=8)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)


@pytest.fixture(scope="module")
def with_oracle(data_root):
    dm = darkroom_data("reward_trajectory", root_dir=data_root, oracle_advantages=True, **TINY)
    dm.prepare_data()
    return dm


def test_stored_advantages_are_the_oracles_a_star_of_the_behavior_actions(with_oracle, data_root):
    data = with_oracle.load()
    train = data["train"]
    family = with_oracle.family
    goals = np.asarray(data["tasks"]["train_goals"])[np.asarray(train["task_index"])]
    horizon = family.horizon
    for side in "ab":
        states, actions = np.asarray(train[f"states_{side}"]), np.asarray(train[f"actions_{side}"])
        steps_left = horizon - np.arange(horizon)[None, :]
        expected = optimal_advantage(states, actions, goals[:, None, :], steps_left, family)
        np.testing.assert_allclose(np.asarray(train[f"advantages_{side}"]), expected, atol=1e-6)
        assert (np.asarray(train[f"advantages_{side}"]) <= 1e-6).all()  # no action beats the optimal one
    # the option adds fields and changes nothing else: the same trajectories and rewards as without it
    plain = darkroom_data("reward_trajectory", root_dir=data_root, **TINY)
    plain.prepare_data()
    for k, v in plain.load()["train"].items():
        np.testing.assert_array_equal(np.asarray(train[k]), np.asarray(v), err_msg=k)
    assert "advantages_a" not in plain.load()["train"]
    served = next(iter(with_oracle.train_dataloader()))
    assert served.advantages_a.shape == served.trajectory_a.rewards.shape and served.advantages_b is not None
    assert next(iter(plain.train_dataloader())).advantages_a is None


def test_dit_oracle_advantage_weights_the_policy_by_the_served_a_star(with_oracle):
    torch.manual_seed(0)
    model = DITModule(**ENV, **SIZES, value_epochs=0, advantage="oracle")
    batch = next(iter(with_oracle.train_dataloader()))
    context, scored = swap_roles(*model.labeled_trajectories(batch))
    weights = standardized_advantages(torch.cat([batch.advantages_b, batch.advantages_a]))
    expected = advantage_weighted_loss(model.log_likelihood(context, scored), weights, model.hparams.eta,
                                       model.hparams.max_weight)
    torch.testing.assert_close(model.loss(batch)[0], expected)
    # Q̂ and V̂ play no part: moving them leaves the loss as it is
    with torch.no_grad():
        for estimator in (model.q_value, model.v_value):
            estimator.apply(lambda m: [p.add_(1.0) for p in m.parameters(recurse=False)])
    torch.testing.assert_close(model.loss(batch)[0], expected)


def test_pairing_names_the_missing_oracle_advantages_before_a_fit(with_oracle, data_root):
    model = DITModule(**ENV, **SIZES, value_epochs=0, advantage="oracle")
    check_pairing(model, with_oracle)  # served: no error
    plain = darkroom_data("reward_trajectory", root_dir=data_root, **TINY)
    with pytest.raises(HyperparameterError, match="oracle_advantages true"):
        check_pairing(model, plain)
    check_pairing(DITModule(**ENV, **SIZES), plain)  # the other advantages read no extra field


def test_icrg_refuses_the_oracle_advantage():
    with pytest.raises(HyperparameterError, match="oracle"):
        ICRGModule(**ENV, **SIZES, advantage="oracle", reward_gen_hparams={})


def test_oracle_advantages_are_only_for_reward_trajectories():
    from icprl_lightning.data.settings import TrajectoryPairs

    with pytest.raises(TypeError):
        TrajectoryPairs(oracle_advantages=True)  # a preference dataset never holds A*
