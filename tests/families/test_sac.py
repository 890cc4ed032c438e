"""Stable-Baselines3 pieces: the single-task gym envs, the SAC oracle and the from-scratch baselines, on
tiny budgets (they check plumbing, selection and shapes, not learning)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from stable_baselines3 import DQN

from icprl_lightning.baselines import dqn_from_scratch, sac_from_scratch
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.gym_env import DarkRoomGoalEnv
from icprl_lightning.families.metaworld_reach.env import latent_reward
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.sac import SACTrainingRun, calibrate_checkpoints, train_sac_oracle
from icprl_lightning.io import write_json_atomic
from icprl_lightning.sb3 import EvalCheckpointCallback, EvalRecord, run_episodes

# Inside reach-v3's goal box (x ∈ [−0.1, 0.1], y ∈ [0.8, 0.9], z ∈ [0.05, 0.3]); no ML1 call (≈7 s) needed.
GOALS = np.array([[0.05, 0.85, 0.2], [-0.05, 0.82, 0.1]])


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.filterwarnings("ignore::UserWarning")  # unbounded Box warnings: metaworld's own bounds are infinite
@pytest.mark.parametrize("goal_visible", [False, True])
def test_reach_goal_env_passes_check_env(goal_visible):
    check_env(ReachGoalEnv(GOALS, horizon=20, goal_visible=goal_visible), skip_render_check=True)


def test_reach_goal_env_latent_reward_goal_mask_truncation_and_determinism():
    env = ReachGoalEnv(GOALS, horizon=4)
    obs, info = env.reset(seed=3)
    assert np.all(obs[36:39] == 0.0)
    actions = np.random.default_rng(0).uniform(-1, 1, size=(4, 4)).astype(np.float32)
    first = []
    for h, a in enumerate(actions):
        obs, reward, terminated, truncated, info = env.step(a)
        state = env.oracle_state()
        assert reward == pytest.approx(float(latent_reward(state.tcp[0], state.goal[0])))
        assert info["success"] == (-reward <= 0.05) and not terminated and truncated == (h == 3)
        first.append(obs)
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(actions[0])
    env.reset(seed=3)
    np.testing.assert_array_equal(np.stack([env.step(a)[0] for a in actions]), np.stack(first))
    visible = ReachGoalEnv(GOALS, horizon=4, goal_visible=True)
    obs, info = visible.reset(seed=0, options={"goal_index": 1})
    np.testing.assert_allclose(obs[36:39], GOALS[1], rtol=1e-6)


def test_darkroom_goal_env_passes_check_env_and_matches_the_vector_env():
    family = DarkRoomFamily()
    goal = family.test_goals[0]
    env = DarkRoomGoalEnv(family, goal)
    check_env(env, skip_render_check=True)
    vec = family.make_env(goal[None])
    obs, _ = env.reset(seed=5)
    vec_obs, _ = vec.reset(seed=5)
    np.testing.assert_array_equal(obs, vec_obs[0])
    for a in np.random.default_rng(1).integers(0, 5, size=family.horizon):
        obs, reward, terminated, truncated, _ = env.step(int(a))
        vec_obs, vec_reward, vec_term, vec_trunc, _ = vec.step(np.array([a]))
        np.testing.assert_array_equal(obs, vec_obs[0])
        assert (reward, terminated, truncated) == (vec_reward[0], vec_term[0], vec_trunc[0])
    assert truncated


@pytest.mark.parametrize("action", [5, 9, -1, 2.7, "1", None, True, np.array([1, 2]), np.float32(1.0)])
def test_darkroom_goal_env_refuses_an_action_outside_its_space(action):
    env = DarkRoomGoalEnv(DarkRoomFamily(), DarkRoomFamily().test_goals[0])
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be an integer move in \[0, 5\)"):
        env.step(action)
    for good in (0, 4, np.int64(3), np.array(2)):  # what the space contains is taken
        env.step(good)


@pytest.mark.parametrize("action", [[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 0.0], np.full(4, np.inf), 0.5])
def test_reach_goal_env_refuses_a_non_finite_or_misshapen_action(action):
    env = ReachGoalEnv(GOALS, horizon=4)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be 4 finite numbers"):
        env.step(action)
    env.step(np.full(4, 2.0))  # out of range: clipped, as before


# --- SAC oracle -------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def oracle_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("sac") / "oracle"
    return train_sac_oracle(GOALS, out, timesteps=200, checkpoint_every=50, eval_episodes=2, horizon=30)


def test_sac_oracle_saves_checkpoints_and_picks_closest_to_targets(oracle_dir):
    summary = json.loads((oracle_dir / "summary.json").read_text())
    steps = [c["step"] for c in summary["checkpoints"]]
    assert steps == [0, 50, 100, 150, 200]
    assert all((oracle_dir / c["path"]).exists() for c in summary["checkpoints"])
    assert not list(oracle_dir.parent.glob(".oracle.tmp-*"))
    returns = np.array([c["mean_return"] for c in summary["checkpoints"]])
    normalized = (returns - summary["uniform_return"]) / (returns[-1] - summary["uniform_return"])
    assert set(summary["calibration"]) == {"low", "medium", "high"}
    for quality in summary["calibration"].values():
        assert all(math.isfinite(quality[k]) for k in ("achieved", "return", "uniform_return", "expert_return"))
        assert quality["step"] == steps[int(np.argmin(np.abs(normalized - quality["target"])))]
    with pytest.raises(FileExistsError):
        train_sac_oracle(GOALS, oracle_dir, timesteps=10)


def test_sac_oracle_on_vectorized_envs_evaluates_each_multiple_and_reports_splits(tmp_path):
    # 2 envs: num_timesteps goes 2, 4, ...; checkpoints where it first passes each multiple of 45
    out = train_sac_oracle(GOALS, tmp_path / "oracle", timesteps=120, checkpoint_every=45, eval_episodes=2,
                           horizon=30, n_envs=2, report_splits={"a": GOALS[:1], "b": GOALS},
                           report_episodes_per_goal=1)
    summary = json.loads((out / "summary.json").read_text())
    assert [c["step"] for c in summary["checkpoints"]] == [0, 46, 90, 120] and summary["n_envs"] == 2
    assert {k: v["episodes"] for k, v in summary["final_by_split"].items()} == {"a": 1, "b": 2}
    for report in summary["final_by_split"].values():
        assert set(report) >= {"deterministic", "stochastic", "uniform", "expert"}
        assert report["expert"]["return"] > report["uniform"]["return"]  # the scripted expert reaches the goal
    with pytest.raises(ValueError, match="n_envs must be >= 1"):
        train_sac_oracle(GOALS, tmp_path / "other", timesteps=10, n_envs=0)
    assert not (tmp_path / "other").exists()


def test_calibrate_checkpoints_on_hand_values():
    records = [EvalRecord(step, r, 0.0, f"c/{step}") for step, r in enumerate([-100.0, -80.0, -60.0, -40.0, -20.0])]
    cal = calibrate_checkpoints(records, uniform_return=-100.0, expert_return=-10.0)
    # normalized returns 0, .25, .5, .75, 1 -> closest to .2, .4, .8
    assert {k: v["step"] for k, v in cal.items()} == {"low": 1, "medium": 2, "high": 3}
    assert cal["high"]["achieved"] == pytest.approx(0.75)
    assert cal["high"]["achieved_vs_expert"] == pytest.approx(60 / 90)


def test_sac_oracle_reloads_and_advantage_is_centred_on_the_policy(oracle_dir):
    oracle = SACTrainingRun(oracle_dir)
    env = ReachGoalEnv(GOALS, horizon=30, goal_visible=True)
    obs, _ = env.reset(seed=0)
    states = []
    for _ in range(8):
        states.append(obs)
        obs, *_ = env.step(env.action_space.sample())
    obs = np.stack(states)  # [8, 39]
    uniform = np.random.default_rng(0).uniform(-1, 1, size=(8, 4)).astype(np.float32)
    adv = oracle.advantage(obs, uniform, n_samples=32)
    assert adv.shape == (8,) and np.all(np.isfinite(adv))
    np.testing.assert_array_equal(adv, oracle.advantage(obs, uniform, n_samples=32))  # seeded
    # E_{a~π} A(s, a) = 0. Exactly, on the very actions the baseline averaged (same generator seed) ...
    many = np.repeat(obs, 32, axis=0)
    same = oracle.policy_actions(many, torch.Generator().manual_seed(0))
    np.testing.assert_allclose((oracle.q_values(obs, uniform) - adv)[:, None],
                               oracle.q_values(many, same).reshape(8, 32).mean(axis=1, keepdims=True), atol=1e-5)
    # ... and within Monte Carlo error on fresh policy actions: |mean| < 4 standard errors per state.
    k, m = 64, 256
    own = oracle.policy_actions(np.repeat(obs, k, axis=0), torch.Generator().manual_seed(1))
    adv_own = oracle.advantage(np.repeat(obs, k, axis=0), own, n_samples=m, seed=2).reshape(8, k)
    sem = adv_own.std(axis=1) * np.sqrt(1 / k + 1 / m)
    assert np.all(np.abs(adv_own.mean(axis=1)) < 4 * sem)
    for quality in ("low", "medium", "high"):
        assert oracle.policy_actions(obs, torch.Generator(), quality).shape == (8, 4)
    with pytest.raises(ValueError, match="goal-visible"):
        oracle.advantage(obs[:, :30], uniform)


# --- from-scratch baselines -------------------------------------------------------------------------------

def test_sac_from_scratch_tiny_budget_writes_finite_json(tmp_path):
    result = sac_from_scratch.run(GOALS, seeds=[0], episodes=3, horizon=20, eval_every=1, eval_episodes=1,
                                  test_episodes=2)
    path = write_json_atomic(tmp_path / "sac.json", result)
    loaded = json.loads(path.read_text())
    assert loaded["n_goals"] == 2 and loaded["episodes_per_goal"] == 3 and loaded["seeds"] == [0]
    for key in ("return", "success", "normalized_return"):
        assert math.isfinite(loaded[key]["mean"]) and math.isfinite(loaded[key]["sem"])
    for goal in loaded["per_goal"]:
        run = goal["runs"][0]
        curve = np.array(run["eval_curve"])  # [evals, (step, return, success)]
        assert list(curve[:, 0]) == [20, 40, 60]  # no untrained step-0 candidate for the baseline
        assert run["best_eval_return"] == curve[:, 1].max()
        assert run["best_step"] == curve[int(np.argmax(curve[:, 1])), 0]
        assert run["reference_returns"]["expert"] > run["reference_returns"]["uniform"]


def test_best_checkpoint_is_restored_and_greedy_table_matches_predict():
    family = DarkRoomFamily()
    goal = family.test_goals[0]
    eval_env = DarkRoomGoalEnv(family, goal)
    model = DQN("MlpPolicy", DarkRoomGoalEnv(family, goal), seed=0, device="cpu", learning_starts=50,
                target_update_interval=200)
    callback = EvalCheckpointCallback(eval_env, 100, 3, eval_seed=7, make_act=dqn_from_scratch.greedy_table_act)
    model.learn(1000, callback=callback)
    assert len(callback.history) == 11
    returns = [r.mean_return for r in callback.history]
    assert callback.best_index == int(np.argmax(returns))
    best = callback.restore_best()
    again = run_episodes(dqn_from_scratch.greedy_table_act(model), eval_env, 3, seed=7)
    assert again.returns.mean() == best.mean_return
    cells = np.stack(np.meshgrid(np.arange(10), np.arange(10), indexing="ij"), -1).reshape(-1, 2).astype(np.float32)
    table = dqn_from_scratch.greedy_table_act(model)
    assert [table(c) for c in cells] == list(model.predict(cells, deterministic=True)[0])


def test_dqn_from_scratch_command_tiny_budget(tmp_path):
    from icprl_lightning.commands import main

    main(["baseline", "dqn", "--episodes", "3", "--n-goals", "2", "--eval-every", "1", "--eval-episodes", "2",
          "--test-episodes", "3", "--out", str(tmp_path / "dqn.json")])
    loaded = json.loads((tmp_path / "dqn.json").read_text())
    assert loaded["n_goals"] == 2 and loaded["episodes_per_goal"] == 3
    assert loaded["command"].startswith("icprl baseline dqn --episodes 3")
    for key in ("return", "success", "normalized_return"):
        assert math.isfinite(loaded[key]["mean"]) and math.isfinite(loaded[key]["sem"])
    for goal in loaded["per_goal"]:
        run = goal["runs"][0]
        assert run["reference_returns"]["optimal"] >= run["return"] >= 0.0
        assert run["best_eval_return"] == max(r for _, r, _ in run["eval_curve"])


@pytest.mark.slow
def test_sac_oracle_commands_train_then_export_per_task(tmp_path):
    """``icprl oracle train`` on one goal (the paper's per-task variant), then ``icprl oracle export`` of its run."""
    from icprl_lightning.commands import main
    from icprl_lightning.families.metaworld_reach.sac_weights import ExportedSAC

    out = tmp_path / "o"
    main(["oracle", "train", "--goals", "train", "--goal-index", "0", "--timesteps", "300", "--checkpoint-every",
          "150", "--eval-episodes", "1", "--horizon", "30", "--out", str(out)])
    summary = SACTrainingRun(out).summary
    assert len(summary["goals"]) == 1 and summary["goal_split"] == "train"
    assert [c["step"] for c in summary["checkpoints"]] == [0, 150, 300]
    assert summary["command"].startswith("icprl oracle train --goals train --goal-index 0")
    main(["oracle", "export", str(out), "--out", str(tmp_path / "exported"), "--targets", "0.5"])
    exported = ExportedSAC(tmp_path / "exported")
    assert exported.levels == (0.5, 1.0)
    assert exported.manifest["training"]["command"] == summary["command"]
