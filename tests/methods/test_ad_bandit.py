"""Algorithm Distillation on dueling bandits: DTS's learning histories (duels and outcomes only), their windows, the
next-duel loss, the DuelHistoryAgent's KV-cached online play, the online evaluation's AD row, load_agent and
``icprl fit`` (docs/ad_bandit.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from factories import REPO, save_untrained

from icprl_lightning import load_agent
from icprl_lightning.commands import run_cli
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.duel_histories import DuelHistoryDataModule
from icprl_lightning.data.settings import BanditDuels
from icprl_lightning.evaluation.online_bandit import evaluate_online_bandit
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.learning_histories import HISTORY_FIELDS, DTSHistories
from icprl_lightning.methods.ad import ADModule, DuelHistoryAgent, HistoryAgent, pair_index
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_pairing

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = dict(backbone={"n_layer": 1, "n_embd": 16, "n_head": 2})
FAMILY = LinearDuelingBanditFamily(horizon=30)
N_ARMS = FAMILY.n_arms


def _model(max_context: int = 31, seed: int = 0) -> ADModule:
    torch.manual_seed(seed)
    return ADModule(state_dim=0, action_dim=N_ARMS, discrete=True, max_context=max_context,
                    context_kind="step_preference", **TINY).eval()


def _data(tmp_path, **kw) -> DuelHistoryDataModule:
    return DuelHistoryDataModule(FAMILY, DTSHistories(rounds=31), **{
        "n_train_problems": 30, "n_val_problems": 6, "n_eval_problems": 5, "windows_per_epoch": 16,
        "batch_size": 8, "root_dir": str(tmp_path), "progress": False, **kw})


def _gaps(theta: np.ndarray) -> np.ndarray:
    rewards = FAMILY.expected_rewards(theta)
    return rewards.max(1, keepdims=True) - rewards


# ---- the histories ----------------------------------------------------------------------------------------
def test_histories_hold_duels_and_outcomes_only(tmp_path):
    theta = FAMILY.sample_tasks(7, np.random.default_rng(0))
    out = DTSHistories(rounds=12).run(FAMILY, theta, np.random.default_rng(1))
    assert set(out) == set(HISTORY_FIELDS) == {"arms_first", "arms_second", "preferred"}
    assert out["arms_first"].shape == out["arms_second"].shape == out["preferred"].shape == (7, 12)
    assert set(np.unique(out["preferred"])) <= {0, 1}
    again = DTSHistories(rounds=12).run(FAMILY, theta, np.random.default_rng(1))
    assert all(np.array_equal(out[k], again[k]) for k in out)
    dm = _data(tmp_path)
    dm.prepare_data()
    data = dm.load()
    for split in ("train", "val"):  # what a batch can read: duels, outcomes and the row's problem index
        assert set(data[split]) == {"arms_first", "arms_second", "preferred", "task_index"}, split
    assert not any(word in k for k in dm.batch_fields() for word in ("reward", "utilit", "theta", "advantage"))


def test_dts_regret_falls_over_its_history_on_average():
    family = LinearDuelingBanditFamily()
    theta = family.sample_tasks(300, np.random.default_rng(0))
    out = DTSHistories(rounds=200).run(family, theta, np.random.default_rng(1))
    rewards = family.expected_rewards(theta)
    gaps = rewards.max(1, keepdims=True) - rewards
    first, second = (np.take_along_axis(gaps, out[k], 1) for k in ("arms_first", "arms_second"))
    weak, strong = np.minimum(first, second).mean(0), ((first + second) / 2).mean(0)
    for curve in (weak, strong):
        assert curve[-20:].mean() < 0.8 * curve[:20].mean(), (curve[:20].mean(), curve[-20:].mean())
        assert np.corrcoef(np.arange(200), curve)[0, 1] < -0.5  # a fall over the whole history, not a jump


def test_the_manifest_reports_dts_learning_and_the_problems_are_icpos(tmp_path):
    dm = _data(tmp_path, n_train_problems=60, n_eval_problems=4)
    dm.prepare_data()
    info = json.loads((dm.path / "manifest.json").read_text())["info"]["dts_regret"]["train"]
    assert set(info) == {f"{w}_20_rounds_{r}_regret" for w in ("first", "last") for r in ("weak", "strong")}
    bandit = PreferenceDataModule(FAMILY, BanditDuels(n_train_problems=2, n_val_problems=2, n_eval_problems=4,
                                                      eval_sources=("uniform",)), root_dir=str(tmp_path / "b"),
                                  progress=False)
    bandit.prepare_data()
    np.testing.assert_array_equal(dm.load()["tasks"]["test_theta"], bandit.load()["tasks"]["test_theta"])
    np.testing.assert_array_equal(dm.load()["tasks"]["train_theta"][:2], bandit.load()["tasks"]["train_theta"])
    assert not np.isin(dm.load()["tasks"]["test_theta"], dm.load()["tasks"]["train_theta"]).any()


# ---- the data ---------------------------------------------------------------------------------------------
def test_windows_are_whole_histories_by_default_and_consecutive_rounds_otherwise(tmp_path):
    dm = _data(tmp_path)
    dm.prepare_data()
    assert dm.context_length == 31 and dm.context_kind == "step_preference" and dm.state_dim == 0
    train = dm.load()["train"]
    torch.manual_seed(0)
    batch = next(iter(dm.train_dataloader()))
    c = batch.context
    assert isinstance(c, StepPreferenceContext)
    assert c.states.shape == (8, 31, 0) and c.actions.shape == c.alt_actions.shape == c.preferred.shape == (8, 31)
    assert c.actions.dtype == torch.int64 and c.preferred.dtype == torch.float32
    for i in range(8):
        row = int(batch.task[i])
        np.testing.assert_array_equal(train["arms_first"][row], c.actions[i].numpy())
        np.testing.assert_array_equal(train["arms_second"][row], c.alt_actions[i].numpy())
        np.testing.assert_array_equal(train["preferred"][row], c.preferred[i].numpy())
    val = list(dm.val_dataloader())
    assert sum(b.batch_size for b in val) == 6  # one whole-history window per val history
    short = _data(tmp_path, window=10, val_windows_per_history=3)
    assert short.path == dm.path  # the window is how the data are served, not what is stored
    torch.manual_seed(1)
    batch = next(iter(short.train_dataloader()))
    assert batch.context.actions.shape == (8, 10)
    for i in range(8):
        row = int(batch.task[i])
        hits = [s for s in range(22) if np.array_equal(train["arms_first"][row, s:s + 10], batch.context.actions[i])
                and np.array_equal(train["arms_second"][row, s:s + 10], batch.context.alt_actions[i])]
        assert hits, i
    assert sum(b.batch_size for b in short.val_dataloader()) == 6 * 3


def test_bad_knobs_and_pairings_are_refused(tmp_path):
    with pytest.raises(HyperparameterError, match="window"):
        _data(tmp_path, window=32)
    with pytest.raises(HyperparameterError, match="rounds"):
        DTSHistories(rounds=0)
    with pytest.raises(HyperparameterError, match="context_kind"):
        ADModule(state_dim=0, action_dim=4, discrete=True, max_context=5, context_kind="reward", **TINY)
    with pytest.raises(HyperparameterError, match="continuous"):
        ADModule(state_dim=0, action_dim=4, discrete=False, max_context=5, context_kind="step_preference", **TINY)
    dm = _data(tmp_path)
    check_pairing(_model(), dm)
    with pytest.raises(HyperparameterError, match="reward_trajectory"):  # DarkRoom's AD on duels
        check_pairing(ADModule(state_dim=0, action_dim=N_ARMS, discrete=True, max_context=31, **TINY), dm)
    with pytest.raises(HyperparameterError, match="pairs"):  # ICPO needs another context of the same problem
        check_pairing(ICPOModule(state_dim=0, action_dim=N_ARMS, discrete=True, max_context=31, **TINY), dm)


# ---- the method -------------------------------------------------------------------------------------------
def _duels(b: int = 3, t: int = 9, seed: int = 0) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(seed)
    return StepPreferenceContext(torch.zeros(b, t, 0), torch.randint(0, N_ARMS, (b, t), generator=g),
                                 torch.randint(0, N_ARMS, (b, t), generator=g),
                                 torch.randint(0, 2, (b, t), generator=g).float())


def test_the_loss_is_the_cross_entropy_of_the_next_duel_and_sees_only_earlier_duels():
    model = _model()
    context = _duels()
    outputs = model.policy.next_step_outputs(context)
    assert outputs.shape == (3, 9, N_ARMS * N_ARMS)
    targets = context.actions * N_ARMS + context.alt_actions
    expected = -outputs.log_softmax(-1).gather(-1, targets[..., None]).mean()
    loss, metrics = model.loss(ContextSamples(context))
    torch.testing.assert_close(loss, expected)
    assert set(metrics) == {"pair_accuracy", "first_arm_accuracy"}
    assert torch.equal(pair_index(context.actions, context.alt_actions, N_ARMS), targets)
    changed = _duels()
    changed.actions[:, 5:] = (changed.actions[:, 5:] + 1) % N_ARMS  # duels 6.. differ
    again = model.policy.next_step_outputs(changed)
    torch.testing.assert_close(again[:, :6], outputs[:, :6])  # prediction of duel h reads duels 1..h-1 only
    assert not torch.allclose(again[:, 6:], outputs[:, 6:])


def test_the_agent_plays_online_with_its_cache_equal_to_re_encoding():
    model = _model()
    cached, slow = DuelHistoryAgent(model.policy, seed=0), DuelHistoryAgent(model.policy, use_cache=False, seed=0)
    obs = torch.zeros(4, 0)
    context = _duels(4, 12, seed=3)
    for agent in (cached, slow):
        agent.reset(4)
    for h in range(12):
        torch.testing.assert_close(cached.outputs(obs), slow.outputs(obs), rtol=1e-5, atol=1e-5)
        first, second = cached.propose(obs)
        assert first.shape == second.shape == (4,) and first.max() < N_ARMS and second.max() < N_ARMS
        step = [x[:, h] for x in (context.actions, context.alt_actions, context.preferred)]
        cached.observe(obs, *step)
        slow.observe(obs, *step)
    assert cached.length == 12
    # the outputs after the duels are those of the training pass at the next position
    full = _duels(4, 13, seed=3)
    full.actions[:, :12], full.alt_actions[:, :12], full.preferred[:, :12] = (
        context.actions, context.alt_actions, context.preferred)
    torch.testing.assert_close(cached.outputs(obs), model.policy.next_step_outputs(full)[:, 12], rtol=1e-5,
                               atol=1e-5)
    greedy = DuelHistoryAgent(model.policy, greedy=True)
    greedy.reset(4)
    logits = greedy.outputs(obs)
    first, second = greedy.propose(obs)
    assert torch.equal(first * N_ARMS + second, logits.argmax(-1))
    assert torch.equal(greedy.act(obs), logits.unflatten(-1, (N_ARMS, N_ARMS)).logsumexp(-1).argmax(-1))
    with pytest.raises(ValueError, match="DistilledPair"):
        greedy.pair_rule = "top_two"
    with pytest.raises(ValueError, match="AD on duels"):
        DuelHistoryAgent(ADModule(state_dim=0, action_dim=N_ARMS, discrete=True, max_context=5, **TINY).policy)


def test_load_agent_gives_each_ad_its_agent(tmp_path):
    duels = load_agent(save_untrained(_model(), tmp_path / "duels.ckpt"))
    assert isinstance(duels, DuelHistoryAgent) and duels.greedy is False and duels.max_context == 31
    steps = ADModule(state_dim=2, action_dim=5, discrete=True, max_context=20, **TINY)
    assert isinstance(load_agent(save_untrained(steps, tmp_path / "steps.ckpt")), HistoryAgent)


def test_an_untrained_ad_plays_online_beside_dts(tmp_path):
    dm = _data(tmp_path)
    dm.prepare_data()
    ckpt = str(save_untrained(_model(), tmp_path / "ad.ckpt"))
    out = evaluate_online_bandit(dm, [], seeds=(0, 1), rounds=30, n_problems=4, ad_checkpoints=[ckpt])
    assert out["icpo"] == {} and out["ad"]["checkpoints"] == [ckpt]
    row = out["ad"]["mean"]
    assert len(row["recommendation_curve"]) == 30 and row["cumulative_weak_regret_sem"] is None
    assert 0 < row["cumulative_weak_regret"] <= row["cumulative_strong_regret"]
    assert set(out) >= {"ad", "dts", "maxinp", "bt_thompson"}
    again = evaluate_online_bandit(dm, [], seeds=(0, 1), rounds=30, n_problems=4, ad_checkpoints=[ckpt])
    assert again["ad"]["mean"]["cumulative_weak_regret"] == row["cumulative_weak_regret"]  # seeded
    with pytest.raises(ValueError, match=r"--rounds must be in \[1, 30\]"):
        evaluate_online_bandit(dm, [], rounds=31, ad_checkpoints=[ckpt])
    darkroom = save_untrained(ADModule(state_dim=2, action_dim=5, discrete=True, max_context=20, **TINY),
                              tmp_path / "steps.ckpt")
    with pytest.raises(ValueError, match="not AD on duels"):
        evaluate_online_bandit(dm, [], rounds=10, ad_checkpoints=[str(darkroom)])


@pytest.mark.slow
def test_icprl_fit_trains_ad_on_duels(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli = run_cli(["fit", "--config", str(REPO / "configs/ad_bandit.yaml"), "--trainer.max_epochs", "1",
                   "--trainer.limit_train_batches", "4", "--trainer.limit_val_batches", "1",
                   "--data.init_args.n_train_problems", "40", "--data.init_args.n_val_problems", "8",
                   "--trainer.default_root_dir", str(tmp_path)])
    assert isinstance(cli.model, ADModule) and cli.model.duels and cli.model.policy.transformer.max_context == 201
    assert "val/loss" in cli.trainer.callback_metrics
