"""T-PRL methods: RewardGen, DIT, ICRG and DP²T on pairs — losses by hand, updates, deployment, configs."""

import math
import pathlib

import lightning as L
import pytest
import torch
from factories import TPRL_TINY, cli_data_args, darkroom_data  # noqa: E402

from icprl_lightning import RewardTrajectoryContext, TrajectoryPreferenceContext, load_agent
from icprl_lightning.commands import run_cli
from icprl_lightning.methods.dit import DITModule, swap_roles, unexplained_variance
from icprl_lightning.methods.dpt import DP2TModule
from icprl_lightning.methods.icrg import ICRGAgent, ICRGModule
from icprl_lightning.methods.losses import (
    advantage_weighted_loss,
    discounted_returns,
    dit_value_loss,
    gae_advantages,
    return_to_go_advantages,
    standardized_advantages,
    td_advantages,
    trajectory_preference_loss,
)
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.samples import RewardTrajectorySamples

REPO = pathlib.Path(__file__).resolve().parents[2]
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100)


pytestmark = pytest.mark.usefixtures("one_thread")


# ---- losses by hand ------------------------------------------------------------------------------

def test_trajectory_preference_loss_by_hand():
    # pair 1: ξ_a won with R_a − R_b = 1 -> −log σ(1); pair 2: ξ_b won with R_a − R_b = −2 -> −log σ(2)
    got = trajectory_preference_loss(torch.tensor([3.0, 0.0]), torch.tensor([2.0, 2.0]), torch.tensor([1.0, 0.0]))
    assert got.item() == pytest.approx((math.log(1 + math.exp(-1)) + math.log(1 + math.exp(-2))) / 2, rel=1e-6)
    # the wrong label on pair 2 costs −log σ(−2)
    got = trajectory_preference_loss(torch.tensor([0.0]), torch.tensor([2.0]), torch.tensor([1.0]))
    assert got.item() == pytest.approx(math.log(1 + math.exp(2)), rel=1e-6)


def test_discounted_returns_and_value_loss_by_hand():
    g = discounted_returns(torch.tensor([[1.0, 0.0, 2.0], [0.0, 0.0, 1.0]]), gamma=0.5)
    torch.testing.assert_close(g, torch.tensor([[1.5, 1.0, 2.0], [0.25, 0.5, 1.0]]))
    q, v, target = torch.tensor([1.0, 2.0]), torch.tensor([0.0, 0.0]), torch.tensor([1.0, 0.0])
    assert dit_value_loss(q, v, target).item() == pytest.approx((0 + 4) / 2 + (1 + 0) / 2)


def test_advantage_weighted_loss_by_hand_with_clipping():
    loglik = torch.tensor([math.log(0.5), math.log(0.25), math.log(0.1)], requires_grad=True)
    adv = torch.tensor([0.0, 1.0, 10.0])
    # weights exp(A/η) with η = 0.5: [1, e², e²⁰ -> clipped at 20]
    expected = -(math.log(0.5) + math.exp(2) * math.log(0.25) + 20 * math.log(0.1)) / 3
    loss = advantage_weighted_loss(loglik, adv, eta=0.5, max_weight=20.0)
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    loss.backward()
    torch.testing.assert_close(loglik.grad, -torch.tensor([1.0, math.exp(2), 20.0]) / 3)


def test_standardized_advantages_remove_the_offset_only_when_centred():
    q, v = torch.tensor([5.0, 6.0, 7.0, 8.0]), torch.zeros(4)  # Q̂ − V̂ = 5..8: offset 6.5, std √(5/3)
    std = math.sqrt(5 / 3)
    centred = standardized_advantages(q - v)
    assert centred.tolist() == pytest.approx([(x - 6.5) / std for x in (5, 6, 7, 8)], rel=1e-5)
    raw = standardized_advantages(q - v, center=False)
    assert raw.tolist() == pytest.approx([x / std for x in (5, 6, 7, 8)], rel=1e-5)
    # uncentred, every weight exp(Â/η) at η = 1 reaches a clip of 20 (Â ≥ 3.87 > ln 20): DIT would be cloning
    assert bool((torch.exp(raw) >= 20).all()) and not bool((torch.exp(centred) >= 20).any())


def test_td_advantages_read_the_next_state_value_and_stop_at_the_horizon():
    v = torch.tensor([[0.2, 0.5, 0.1]])
    r = torch.tensor([[0.0, 1.0, 2.0]])
    gamma = 0.9  # (1 − γ) r_h + γ V̂(s_{h+1}) − V̂(s_h), V̂ = 0 after the last step
    expected = [0.9 * 0.5 - 0.2, 0.1 * 1.0 + 0.9 * 0.1 - 0.5, 0.1 * 2.0 - 0.1]
    assert td_advantages(v, r, gamma)[0].tolist() == pytest.approx(expected, rel=1e-6)


def test_return_to_go_advantages_subtract_v_from_the_scaled_return_and_ignore_its_neighbours():
    v = torch.tensor([[0.2, 0.5, 0.1]])
    r = torch.tensor([[0.0, 1.0, 2.0]])
    gamma = 0.5  # G = [0 + 0.5 + 0.5, 1 + 1, 2] = [1, 2, 2]; (1 − γ) G − V̂
    expected = [0.5 * 1 - 0.2, 0.5 * 2 - 0.5, 0.5 * 2 - 0.1]
    assert return_to_go_advantages(v, r, gamma)[0].tolist() == pytest.approx(expected, rel=1e-6)
    # unlike the TD error, V̂ at the next state does not enter: a step's advantage moves only with its own V̂
    shifted = v + torch.tensor([[0.0, 3.0, 0.0]])
    assert return_to_go_advantages(shifted, r, gamma)[0, [0, 2]].tolist() == pytest.approx([0.3, 0.9], rel=1e-6)


def test_gae_spans_the_td_error_and_the_return_to_go():
    torch.manual_seed(0)
    v, r, gamma = torch.rand(3, 7), torch.rand(3, 7), 0.9
    # λ = 1 against the separately written Monte Carlo form (λ = 0 is td_advantages itself, checked by hand above)
    torch.testing.assert_close(gae_advantages(v, r, gamma, 1.0), return_to_go_advantages(v, r, gamma))
    # λ = 0.5 by hand on one row of two steps: δ = [(1 − γ) r_0 + γ V_1 − V_0, (1 − γ) r_1 − V_1]
    v, r = torch.tensor([[0.2, 0.5]]), torch.tensor([[1.0, 2.0]])
    deltas = [0.1 * 1.0 + 0.9 * 0.5 - 0.2, 0.1 * 2.0 - 0.5]
    expected = [deltas[0] + 0.45 * deltas[1], deltas[1]]
    assert gae_advantages(v, r, gamma, 0.5)[0].tolist() == pytest.approx(expected, rel=1e-6)


# ---- modules -------------------------------------------------------------------------------------



@pytest.fixture(scope="module")
def reward_gen_ckpt(tprl, tmp_path_factory) -> pathlib.Path:
    torch.manual_seed(0)
    trainer = L.Trainer(max_steps=2, limit_val_batches=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(RewardGenModule(**ENV, **SIZES), datamodule=tprl)
    path = tmp_path_factory.mktemp("rg") / "reward_gen.ckpt"
    trainer.save_checkpoint(path)
    return path


def _step_and_compare(model, batch) -> dict[str, bool]:
    before = {k: v.clone() for k, v in model.named_parameters()}
    opt = model.configure_optimizers()
    model.loss(batch)[0].backward()
    opt.step()
    return {k: not torch.equal(v, before[k]) for k, v in model.named_parameters()}


@pytest.mark.parametrize("pair_source", ["other_pair", "context"])
def test_reward_gen_updates_every_parameter(tprl, pair_source):
    torch.manual_seed(0)
    moved = _step_and_compare(RewardGenModule(**ENV, **SIZES, pair_source=pair_source),
                              next(iter(tprl.train_dataloader())))
    assert all(moved.values()), [k for k, m in moved.items() if not m]


def test_dp2t_on_pairs_updates_every_parameter(tprl):
    torch.manual_seed(0)
    moved = _step_and_compare(DP2TModule(**ENV, **SIZES, context_kind="trajectory_preference"),
                              next(iter(tprl.train_dataloader())))
    assert all(moved.values()), [k for k, m in moved.items() if not m]


@pytest.mark.parametrize("value_epochs,learns", [(1, ("q_value", "v_value")), (0, ("policy",))])
def test_dit_phases_update_only_their_networks(tprl_rewards, value_epochs, learns):
    torch.manual_seed(0)
    moved = _step_and_compare(DITModule(**ENV, **SIZES, value_epochs=value_epochs),
                              next(iter(tprl_rewards.train_dataloader())))
    for name, m in moved.items():
        assert m == name.startswith(learns), name


@pytest.mark.parametrize("advantage, form", [("td", td_advantages), ("return_to_go", return_to_go_advantages)])
def test_dit_v_advantages_come_from_v_alone_and_train_only_the_policy(tprl_rewards, advantage, form):
    torch.manual_seed(0)
    model = DITModule(**ENV, **SIZES, value_epochs=0, advantage=advantage)
    batch = next(iter(tprl_rewards.train_dataloader()))
    context, scored = swap_roles(*model.labeled_trajectories(batch))
    with torch.no_grad():
        expected = form(model.v_value(context, scored.states), scored.rewards, model.hparams.gamma)
        model.q_value.apply(lambda m: [p.add_(1.0) for p in m.parameters(recurse=False)])  # Q̂ must not matter
        torch.testing.assert_close(model.advantages(context, scored), expected)
    moved = _step_and_compare(model, batch)
    for name, m in moved.items():
        assert m == name.startswith("policy"), name


def test_unexplained_variance_by_hand():
    targets = torch.tensor([0.0, 1.0, 2.0, 3.0])  # variance 1.25
    assert unexplained_variance(targets.mean().expand(4), targets).item() == pytest.approx(1.0)
    assert unexplained_variance(targets + 0.5, targets).item() == pytest.approx(0.25 / 1.25)


@pytest.mark.parametrize("value_epochs", [1, 0])
def test_dit_value_auxiliary_trains_the_policy_in_both_phases(tprl_rewards, value_epochs):
    """The auxiliary return-to-go head sits on the policy's transformer: it moves the policy in the value phase too,
    and adds 1 − R² of its prediction, times value_auxiliary, to the phase's loss."""
    torch.manual_seed(0)
    batch = next(iter(tprl_rewards.train_dataloader()))
    model = DITModule(**ENV, **SIZES, value_epochs=value_epochs, value_auxiliary=2.0)
    loss, metrics = model.loss(batch)
    plain = DITModule(**ENV, **SIZES, value_epochs=value_epochs)
    plain.load_state_dict({k: v for k, v in model.state_dict().items() if not k.startswith("policy_value_head")})
    torch.testing.assert_close(loss, plain.loss(batch)[0] + 2.0 * metrics["policy_value_loss"])
    moved = _step_and_compare(model, batch)
    learns = ("q_value", "v_value", "policy") if value_epochs else ("policy",)
    for name, m in moved.items():  # in the value phase the action head has no loss yet
        assert m == (name.startswith(learns) and not (value_epochs and name.startswith("policy.head"))), name
    assert moved["policy_value_head.weight"] and moved["policy.transformer.blocks.0.attn.qkv.weight"]


def test_dit_rejects_a_negative_value_auxiliary():
    with pytest.raises(ValueError, match="value_auxiliary"):
        DITModule(**ENV, **SIZES, value_auxiliary=-1.0)


def test_dit_context_reading_compares_the_own_context_with_another_tasks(tprl_rewards):
    torch.manual_seed(0)
    model = DITModule(**ENV, **SIZES, value_epochs=0)
    batch = next(iter(tprl_rewards.val_dataloader()))
    reading = model.context_reading(batch)
    assert set(reading) == {"value_loss_own_context", "value_loss_other_task", "log_likelihood_own_context",
                            "log_likelihood_other_task"}
    context, scored = swap_roles(*model.labeled_trajectories(batch))
    task = torch.cat([batch.task, batch.task])
    keep = torch.roll(task, 1) != task
    torch.testing.assert_close(reading["log_likelihood_own_context"],
                               model.log_likelihood(context, scored)[keep].mean())
    assert reading["log_likelihood_own_context"] != reading["log_likelihood_other_task"]
    same_task = batch._replace(task=torch.zeros_like(batch.task))
    assert model.context_reading(same_task) == {}


def test_dit_rejects_an_unknown_advantage():
    with pytest.raises(ValueError, match="advantage"):
        DITModule(**ENV, **SIZES, advantage="monte_carlo")


def test_dit_on_continuous_actions_weights_the_gaussian_mean_likelihood():
    torch.manual_seed(0)
    model = DITModule(state_dim=3, action_dim=2, discrete=False, max_context=10, value_epochs=0, **SIZES)
    batch = RewardTrajectorySamples(*(RewardTrajectoryContext(torch.rand(4, 10, 3), torch.rand(4, 10, 2) * 2 - 1,
                                                              torch.rand(4, 10)) for _ in "ab"))
    a, b = model.labeled_trajectories(batch)
    mean = model.policy(a, b.states, torch.full((10,), 10))
    torch.testing.assert_close(model.log_likelihood(a, b), -(mean - b.actions).pow(2).sum(-1))
    moved = _step_and_compare(model, batch)
    assert all(m == name.startswith("policy") for name, m in moved.items())


def test_icrg_trains_dit_on_rewardgen_labels_and_never_updates_rewardgen(tprl, reward_gen_ckpt):
    torch.manual_seed(0)
    model = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(reward_gen_ckpt), value_epochs=0)
    stage1 = RewardGenModule.load_from_checkpoint(reward_gen_ckpt, weights_only=False)
    torch.testing.assert_close(model.reward_gen.state_dict(), stage1.reward.state_dict())
    batch = next(iter(tprl.train_dataloader()))
    a, _ = model.labeled_trajectories(batch)
    assert a.rewards.shape == (8, 100) and a.rewards.std() > 0
    moved = _step_and_compare(model, batch)
    for name, m in moved.items():
        assert m == name.startswith("policy"), name


def test_icrg_refuses_a_checkpoint_that_is_not_rewardgen(tprl, tmp_path):
    path = _fit_and_save(DP2TModule(**ENV, **SIZES, context_kind="trajectory_preference"), tprl, tmp_path / "x.ckpt")
    with pytest.raises(ValueError, match="not a RewardGen checkpoint"):
        ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(path))
    with pytest.raises(ValueError, match="needs reward_gen_checkpoint"):
        ICRGModule(**ENV, **SIZES)


def test_rewardgen_queries_do_not_interact(tprl):
    """Scoring all 2H transitions in one pass equals scoring each alone after the context (the last position)."""
    torch.manual_seed(0)
    model = RewardGenModule(**ENV, **SIZES).eval()
    batch = next(iter(tprl.train_dataloader()))
    ctx = batch.context.map(lambda x: x[:2])
    states, actions = ctx.states_b[:, :6], ctx.actions_b[:, :6]
    together = model(ctx, states, actions)
    alone = torch.cat([model(ctx, states[:, i:i + 1], actions[:, i:i + 1]) for i in range(6)], dim=1)
    torch.testing.assert_close(together, alone)


# ---- deployment ------------------------------------------------------------------------------------

def _fit_and_save(model, dm, path) -> pathlib.Path:
    trainer = L.Trainer(max_steps=1, limit_val_batches=1, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    trainer.save_checkpoint(path)
    return path


def test_icrg_checkpoint_deploys_alone_and_labels_the_behavior_trajectory(tprl, reward_gen_ckpt, tmp_path):
    torch.manual_seed(0)
    model = ICRGModule(**ENV, **SIZES, reward_gen_checkpoint=str(reward_gen_ckpt))
    path = _fit_and_save(model, tprl, tmp_path / "icrg.ckpt")
    moved_away = tmp_path / "gone.ckpt"
    reward_gen_ckpt.rename(moved_away)  # the ICRG checkpoint must not need stage 1's file
    try:
        agent = load_agent(path, greedy=True)
        uncached = load_agent(path, greedy=True, use_cache=False)
    finally:
        moved_away.rename(reward_gen_ckpt)
    assert isinstance(agent, ICRGAgent)
    assert agent.policy_agent.greedy
    assert not load_agent(path).policy_agent.greedy  # ICRG's own default: sample from T^R
    ctx = next(s for s in tprl.held_out("rollouts") if s.quality == "low").context
    agent.reset(ctx)
    uncached.reset(ctx)
    expected = (model.reward_gen(ctx, ctx.behavior_states, ctx.behavior_actions) - model.reward_gen.reward_mean) \
        / model.reward_gen.reward_std
    torch.testing.assert_close(agent.labeled_context.rewards, expected)
    obs = ctx.behavior_states[:, 0]
    for _ in range(3):
        action = agent.act(obs)
        assert action.shape == (ctx.batch_size,) and action.dtype == torch.int64
        assert torch.equal(action, uncached.act(obs))
        obs = torch.rand_like(obs) * 9
    with pytest.raises(ValueError, match="behavior trajectory"):
        agent.reset(TrajectoryPreferenceContext(ctx.states_a, ctx.actions_a, ctx.states_b, ctx.actions_b,
                                                ctx.preferred))
    with pytest.raises(ValueError, match="takes a TrajectoryPreferenceContext"):
        agent.reset(agent.labeled_context)


def test_dp2t_and_dit_checkpoints_deploy_on_their_contexts(tprl, tprl_rewards, tmp_path):
    for model, dm in ((DP2TModule(**ENV, **SIZES, context_kind="trajectory_preference"), tprl),
                      (DITModule(**ENV, **SIZES, value_epochs=0), tprl_rewards),
                      (DITModule(**ENV, **SIZES, value_epochs=0, value_auxiliary=1.0), tprl_rewards)):
        agent = load_agent(_fit_and_save(model, dm, tmp_path / "m.ckpt"), seed=0)
        # each method's own default: DP²T acts by its argmax, DIT samples from T^R (the paper's deployment)
        assert agent.greedy == isinstance(model, DP2TModule)
        ctx = dm.held_out("rollouts")[2].context
        agent.reset(ctx)
        assert agent.act(ctx.states[:, 0]).shape == (ctx.batch_size,)


def test_rewardgen_checkpoint_is_not_an_agent(reward_gen_ckpt):
    with pytest.raises(TypeError, match="deploy that checkpoint"):
        load_agent(reward_gen_ckpt)


# ---- configs -----------------------------------------------------------------------------------------

def _tiny_cli(config: str, root, *extra: str):
    args = ["fit", "--config", str(REPO / config), "--trainer.fast_dev_run", "1", "--trainer.logger", "false",
            "--data.init_args.root_dir", str(root), "--data.init_args.progress", "false",
            *cli_data_args("darkroom", **{k: v for k, v in TPRL_TINY.items() if k not in ("progress", "batch_size")}),
            *(x for k, v in SIZES["backbone"].as_dict().items() for x in (f"--model.init_args.backbone.{k}", str(v))),
            *extra]
    return run_cli(args)


@pytest.mark.parametrize("config", ["configs/dp2t_darkroom_tprl.yaml", "configs/reward_gen_darkroom.yaml",
                                    "configs/dit_darkroom.yaml"])
def test_config_runs_under_fast_dev_run(config, data_root, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli = _tiny_cli(config, data_root)
    assert cli.trainer.state.finished
    assert cli.model.hparams.max_context == cli.datamodule.context_length
    if "reward_gen" in config:
        assert 0.0 <= cli.trainer.callback_metrics["val/darkroom/heldout_pair_accuracy"] <= 1.0


def test_icrg_config_runs_under_fast_dev_run(data_root, reward_gen_ckpt, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli = _tiny_cli("configs/icrg_darkroom.yaml", data_root, "--model.init_args.reward_gen_checkpoint",
                    str(reward_gen_ckpt))
    assert cli.trainer.state.finished
    assert cli.model.hparams.reward_gen_hparams["backbone"] == SIZES["backbone"].as_dict()  # stage 1's, from its file


def test_paper_configs_have_the_paper_architecture():
    import yaml

    for name in ("dp2t", "reward_gen", "icrg", "dit"):
        cfg = yaml.safe_load((REPO / f"configs/paper/{name}_darkroom_tprl.yaml").read_text())
        args = cfg["model"]["init_args"]
        assert args["backbone"] == {"n_layer": 4, "n_embd": 32, "n_head": 4}, name
        assert cfg["data"]["init_args"]["setting"]["init_args"]["trajectories_per_task"] == 5000
        assert args["optimizer"] == {"lr": 3e-4}


# ---- learning ----------------------------------------------------------------------------------------

@pytest.mark.slow
def test_rewardgen_beats_chance_on_heldout_pairs(tmp_path):
    """A few hundred steps suffice for R_ψ to order unseen goals' pairs better than a coin (chance 0.5)."""
    from icprl_lightning.callbacks.pair_accuracy import HeldOutPairAccuracyCallback

    L.seed_everything(0)
    dm = darkroom_data("trajectory_preference", root_dir=str(tmp_path), trajectories_per_task=30,
                       val_trajectories_per_task=2, eval_contexts_per_task=4, calibration_episodes=5, progress=False,
                       batch_size=32, pairs=True)
    callback = HeldOutPairAccuracyCallback()
    trainer = L.Trainer(max_epochs=3, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, callbacks=[callback], num_sanity_val_steps=0)
    model = RewardGenModule(**ENV, backbone=TransformerConfig(n_layer=2, n_embd=32, n_head=4),
                            optimizer={"lr": 1e-3})
    trainer.fit(model, datamodule=dm)
    accuracy = callback.last_results["val/darkroom/heldout_pair_accuracy"]
    assert accuracy > 0.65, callback.last_results  # 240 held-out pairs: chance ± 4 sd is 0.5 ± 0.13
