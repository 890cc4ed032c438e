"""Input standardization (models/normalization.py): statistics by hand, invariance to the inputs' units, fitting at
fit start once, and the statistics travelling with the checkpoint to a deployed agent."""

import copy

import lightning as L
import numpy as np
import pytest
import torch
from factories import darkroom_data

from icprl_lightning import RewardTrajectoryContext, load_agent
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.normalization import InputNormalizer

SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)

pytestmark = pytest.mark.usefixtures("one_thread")


def test_statistics_by_hand_and_constant_dimensions_keep_unit_scale():
    norm = InputNormalizer(3)
    states = np.array([[[0.0, 5.0, 1.0], [2.0, 5.0, 3.0]]], dtype=np.float32)  # dim 1 is constant
    norm.fit({"states_a": states, "rewards_a": np.array([[1.0, 3.0]], dtype=np.float32),
              "actions_a": np.full((1, 2), 7.0, dtype=np.float32)})
    torch.testing.assert_close(norm.state_mean, torch.tensor([1.0, 5.0, 2.0]))
    torch.testing.assert_close(norm.state_std, torch.tensor([1.0, 1.0, 1.0]))
    assert (norm.reward_mean.item(), norm.reward_std.item(), bool(norm.fitted)) == (2.0, 1.0, True)
    ctx = RewardTrajectoryContext(torch.tensor(states), torch.zeros(1, 2, dtype=torch.long), torch.tensor([[1.0, 3.0]]))
    out = norm.context(ctx)
    torch.testing.assert_close(out.states, torch.tensor([[[-1.0, 0.0, -1.0], [1.0, 0.0, 1.0]]]))
    torch.testing.assert_close(out.rewards, torch.tensor([[-1.0, 1.0]]))
    assert out.actions is ctx.actions


def test_a_split_without_states_of_the_width_is_a_clear_error():
    with pytest.raises(ValueError, match="no field of states of width 3"):
        InputNormalizer(3).fit({"states": np.zeros((2, 4, 2)), "rewards": np.zeros((2, 4))})


def test_standardized_model_does_not_see_the_inputs_units():
    """Refitting on states and rewards in other units (×10 + 3) gives the same outputs on the same data in those
    units; without standardization the outputs change."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    split = {"states_a": rng.normal(size=(6, 10, 2)).astype(np.float32),
             "rewards_a": rng.normal(size=(6, 10)).astype(np.float32)}
    moved = {k: v * 10 + 3 for k, v in split.items()}
    outputs = []
    for normalize in (True, False):
        model = DITModule(**ENV, **SIZES, normalize_inputs=normalize)
        other = copy.deepcopy(model)
        for m, data in ((model, split), (other, moved)):
            for n in m.modules():
                if isinstance(n, InputNormalizer):
                    n.fit(data)
        ctx = [RewardTrajectoryContext(torch.tensor(d["states_a"]), torch.zeros(6, 10, dtype=torch.long),
                                       torch.tensor(d["rewards_a"])) for d in (split, moved)]
        with torch.no_grad():
            a = (model.v_value(ctx[0], ctx[0].states), model.log_likelihood(ctx[0], ctx[0]))
            b = (other.v_value(ctx[1], ctx[1].states), other.log_likelihood(ctx[1], ctx[1]))
        outputs.append(all(torch.allclose(x, y, atol=1e-5) for x, y in zip(a, b, strict=True)))
    assert outputs == [True, False]


def test_fit_start_fits_every_network_once_and_the_agent_keeps_the_statistics(data_root, tmp_path):
    dm = darkroom_data(context_kind="reward_trajectory", root_dir=data_root, trajectories_per_task=3,
                       val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2, progress=False,
                       batch_size=8)
    dm.prepare_data()
    torch.manual_seed(0)
    model = DITModule(**ENV, **SIZES, value_epochs=0, normalize_inputs=True)
    trainer = L.Trainer(max_steps=1, limit_val_batches=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    normalizers = [m for m in model.modules() if isinstance(m, InputNormalizer)]
    assert len(normalizers) == 3 and all(n.fitted for n in normalizers)  # policy, Q̂, V̂
    train = dm.load()["train"]
    states = np.concatenate([np.asarray(train[k]).reshape(-1, 2) for k in ("states_a", "states_b")])
    torch.testing.assert_close(model.policy.normalizer.state_mean, torch.tensor(states.mean(0), dtype=torch.float32))
    assert model.policy.normalizer.reward_std.item() > 0

    # a second fit (resume, fine-tuning) keeps the statistics it has
    model.policy.normalizer.state_mean.add_(1.0)
    kept = model.policy.normalizer.state_mean.clone()
    L.Trainer(max_steps=1, limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
              enable_model_summary=False).fit(model, datamodule=dm)
    torch.testing.assert_close(model.policy.normalizer.state_mean, kept)

    path = tmp_path / "dit.ckpt"
    trainer.save_checkpoint(path)
    agent = load_agent(path, seed=0)
    torch.testing.assert_close(agent.policy.normalizer.state_mean, kept)
    ctx = dm.held_out("rollouts")[0].context
    agent.reset(ctx)
    assert agent.act(ctx.states[:, 0]).shape == (ctx.batch_size,)


@pytest.mark.parametrize("method, data", [("ICPO", "tiny_ipref"), ("DP2T", "tiny_ipref"), ("DPT", "tiny_reward")])
def test_every_policy_method_standardizes_and_a_preference_method_sees_no_reward_statistics(method, data, request):
    from icprl_lightning.methods.dpt import DP2TModule, DPTModule
    from icprl_lightning.methods.icpo import ICPOModule

    dm = request.getfixturevalue(data)
    torch.manual_seed(0)
    model = {"ICPO": ICPOModule, "DP2T": DP2TModule, "DPT": DPTModule}[method](**ENV, **SIZES, normalize_inputs=True)
    L.Trainer(max_steps=1, limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
              enable_model_summary=False).fit(model, datamodule=dm)
    norm = model.policy.normalizer
    assert bool(norm.fitted) and (norm.state_std != 1).all()
    rewarded = method == "DPT"  # only the reward-context oracle is served rewards
    reward_statistics = (norm.reward_mean.item(), norm.reward_std.item())
    assert (reward_statistics != (0.0, 1.0)) == rewarded, reward_statistics


def test_rewardgen_standardizes_and_icrg_keeps_its_statistics(data_root, tmp_path):
    """RewardGen fits its statistics on the pairs' states; ICRG copies its architecture with normalize_inputs, loads
    the fitted statistics with the weights and does not refit them; its own DIT networks see no true rewards."""
    from icprl_lightning.methods.icrg import ICRGModule
    from icprl_lightning.methods.reward_gen import RewardGenModule

    dm = darkroom_data("trajectory_preference", root_dir=data_root, pairs=True, query_labels=True,
                       trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2,
                       calibration_episodes=2, progress=False, batch_size=8)
    dm.prepare_data()
    torch.manual_seed(0)

    def fit(model):
        trainer = L.Trainer(max_steps=1, limit_val_batches=0, logger=False, enable_checkpointing=False,
                            enable_progress_bar=False, enable_model_summary=False)
        trainer.fit(model, datamodule=dm)
        return trainer

    stage1 = RewardGenModule(**ENV, **SIZES, normalize_inputs=True)
    trainer = fit(stage1)
    assert bool(stage1.reward.normalizer.fitted)
    path = tmp_path / "rg.ckpt"
    trainer.save_checkpoint(path)
    stage1.reward.normalizer.state_mean.add_(1.0)  # the checkpoint holds the fitted statistics, not these
    icrg = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(path), normalize_inputs=True)
    assert icrg.hparams.reward_gen_hparams["normalize_inputs"] is True
    fitted = icrg.reward_gen.normalizer.state_mean.clone()
    fit(icrg)
    torch.testing.assert_close(icrg.reward_gen.normalizer.state_mean, fitted)
    torch.testing.assert_close(fitted + 1.0, stage1.reward.normalizer.state_mean)
    assert bool(icrg.policy.normalizer.fitted)
    assert (icrg.v_value.normalizer.reward_mean.item(), icrg.v_value.normalizer.reward_std.item()) == (0.0, 1.0)
