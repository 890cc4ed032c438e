import numpy as np
import pytest

from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import MOVES, NOOP


def test_split_is_disjoint_fixed_and_covers_the_grid():
    fam = DarkRoomFamily(seed=3)
    train, test = fam.train_goals, fam.test_goals
    assert train.shape == (80, 2) and test.shape == (20, 2)
    cells = {tuple(g) for g in np.concatenate([train, test])}
    assert len(cells) == 100
    assert not {tuple(g) for g in train} & {tuple(g) for g in test}
    np.testing.assert_array_equal(DarkRoomFamily(seed=3).test_goals, test)
    assert not np.array_equal(DarkRoomFamily(seed=4).test_goals, test)


def test_moves_walls_and_reward_each_step_on_goal():
    fam = DarkRoomFamily(horizon=5)
    env = fam.make_env(np.array([[0, 1]]))
    env.reset(seed=0)
    env.states = np.array([[0, 0]])
    obs, r, term, trunc, _ = env.step(np.array([2]))  # left into the wall: stays
    assert obs.tolist() == [[0.0, 0.0]] and r[0] == 0
    obs, r, *_ = env.step(np.array([0]))  # up onto the goal
    assert obs.tolist() == [[0.0, 1.0]] and r[0] == 1
    obs, r, term, trunc, _ = env.step(np.array([NOOP]))  # staying on the goal keeps paying
    assert r[0] == 1 and not term[0] and not trunc[0]
    env.step(np.array([NOOP]))
    *_, trunc, _ = env.step(np.array([NOOP]))
    assert trunc[0]
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([NOOP]))


def test_terminate_on_goal_freezes_the_episode():
    fam = DarkRoomFamily(horizon=10, terminate_on_goal=True)
    env = fam.make_env(np.array([[1, 0]]))
    env.reset(seed=0)
    env.states = np.array([[0, 0]])
    _, r, term, _, _ = env.step(np.array([3]))
    assert r[0] == 1 and term[0]
    obs, r, term, _, _ = env.step(np.array([2]))
    assert r[0] == 0 and term[0] and obs.tolist() == [[1.0, 0.0]]


def test_batched_step_matches_single_envs_and_is_deterministic():
    fam = DarkRoomFamily()
    goals = fam.train_goals[:16]
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 5, size=(fam.horizon, 16))

    def run(g):
        env = fam.make_env(g)
        obs, _ = env.reset(seed=11)
        out = [obs]
        for a in actions[:, : len(g)]:
            obs, r, *_ = env.step(a)
            out.append(np.concatenate([obs, r[:, None]], 1))
        return np.stack(out[1:]), out[0]

    batch, start = run(goals)
    again, _ = run(goals)
    np.testing.assert_array_equal(batch, again)
    # the same episode stepped alone, from the same start, gives the same trajectory
    env = fam.make_env(goals[5:6])
    env.reset(seed=0)
    env.states = start[5:6].astype(np.int64)
    for t, a in enumerate(actions[:, 5]):
        obs, r, *_ = env.step(np.array([a]))
        np.testing.assert_array_equal(obs[0], batch[t, 5, :2])
        assert r[0] == batch[t, 5, 2]


def test_bad_action_shape_is_a_clear_error():
    env = DarkRoomFamily().make_env(np.zeros((3, 2), dtype=int))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \[3\]"):
        env.step(np.zeros(4, dtype=int))
    assert MOVES.shape == (5, 2)
