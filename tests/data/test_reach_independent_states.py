"""Meta-World Reach states drawn independently of the task and the actions (``state_source="uniform"``):
``ReachVectorEnv.place_hands`` and ``ReachTaskFamily.independent_state_rollouts``.

Small B, horizon 5 and in-process envs (``num_workers=0``) keep these fast.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("metaworld")

from factories import reach_data  # noqa: E402

from icprl_lightning.families.metaworld_reach import ReachTaskFamily  # noqa: E402
from icprl_lightning.families.metaworld_reach.env import (  # noqa: E402
    GOAL_SLICE,
    HAND_HIGH,
    HAND_LOW,
    ReachVectorEnv,
    _CompiledReachEnv,
)
from icprl_lightning.families.metaworld_reach.oracle import expert_actions  # noqa: E402

H = 5
# Points well inside the arm's reach (the box's far corners, y ≈ 1, are not: see ``place_hands``).
REACHABLE = np.array([[0.0, 0.6, 0.2], [0.15, 0.7, 0.3], [-0.15, 0.55, 0.12]])
STATE_TOL = 0.01  # the hand rests ≈ 0.005 from the mocap (gravity sag of the weld)


@pytest.fixture(scope="module")
def family() -> ReachTaskFamily:
    return ReachTaskFamily(n_train=2, n_test=1, horizon=H, num_workers=0)


@pytest.fixture(scope="module")
def goals(family) -> np.ndarray:
    return family.train_goals[[0, 1, 0]]


def _run(family, goals, seed: int, policy: str):
    """observations() and oracle states before each step, with the expert's or uniform actions."""
    obs, states, rewards = [], [], []
    act_rng = np.random.default_rng(123)
    with family.independent_state_rollouts(goals, np.random.default_rng(seed)) as roll:
        for _ in range(H):
            state = roll.oracle_state()
            obs.append(roll.observations().copy())
            states.append(state)
            actions = (family.oracle.optimal_actions(state) if policy == "expert"
                       else family.oracle.uniform_actions(state, act_rng))
            _, reward = roll.step(actions)
            rewards.append(reward)
    return np.stack(obs, axis=1), states, np.stack(rewards, axis=1)


def test_box_is_reach_v3s_hand_and_mocap_box():
    env = _CompiledReachEnv()
    for low, high in ((env.hand_low, env.hand_high), (env.mocap_low, env.mocap_high)):
        np.testing.assert_array_equal(low, HAND_LOW)
        np.testing.assert_array_equal(high, HAND_HIGH)


def test_place_hands_moves_the_hand_without_counting_a_step(goals):
    with ReachVectorEnv(goals, horizon=H, num_workers=0) as env:
        with pytest.raises(RuntimeError, match="reset"):
            env.place_hands(REACHABLE)
        env.reset(seed=0)
        obs = env.place_hands(REACHABLE)
        state = env.oracle_state()
        assert obs.dtype == np.float32 and obs.shape == (3, 39) and state.t == 0 and env.t == 0
        np.testing.assert_array_equal(state.mocap, REACHABLE)
        np.testing.assert_allclose(obs[:, 0:3], REACHABLE, atol=STATE_TOL)
        np.testing.assert_array_equal(obs[:, 18:36], obs[:, 0:18])  # previous frame = current, as after reset
        np.testing.assert_array_equal(state.prev_hand, state.hand)
        np.testing.assert_array_equal(obs[:, GOAL_SLICE], 0.0)
        np.testing.assert_allclose(obs, env._masked_obs())
        stepped, reward, *_ = env.step(np.ones((3, 4)))
        assert env.t == 1
        np.testing.assert_array_equal(stepped[:, 18:36], obs[:, 0:18])  # the step starts from the placed state
        # The placement starts from the post-reset state: the actions since leave no trace.
        again = env.place_hands(REACHABLE)
        np.testing.assert_array_equal(again, obs)
        with pytest.raises(ValueError, match="box"):
            env.place_hands(REACHABLE + np.array([0.0, 1.0, 0.0]))
        with pytest.raises(ValueError, match="shape"):
            env.place_hands(REACHABLE[:2])


def test_states_are_drawn_uniformly_in_the_box_and_change_every_step(family, goals):
    seed = 7
    obs, states, rewards = _run(family, goals, seed, "expert")
    # The draws: the env's reset seed first, then one [N, 3] uniform draw before each step.
    rng = np.random.default_rng(seed)
    rng.integers(2**31)
    drawn = np.stack([rng.uniform(HAND_LOW, HAND_HIGH, size=(3, 3)) for _ in range(H)], axis=1)
    mocap = np.stack([s.mocap for s in states], axis=1)
    hand = np.stack([s.hand for s in states], axis=1)
    np.testing.assert_array_equal(mocap, drawn)
    np.testing.assert_array_equal(obs[..., 0:3], hand.astype(np.float32))
    assert np.all((mocap >= HAND_LOW) & (mocap <= HAND_HIGH))
    assert np.all(np.linalg.norm(np.diff(hand, axis=1), axis=-1) > 1e-3)  # a new state at every step
    assert [s.t for s in states] == list(range(H))
    np.testing.assert_array_equal(obs[..., GOAL_SLICE], 0.0)
    np.testing.assert_array_equal(obs[..., 18:36], obs[..., 0:18])
    # Where the arm reaches, the hand is at the drawn point; nowhere is it far off.
    dist = np.linalg.norm(hand - drawn, axis=-1)
    assert np.median(dist) < STATE_TOL and dist.max() < 0.2
    assert rewards.shape == (3, H) and np.all(rewards < 0)


def test_states_do_not_depend_on_the_actions(family, goals):
    obs_expert, states_expert, rewards_expert = _run(family, goals, 3, "expert")
    obs_uniform, states_uniform, rewards_uniform = _run(family, goals, 3, "uniform")
    np.testing.assert_array_equal(obs_expert, obs_uniform)
    for a, b in zip(states_expert, states_uniform, strict=True):
        for field in ("hand", "prev_hand", "tcp", "mocap", "goal"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(rewards_expert, rewards_uniform)  # the actions did differ
    obs_other, *_ = _run(family, goals, 4, "expert")
    assert not np.allclose(obs_other, obs_expert)


def test_the_expert_still_heads_for_the_goal_from_a_placed_state(family, goals):
    with ReachVectorEnv(goals, horizon=H, num_workers=0) as env:
        env.reset(seed=1)
        env.place_hands(REACHABLE)
        state = env.oracle_state()
        actions = expert_actions(state)
        to_goal = state.goal - state.tcp
        assert np.all(np.sum(actions[:, :3] * to_goal, axis=1) > 0)
        q = family.oracle.utility(state, np.stack([actions, -actions]))
        assert np.all(q[0] > q[1])
        before = -np.linalg.norm(to_goal, axis=1)
        _, reward, *_ = env.step(actions)
        assert np.all(reward > before)


def test_a_step_preference_dataset_with_uniform_states_generates(tmp_path):
    dm = reach_data(context_kind="step_preference", state_source="uniform", root_dir=str(tmp_path),
                    n_train_tasks=2, n_test_tasks=1, horizon=H, trajectories_per_task=2, val_trajectories_per_task=1,
                    eval_contexts_per_task=1, calibration_episodes=1, reference_episodes=1, num_workers=0,
                    progress=False, batch_size=2)
    dm.prepare_data()
    data = dm.load()
    states = data["train"]["states"]
    assert states.shape == (4, H, 39) and data["val"]["states"].shape == (2, H, 39)
    assert np.all((states[..., 0:3] >= HAND_LOW - 0.05) & (states[..., 0:3] <= HAND_HIGH + 0.05))
    np.testing.assert_array_equal(states[..., 18:36], states[..., 0:18])  # every state a placement
    assert "uniform" in str(data.manifest)


def test_workers_place_the_same_hands(goals):
    out = []
    for workers in (0, 2):
        with ReachVectorEnv(goals, horizon=H, num_workers=workers) as env:
            env.reset(seed=2)
            env.step(np.zeros((3, 4)))
            out.append((env.place_hands(REACHABLE), env.oracle_state()))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1].mocap, out[1][1].mocap)
    np.testing.assert_array_equal(out[0][1].tcp, out[1][1].tcp)
