"""Algorithm Distillation on DarkRoom: the Q-learner's histories, their windows, the AD loss, the HistoryAgent's
growing KV-cached context across episodes, the learning curve, load_agent and ``icprl fit``."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from factories import REPO, save_untrained

from icprl_lightning import load_agent
from icprl_lightning.commands import run_cli
from icprl_lightning.contexts import RewardTrajectoryContext
from icprl_lightning.data.learning_histories import LearningHistoryDataModule
from icprl_lightning.data.settings import RewardTrajectories
from icprl_lightning.evaluation.ad_rollout import ad_learning_curve, source_learning_curve
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import step_reward, transition
from icprl_lightning.families.darkroom.learning_histories import QLearningHistories
from icprl_lightning.methods.ad import ADModule, HistoryAgent
from icprl_lightning.methods.dpt import DPTModule
from icprl_lightning.registry import BUILTIN_METHODS
from icprl_lightning.validation import HyperparameterError, check_pairing

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = dict(backbone={"n_layer": 1, "n_embd": 16, "n_head": 2})
SHORT = DarkRoomFamily(horizon=10)  # 10-step episodes: several fit in a small window


def _model(max_context: int = 30, seed: int = 0) -> ADModule:
    torch.manual_seed(seed)
    return ADModule(state_dim=2, action_dim=5, discrete=True, max_context=max_context, **TINY).eval()


def _data(tmp_path, **kw) -> LearningHistoryDataModule:
    learner = QLearningHistories(episodes=6, epsilon_decay_episodes=3)
    return LearningHistoryDataModule(SHORT, learner, **{"context_episodes": 2, "windows_per_epoch": 32,
                                                        "batch_size": 8, "root_dir": str(tmp_path), **kw})


# ---- the learner ------------------------------------------------------------------------------------------
def test_the_learners_return_rises_over_its_history_on_average():
    family = DarkRoomFamily()
    returns = QLearningHistories().run(family, family.train_goals, np.random.default_rng(0))["episode_returns"]
    curve = returns.mean(0)  # mean over the 80 goals, per episode
    assert curve[:5].mean() < 5 and curve[-10:].mean() > 60, curve.round(1)
    assert np.corrcoef(np.arange(len(curve)), curve)[0, 1] > 0.9  # a rise over the whole history, not a jump


def test_the_history_is_the_learners_own_trajectory_and_seeded():
    learner = QLearningHistories(episodes=3, epsilon_decay_episodes=2)
    goals = SHORT.train_goals[:7]
    out = learner.run(SHORT, goals, np.random.default_rng(1))
    again = learner.run(SHORT, goals, np.random.default_rng(1))
    assert all(np.array_equal(out[k], again[k]) for k in out)
    assert out["states"].shape == (7, 30, 2) and out["actions"].shape == out["rewards"].shape == (7, 30)
    cells = out["states"].astype(np.int64)
    nxt = transition(cells, out["actions"], SHORT.size)
    np.testing.assert_array_equal(out["rewards"], step_reward(nxt, goals[:, None]))
    within = np.arange(30) % 10 != 9  # inside an episode the next state follows the action; episodes restart
    np.testing.assert_array_equal(cells[:, 1:][:, within[:-1]], nxt[:, :-1][:, within[:-1]])
    np.testing.assert_array_equal(out["episode_returns"], out["rewards"].reshape(7, 3, 10).sum(-1))


def test_the_learner_refuses_bad_knobs_and_terminating_episodes():
    with pytest.raises(HyperparameterError, match="epsilon_end"):
        QLearningHistories(epsilon_end=1.5)
    with pytest.raises(HyperparameterError, match="terminate_on_goal"):
        QLearningHistories().run(DarkRoomFamily(terminate_on_goal=True), SHORT.train_goals[:2],
                                 np.random.default_rng(0))


# ---- the data ---------------------------------------------------------------------------------------------
def test_windows_are_consecutive_steps_of_one_history(tmp_path):
    dm = _data(tmp_path)
    dm.prepare_data()
    assert dm.context_length == 20 and dm.context_kind == "reward_trajectory"
    train = dm.load()["train"]
    assert train["actions"].shape == (2 * 80, 60)  # 2 histories per training goal, 6 episodes of 10 steps
    torch.manual_seed(0)
    batch = next(iter(dm.train_dataloader()))
    assert isinstance(batch.context, RewardTrajectoryContext) and batch.context.states.shape == (8, 20, 2)
    for i in range(8):  # each window is found, whole, in a history of its own task's rows
        rows = np.arange(2) + 2 * int(batch.task[i])
        hits = [(r, s) for r in rows for s in range(41)
                if np.array_equal(train["actions"][r, s:s + 20], batch.context.actions[i].numpy())
                and np.array_equal(train["states"][r, s:s + 20], batch.context.states[i].numpy())]
        assert hits, i
    val = list(dm.val_dataloader())
    assert sum(b.batch_size for b in val) == 80 * 4  # 1 val history per goal, 4 fixed windows each
    assert torch.equal(val[0].context.actions, next(iter(dm.val_dataloader())).context.actions)


def test_the_dataset_is_deterministic_and_checked_against_its_config(tmp_path):
    a, b = _data(tmp_path / "a"), _data(tmp_path / "b")
    a.prepare_data(), b.prepare_data()
    assert a.path.name == b.path.name
    assert all(np.array_equal(a.load()["train"][k], b.load()["train"][k]) for k in ("states", "actions", "rewards"))
    other = _data(tmp_path / "a", data_dir=str(a.path), histories_per_goal=3)
    with pytest.raises(Exception, match="histories_per_goal"):
        other.prepare_data()


def test_pairing_refuses_ad_on_two_trajectory_rows_and_dpt_on_histories(tmp_path):
    from icprl_lightning.data import PreferenceDataModule

    with pytest.raises(HyperparameterError, match="states"):
        check_pairing(_model(), PreferenceDataModule(SHORT, RewardTrajectories(), root_dir=str(tmp_path)))
    with pytest.raises(HyperparameterError, match="DPTModule"):
        check_pairing(DPTModule(state_dim=2, action_dim=5, discrete=True, max_context=20, **TINY), _data(tmp_path))
    check_pairing(_model(20), _data(tmp_path))


# ---- the method -------------------------------------------------------------------------------------------
def test_each_prediction_sees_only_the_steps_before_it():
    model = _model()
    g = torch.Generator().manual_seed(0)
    context = RewardTrajectoryContext(torch.randint(0, 10, (2, 12, 2), generator=g).float(),
                                      torch.randint(0, 5, (2, 12), generator=g), torch.rand(2, 12, generator=g))
    before = model.policy.next_step_outputs(context)
    k = 6  # change step k's action and reward: outputs 0..k (which predict actions 0..k) must not move
    changed = RewardTrajectoryContext(context.states, context.actions.clone(), context.rewards.clone())
    changed.actions[:, k] = (changed.actions[:, k] + 1) % 5
    changed.rewards[:, k] += 1.0
    after = model.policy.next_step_outputs(changed)
    torch.testing.assert_close(after[:, :k + 1], before[:, :k + 1])
    assert not torch.allclose(after[:, k + 1:], before[:, k + 1:])


def test_the_loss_decreases_on_a_tiny_history(tmp_path):
    dm = _data(tmp_path)
    dm.prepare_data()
    torch.manual_seed(0)
    model = ADModule(state_dim=2, action_dim=5, discrete=True, max_context=dm.context_length, optimizer={"lr": 3e-3},
                     **TINY)
    batch = next(iter(dm.train_dataloader()))
    opt = model.configure_optimizers()
    first = model.loss(batch)[0].item()
    for _ in range(40):
        opt.zero_grad()
        loss, metrics = model.loss(batch)
        loss.backward()
        opt.step()
    assert loss.item() < 0.8 * first, (first, loss.item())
    assert 0.0 <= metrics["action_accuracy"].item() <= 1.0


# ---- deployment -------------------------------------------------------------------------------------------
def _walk(agents: list[HistoryAgent], steps: int, seed: int = 0) -> list[list[torch.Tensor]]:
    """Drive the agents through the same steps (the first agent's greedy actions); each one's logits per step."""
    g = torch.Generator().manual_seed(seed)
    for agent in agents:
        agent.reset(3)
    logits = [[] for _ in agents]
    for _ in range(steps):
        obs = torch.randint(0, 10, (3, 2), generator=g).float()
        for out, agent in zip(logits, agents, strict=True):
            out.append(agent.outputs(obs))
        action, reward = logits[0][-1].argmax(-1), torch.rand(3, generator=g)
        for agent in agents:
            agent.observe(obs, action, reward)
    return logits


def test_the_context_grows_across_episodes_and_cached_outputs_equal_uncached():
    model = _model(max_context=30)
    cached, uncached = model.make_agent(greedy=True), model.make_agent(greedy=True, use_cache=False)
    logits = _walk([cached, uncached], steps=25)  # 2.5 episodes of 10 steps, within the window of 29
    assert cached.length == uncached.length == 25 and cached.cache.length == 25
    for a, b in zip(*logits, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
        assert torch.equal(a.argmax(-1), b.argmax(-1))


@pytest.mark.parametrize("slide", [1, 10])
def test_a_full_window_slides_and_stays_equal_to_the_uncached_agent(slide):
    model = _model(max_context=30)
    cached = model.make_agent(greedy=True, slide=slide)
    uncached = model.make_agent(greedy=True, use_cache=False, slide=slide)
    logits = _walk([cached, uncached], steps=45)
    assert cached.length == uncached.length <= cached.window == 29
    for a, b in zip(*logits, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_the_agent_refuses_what_it_cannot_take():
    with pytest.raises(ValueError, match="reward_trajectory"):
        HistoryAgent(DPTModule(state_dim=2, action_dim=5, discrete=True, max_context=5, **TINY).policy)
    agent = _model().make_agent()
    with pytest.raises(RuntimeError, match="reset"):
        agent.act(torch.zeros(2, 2))
    agent.reset(2)
    with pytest.raises(ValueError, match="actions"):
        agent.observe(torch.zeros(2, 2), torch.tensor([0, 7]), torch.zeros(2))
    with pytest.raises(HyperparameterError, match="slide"):
        agent.slide = 30  # more than the window of 29 steps
    with pytest.raises(ValueError, match="window"):
        agent.reset(RewardTrajectoryContext(torch.zeros(1, 30, 2), torch.zeros(1, 30, dtype=torch.long),
                                            torch.zeros(1, 30)))


def test_the_learning_curve_has_one_return_per_goal_and_episode():
    model = _model(max_context=50)
    goals = SHORT.test_goals[:4]
    agent = model.make_agent(seed=0)
    curve = ad_learning_curve(agent, SHORT, goals, episodes=4, seed=0)
    assert agent.length == 4 * SHORT.horizon  # one history across the 4 episodes, never reset between them
    again = ad_learning_curve(model.make_agent(seed=0), SHORT, goals, episodes=4, seed=0)
    assert curve.shape == (4, 4) and np.array_equal(curve, again)
    assert ((curve >= 0) & (curve <= SHORT.horizon)).all()
    source = source_learning_curve(QLearningHistories(episodes=4, epsilon_decay_episodes=2), SHORT, goals)
    assert source.shape == (4, 4)


def test_a_checkpoint_loads_as_a_history_agent(tmp_path):
    assert "icprl_lightning.methods.ad.ADModule" in BUILTIN_METHODS
    model = _model()
    agent = load_agent(save_untrained(model, tmp_path / "ad.ckpt"), seed=0)
    assert isinstance(agent, HistoryAgent) and not agent.greedy and agent.context_kind == "reward_trajectory"
    agent.reset(2)
    agent.observe(torch.zeros(2, 2), agent.act(torch.zeros(2, 2)), torch.zeros(2))
    assert agent.length == 1


def test_icprl_fit_runs_the_config_under_fast_dev_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli = run_cli(["fit", "--config", str(REPO / "configs/ad_darkroom.yaml"), "--trainer.fast_dev_run", "1",
                   "--trainer.logger", "false", "--data.init_args.root_dir", str(tmp_path),
                   "--data.init_args.learner.init_args.episodes", "3",
                   "--data.init_args.learner.init_args.epsilon_decay_episodes", "2",
                   "--data.init_args.histories_per_goal", "1", "--model.init_args.backbone",
                   "{n_layer: 1, n_embd: 16, n_head: 2}"])
    assert cli.trainer.state.finished
    assert cli.model.hparams.max_context == cli.datamodule.context_length == 200
