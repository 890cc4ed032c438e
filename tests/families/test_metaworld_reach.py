"""Meta-World Reach family (real metaworld reach-v3) and its CPU oracle."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("metaworld")

from metaworld.envs.sawyer_reach_v3 import SawyerReachEnvV3  # noqa: E402
from metaworld.policies import SawyerReachV3Policy  # noqa: E402

from icprl_lightning.families.metaworld_reach import ReachTaskFamily  # noqa: E402
from icprl_lightning.families.metaworld_reach.env import (  # noqa: E402
    GOAL_HIGH,
    GOAL_LOW,
    GOAL_SLICE,
    MIN_PUCK_GOAL_XY,
    PUCK_HIGH,
    PUCK_LOW,
    ReachOracleState,
    ReachVectorEnv,
    latent_reward,
    reach_task,
    sample_puck_positions,
)
from icprl_lightning.families.metaworld_reach.oracle import (  # noqa: E402
    DEFAULT_BT_TEMPERATURE,
    advantage,
    expert_actions,
    expert_q_values,
    metaworld_expert_actions,
    simulated_q_values,
)
from icprl_lightning.families.metaworld_reach.simulation import (  # noqa: E402
    calibrate_mixing,
    rollout_returns,
    step_label_agreement,
)


@pytest.fixture(scope="module")
def family() -> ReachTaskFamily:
    return ReachTaskFamily(seed=0)


@pytest.fixture(scope="module")
def calibration(family: ReachTaskFamily) -> dict[str, dict[str, float]]:
    # A small budget: 4 goals, 5 grid points, then 5 check policies (uniform, 3 qualities, expert).
    return calibrate_mixing(family, episodes=4, seed=0, grid=(0.0, 0.05, 0.15, 0.4, 1.0), num_workers=2)


def test_split_is_disjoint_fixed_and_in_the_goal_space(family: ReachTaskFamily) -> None:
    train, test = family.train_goals, family.test_goals
    assert train.shape == (45, 3) and test.shape == (5, 3)
    assert len(np.unique(np.concatenate([train, test]), axis=0)) == 50
    again = ReachTaskFamily(seed=0)
    np.testing.assert_array_equal(again.train_goals, train)
    np.testing.assert_array_equal(again.test_goals, test)
    np.testing.assert_array_equal(family.goals("test"), test)
    space = SawyerReachEnvV3().goal_space
    assert np.all((train >= space.low) & (train <= space.high))
    assert np.all((test >= space.low) & (test <= space.high))
    with pytest.raises(ValueError, match="50 goals"):
        ReachTaskFamily(n_train=48, n_test=5)


def test_fresh_held_out_goals_widen_the_test_split_only(family: ReachTaskFamily) -> None:
    np.testing.assert_array_equal(SawyerReachEnvV3().goal_space.low, GOAL_LOW)
    np.testing.assert_array_equal(SawyerReachEnvV3().goal_space.high, GOAL_HIGH)
    wide = ReachTaskFamily(seed=0, fresh_test_goals=50)
    np.testing.assert_array_equal(wide.train_goals, family.train_goals)  # training is untouched
    test = wide.test_goals
    assert test.shape == (50, 3) and wide.n_test == 50
    assert np.all((test >= GOAL_LOW) & (test <= GOAL_HIGH))
    # never a training goal nor one of the paper's 5, and fixed by the seed
    everything = np.concatenate([family.train_goals, family.test_goals, test])
    assert len(np.unique(everything, axis=0)) == 100
    np.testing.assert_array_equal(ReachTaskFamily(seed=0, fresh_test_goals=50).test_goals, test)
    assert not np.allclose(ReachTaskFamily(seed=1, fresh_test_goals=50).test_goals, test)
    assert wide.config()["fresh_test_goals"] == 50 and "fresh_test_goals" not in family.config()
    with ReachVectorEnv(test[:4], num_workers=0) as env:  # every fresh goal resets (the puck avoids it)
        obs, _ = env.reset(seed=0)
        assert obs.shape == (4, 39)


def test_puck_sampling_avoids_the_reset_hang() -> None:
    env = SawyerReachEnvV3()
    np.testing.assert_array_equal(env._random_reset_space.low[:3], PUCK_LOW)
    np.testing.assert_array_equal(env._random_reset_space.high[:3], PUCK_HIGH)
    rng = np.random.default_rng(0)
    goals = rng.uniform(env.goal_space.low, env.goal_space.high, size=(2000, 3))
    pucks = sample_puck_positions(goals, rng)
    assert np.linalg.norm(pucks[:, :2] - goals[:, :2], axis=1).min() >= MIN_PUCK_GOAL_XY
    with pytest.raises(ValueError, match="loop forever"):
        reach_task(np.array([0.0, 0.8, 0.2]), np.array([0.0, 0.7, 0.02]))


def test_goal_hidden_reward_and_success(family: ReachTaskFamily) -> None:
    goals = family.train_goals[:3]
    with ReachVectorEnv(goals, num_workers=0) as env:
        obs, info = env.reset(seed=0)
        assert obs.shape == (3, 39) and obs.dtype == np.float32 and info == {}
        assert env.observation_space.contains(obs) and env.action_space.shape == (3, 4)
        assert np.all(obs[:, GOAL_SLICE] == 0)
        expert_hit = np.zeros(3, dtype=bool)
        for _ in range(80):
            state = env.oracle_state()
            obs, reward, terminated, truncated, info = env.step(expert_actions(state))
            state = env.oracle_state()
            assert np.all(obs[:, GOAL_SLICE] == 0)
            assert not terminated.any() and not truncated.any()
            np.testing.assert_allclose(reward, -np.linalg.norm(state.tcp - goals, axis=1), rtol=0, atol=1e-12)
            assert info["success"].dtype == bool and info["success"].shape == (3,)
            np.testing.assert_array_equal(info["success"], -reward <= 0.05)
            expert_hit |= info["success"]
        assert expert_hit.all()
        env.reset(options={"goals": family.test_goals[:3]})
        np.testing.assert_array_equal(env.oracle_state().goal, family.test_goals[:3])
        with pytest.raises(ValueError, match="shape"):
            env.reset(options={"goals": family.test_goals[:2]})


def test_batched_env_matches_a_stock_env_stepped_alone(family: ReachTaskFamily) -> None:
    goals = family.train_goals[:4]
    actions = np.random.default_rng(1).uniform(-1, 1, size=(40, 4, 4))
    with ReachVectorEnv(goals, num_workers=2) as env:
        batched = [env.reset(seed=5)[0]]
        rewards, successes = [], []
        for a in actions:
            obs, reward, _, _, info = env.step(a)
            batched.append(obs)
            rewards.append(reward)
            successes.append(info["success"])
        pucks = env.puck_positions
    i = 2
    single = SawyerReachEnvV3()
    single.set_task(reach_task(goals[i], pucks[i]))
    obs, _ = single.reset()
    assert np.all(obs[GOAL_SLICE] == 0)  # metaworld's goal-hidden tasks zero it already
    np.testing.assert_array_equal(obs.astype(np.float32), batched[0][i])
    for h, a in enumerate(actions[:, i]):
        obs, _, _, _, info = single.step(a)
        np.testing.assert_array_equal(obs.astype(np.float32), batched[h + 1][i])
        assert rewards[h][i] == latent_reward(single.tcp_center, goals[i])
        assert successes[h][i] == bool(info["success"])


def test_same_seed_same_episode_and_horizon_truncation(family: ReachTaskFamily) -> None:
    goals = family.test_goals[:2]
    actions = np.random.default_rng(2).uniform(-1, 1, size=(5, 2, 4))

    def run(seed: int) -> tuple[np.ndarray, np.ndarray]:
        with ReachVectorEnv(goals, horizon=5, num_workers=0) as env:
            obs = [env.reset(seed=seed)[0]]
            rewards = []
            for h, a in enumerate(actions):
                o, r, terminated, truncated, _ = env.step(a)
                obs.append(o)
                rewards.append(r)
                assert truncated.all() == (h == 4) and not terminated.any()
            with pytest.raises(RuntimeError, match="reset"):
                env.step(actions[0])
        return np.stack(obs), np.stack(rewards)

    obs_a, rew_a = run(7)
    obs_b, rew_b = run(7)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    obs_c, _ = run(8)
    assert not np.array_equal(obs_a[0, :, 4:7], obs_c[0, :, 4:7])  # another seed moves the puck


def test_metaworld_expert_is_metaworld_policy() -> None:
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, size=(200, 39))
    obs[:, GOAL_SLICE] = rng.uniform(0, 1, size=(200, 3))
    policy = SawyerReachV3Policy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # metaworld warns when the gain saturates the action
        reference = np.stack([np.clip(policy.get_action(o), -1, 1) for o in obs])
    np.testing.assert_allclose(metaworld_expert_actions(obs), reference, atol=1e-6)


def test_tcp_expert_settles_on_the_goal_and_beats_metaworlds_expert(family: ReachTaskFamily) -> None:
    goals = family.test_goals
    with ReachVectorEnv(np.concatenate([goals, goals]), num_workers=0) as env:
        env.reset(seed=0)
        total = np.zeros(10)
        for _ in range(150):
            state = env.oracle_state()
            visible = np.concatenate([np.zeros((10, 36)), state.goal], axis=1)
            visible[:, 0:3] = state.hand
            actions = np.concatenate([expert_actions(state)[:5], metaworld_expert_actions(visible)[5:]])
            _, reward, _, _, _ = env.step(actions)
            total += reward
    assert np.all(-reward[:5] < 0.01)  # the TCP expert puts the TCP on the goal ...
    assert np.all(-reward[5:] > 0.03)  # ... metaworld's stops with the hand there, the TCP ≈0.045 off
    assert np.all(total[:5] > total[5:])


def test_expert_reaches_the_goal_and_beats_uniform(family: ReachTaskFamily) -> None:
    goals = np.concatenate([family.test_goals, family.train_goals[:5]])
    returns, success = rollout_returns(family, goals, np.array([0.0, 1.0]), seed=0, num_workers=2)
    assert success[1].mean() >= 0.9
    assert np.all(returns[1] > returns[0])


def test_calibration_is_monotone_and_near_targets(calibration: dict[str, dict[str, float]]) -> None:
    ps = [calibration[q]["mixing"] for q in ("low", "medium", "high")]
    achieved = [calibration[q]["achieved"] for q in ("low", "medium", "high")]
    assert ps == sorted(ps) and len(set(ps)) == 3
    assert achieved == sorted(achieved)
    for q in ("low", "medium", "high"):
        # 4 episodes per policy: the check run alone has a standard error of about 0.06.
        assert abs(calibration[q]["achieved"] - calibration[q]["target"]) < 0.15, calibration


def _oracle_state(env: SawyerReachEnvV3, obs: np.ndarray, t: int) -> ReachOracleState:
    return ReachOracleState(hand=obs[None, 0:3].copy(), prev_hand=obs[None, 18:21].copy(),
                            tcp=np.array(env.tcp_center)[None], mocap=env.data.mocap_pos[:1].copy(),
                            goal=env._get_pos_goal()[None].copy(), t=t)


def test_advantage_agrees_with_simulated_rollouts(family: ReachTaskFamily) -> None:
    rng = np.random.default_rng(3)
    goals = family.train_goals[:6]
    pucks = sample_puck_positions(goals, rng)
    agree = []
    env = SawyerReachEnvV3()
    for goal, puck in zip(goals, pucks, strict=True):
        env.set_task(reach_task(goal, puck))
        obs, _ = env.reset()
        visits = set(rng.choice(np.arange(20, 150), size=3, replace=False).tolist())
        for t in range(150):
            state = _oracle_state(env, obs, t)
            if t in visits:
                pair = np.concatenate([family.oracle.behavior_actions(state, p, rng) for p in (0.05, 0.4)])
                truth = simulated_q_values(env, pair)
                estimate = np.array([advantage(state, a[None])[0] for a in pair])
                if truth[0] != truth[1]:
                    agree.append(np.sign(truth[0] - truth[1]) == np.sign(estimate[0] - estimate[1]))
            obs, *_ = env.step(family.oracle.behavior_actions(state, 0.3, rng)[0])
    assert len(agree) >= 12 and np.mean(agree) >= 0.8


def test_advantage_is_zero_for_the_expert_and_ranks_it_above_random(family: ReachTaskFamily) -> None:
    rng = np.random.default_rng(4)
    wins = []
    with ReachVectorEnv(family.train_goals[:10], num_workers=0) as env:
        env.reset(seed=4)
        for _ in range(60):
            state = env.oracle_state()
            np.testing.assert_array_equal(advantage(state, expert_actions(state)), 0.0)
            wins.append(advantage(state, rng.uniform(-1, 1, size=(10, 4))) < 0)
            env.step(family.oracle.behavior_actions(state, 0.3, rng))
        state = env.oracle_state()
        candidates = rng.uniform(-1, 1, size=(3, 10, 4))
        np.testing.assert_allclose(expert_q_values(state, candidates),
                                   np.stack([expert_q_values(state, a) for a in candidates]), rtol=0, atol=1e-12)
        with pytest.raises(ValueError, match="shape"):
            expert_q_values(state, np.zeros((3, 4)))
    # Measured 0.98: near the goal a small random action can still beat the proportional expert.
    assert np.mean(wins) > 0.9


def test_default_temperature_gives_informative_labels(family: ReachTaskFamily,
                                                      calibration: dict[str, dict[str, float]]) -> None:
    stats = step_label_agreement(family, calibration["low"]["mixing"], calibration["high"]["mixing"],
                                 DEFAULT_BT_TEMPERATURE, episodes=4, seed=0, num_workers=0)
    assert 0.75 <= stats["agreement"] <= 0.95, stats
