"""Online deployment (``icprl evaluate online``: ``evaluation/online_mdp.py``, ``online_bandit.py``,
``online_command.py``): the annotator answers the agent's own pairs at its own states, the label diagnostics
invert or randomize what the agent sees, and the command runs end to end on tiny untrained checkpoints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from factories import save_untrained

from icprl_lightning.annotators import BradleyTerryAnnotator
from icprl_lightning.commands import main
from icprl_lightning.contexts import ActionSpec
from icprl_lightning.evaluation import online_bandit, online_mdp
from icprl_lightning.evaluation.online_command import evaluate_online
from icprl_lightning.families.darkroom.oracle import optimal_advantage
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.online import OnlineAgent


def test_query_steps_spread_over_the_horizon():
    assert online_mdp.query_steps(100, 20).tolist() == list(range(0, 100, 5))
    assert online_mdp.query_steps(100, 100).tolist() == list(range(100))
    assert online_mdp.query_steps(100, 0).tolist() == []
    assert len(online_mdp.query_steps(100, 33)) == 33
    with pytest.raises(ValueError, match="queries per episode"):
        online_mdp.query_steps(10, 11)


def _agent(max_context: int = 100, seed: int = 0) -> OnlineAgent:
    torch.manual_seed(seed)
    policy = InContextPolicy("step_preference", 2, ActionSpec(discrete=True, size=5),
                             backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2), max_context=max_context).eval()
    return OnlineAgent(policy, seed=seed)


@pytest.mark.parametrize("labels", ["own", "flipped", "random"])
def test_online_episodes_ask_the_oracle_at_the_agents_own_states(tiny_ipref, labels):
    suite = tiny_ipref.held_out("rollouts")[0]
    agent = _agent()
    # a near-deterministic teacher, so that the stored label is the sign of A*(s, a) − A*(s, a')
    result = online_mdp.online_episodes(agent, tiny_ipref.family, suite, BradleyTerryAnnotator(0.01), episodes=2,
                                        seed=0, labels=labels)
    assert result["return"].shape == (3, len(suite.task_index))
    assert result["context_length"].tolist() == [50, 100, 100]  # the third episode asks nothing
    ctx = agent.context
    steps = online_mdp.query_steps(suite.horizon, 50)
    goals = suite.make_env().goals
    a_star = [optimal_advantage(ctx.states[:, i].numpy().astype(np.int64), ctx.actions[:, i].numpy(), goals,
                                suite.horizon - steps[i % 50], tiny_ipref.family)
              - optimal_advantage(ctx.states[:, i].numpy().astype(np.int64), ctx.alt_actions[:, i].numpy(), goals,
                                  suite.horizon - steps[i % 50], tiny_ipref.family) for i in range(100)]
    diff = np.stack(a_star, 1)
    decided = np.abs(diff) > 0.1
    agree = float(((diff > 0) == (ctx.preferred.numpy() == 1))[decided].mean())
    expected = {"own": (0.99, 1.0), "flipped": (0.0, 0.01), "random": (0.4, 0.6)}[labels]
    assert expected[0] <= agree <= expected[1], agree
    # the context holds the states the agent visited, not states drawn elsewhere: queries 2 steps apart within an
    # episode lie at most 2 moves apart (one cell per step)
    moves = (ctx.states[:, 1:] - ctx.states[:, :-1]).abs().sum(-1)  # [B, 99]
    within = torch.ones(99, dtype=torch.bool)
    within[49] = False  # query 49 -> 50 crosses into the next episode (a new start cell)
    assert int(moves[:, within].max()) <= 2 and int(moves[:, within].max()) >= 1


def _bandit_config(tmp_path: Path) -> Path:
    config = tmp_path / "bandit.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.dueling_bandit.LinearDuelingBanditFamily",
                                 "init_args": {"n_arms": 5, "dim": 3, "horizon": 20}},
                      "setting": {"class_path": "icprl_lightning.data.settings.BanditDuels",
                                  "init_args": {"n_train_problems": 20, "n_val_problems": 4, "n_eval_problems": 6}},
                      "root_dir": str(tmp_path / "data"), "pairs": True}}}))
    return config


def _bandit_checkpoint(tmp_path: Path) -> str:
    torch.manual_seed(0)
    module = ICPOModule(state_dim=0, action_dim=5, discrete=True, max_context=20,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    return str(save_untrained(module, tmp_path / "bandit.ckpt"))


@pytest.mark.slow
def test_online_mdp_command_end_to_end(tmp_path, tiny_kwargs, capsys):
    torch.manual_seed(0)
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100,
                        backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    ckpt = str(save_untrained(module, tmp_path / "icpo.ckpt"))
    setting = {k: v for k, v in tiny_kwargs.items() if k in ("trajectories_per_task", "val_trajectories_per_task",
                                                             "eval_contexts_per_task", "calibration_episodes")}
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.StepPreferences",
                                  "init_args": {**setting, "reference_episodes": 4}},
                      "root_dir": str(tmp_path / "data"), "pairs": True}}}))
    main(["evaluate", "online", "--config", str(config), "--ckpt", ckpt, "--ckpt", ckpt, "--episodes", "4",
          "--seeds", "0", "--rule", "action_uniform", "--rule", "top_two", "--out", str(tmp_path / "online")])
    out = json.loads(capsys.readouterr().out)
    assert out == json.loads((tmp_path / "online.json").read_text())
    assert out["configs"] == [str(config)] and out["checkpoints"] == [ckpt, ckpt]
    for rule in ("action_uniform", "top_two"):
        result = out["online"][rule]
        assert result["queries_before_episode"] == [0, 25, 50, 75, 100]
        assert len(result["mean"]) == 5 and all(0 <= e["return"] <= 100 for e in result["mean"])
        # the same checkpoint twice: the training-seed sem is zero
        assert all(e["return_sem"] == 0 for e in result["mean"])
    assert set(out["offline"]) == {"low", "medium", "high"} and "optimal_return" in out["offline"]["low"]
    assert (tmp_path / "online.png").stat().st_size > 0


def test_online_bandit_end_to_end_as_a_function_and_a_command(tmp_path, capsys):
    config, ckpt = _bandit_config(tmp_path), _bandit_checkpoint(tmp_path)
    common = {"configs": [config], "checkpoints": [ckpt], "rounds": 20, "seeds": [0, 1]}
    out = evaluate_online(**common, rules=["action_uniform", "uniform"], out=tmp_path / "bandit")
    for rule in ("action_uniform", "uniform"):
        mean = out["icpo"][rule]["mean"]
        assert len(mean["recommendation_curve"]) == 20 and set(mean["recommendation_regret"]) == {"10"}
        assert mean["cumulative_weak_regret"] >= 0 and mean["recommendation_regret"]["10"]["sem"] is None
    assert (tmp_path / "bandit.png").stat().st_size > 0
    assert json.loads((tmp_path / "bandit.json").read_text()) == json.loads(json.dumps(out))
    flipped = evaluate_online(**common, labels="flipped")
    assert flipped["labels"] == "flipped"
    assert flipped["dts"] == out["dts"]  # DTS keeps the true labels
    assert flipped["icpo"]["action_uniform"] != out["icpo"]["action_uniform"]
    # the command prints the function's result
    main(["evaluate", "online", "--config", str(config), "--ckpt", ckpt, "--rounds", "20", "--seeds", "0", "1",
          "--labels", "flipped"])
    printed = json.loads(capsys.readouterr().out)
    assert printed["icpo"] == json.loads(json.dumps(flipped["icpo"])) and printed["dts"] == flipped["dts"]


@pytest.mark.parametrize(("extra", "message"), [
    (["--episodes", "3"], "--episodes applies to MDP families"),
    (["--rounds", "21"], "--rounds must be in [1, 20] (the model's max_context), got 21"),
    (["--n-problems", "0"], "--n-problems must be >= 1, got 0"),
])
def test_online_mistakes_are_one_line_naming_the_option(tmp_path, capsys, extra, message):
    config, ckpt = _bandit_config(tmp_path), _bandit_checkpoint(tmp_path)
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["evaluate", "online", "--config", str(config), "--ckpt", ckpt, *extra])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("icprl evaluate: error: ") and message in err, err


def test_a_checkpoint_of_another_family_is_one_line_naming_the_mismatch(tmp_path, capsys):
    darkroom = tmp_path / "darkroom.yaml"
    darkroom.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.StepPreferences"},
                      "root_dir": str(tmp_path / "data")}}}))
    ckpt = _bandit_checkpoint(tmp_path)
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["evaluate", "online", "--config", str(darkroom), "--ckpt", ckpt, "--episodes", "2"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert f"--ckpt {ckpt} does not fit the data of {darkroom} (DarkRoomFamily): ICPOModule " in err, err
    assert "has state_dim 0, the data 2" in err, err
    assert not (tmp_path / "data").exists()  # refused before any data is generated


def test_online_help_names_both_kinds_of_family(capsys):
    with pytest.raises(SystemExit) as info:
        main(["evaluate", "online", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: icprl evaluate online") and "--rounds" in out and "--episodes" in out


def test_queries_to_reach_needs_the_curve_to_stay_below():
    assert online_bandit.queries_to_reach([0.5, 0.2, 0.35, 0.1, 0.12, 0.14]) == {
        "0.4": 2, "0.35": 2, "0.3": 4, "0.25": 4}
    assert online_bandit.queries_to_reach([0.1, 0.1, 0.4])["0.3"] is None
    assert online_bandit.queries_to_reach([0.1, 0.1])["0.25"] == 1
