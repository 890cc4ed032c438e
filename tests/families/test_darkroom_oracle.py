"""The closed-form A* against brute-force backward induction, and the mixed-policy calibration."""

import itertools

import numpy as np
import pytest

from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import N_ACTIONS, NOOP, step_reward, transition
from icprl_lightning.families.darkroom.family import calibrate_mixing
from icprl_lightning.families.darkroom.oracle import optimal_actions, optimal_advantage


def backward_induction(fam: DarkRoomFamily, goal: np.ndarray) -> np.ndarray:
    """Q[k, x, y, a] for k = 1..H steps left, by dynamic programming over every cell."""
    cells = np.array(list(itertools.product(range(fam.size), repeat=2)))
    v = np.zeros((fam.size, fam.size))
    q_all = np.zeros((fam.horizon + 1, fam.size, fam.size, N_ACTIONS))
    for k in range(1, fam.horizon + 1):
        q = np.zeros((fam.size, fam.size, N_ACTIONS))
        for a in range(N_ACTIONS):
            nxt = transition(cells, np.full(len(cells), a), fam.size)
            r = step_reward(nxt, goal)
            cont = v[nxt[:, 0], nxt[:, 1]]
            if fam.terminate_on_goal:
                cont = np.where(r > 0, 0.0, cont)
            q[cells[:, 0], cells[:, 1], a] = r + cont
        if fam.terminate_on_goal:  # the goal cell is terminal: no value there
            q[goal[0], goal[1]] = 0.0
        q_all[k] = q
        v = q.max(-1)
    return q_all


@pytest.mark.parametrize("terminate", [False, True])
@pytest.mark.parametrize("size,horizon", [(3, 6), (4, 9), (5, 4)])
def test_closed_form_advantage_matches_backward_induction(size, horizon, terminate):
    fam = DarkRoomFamily(size=size, horizon=horizon, n_train_tasks=1, n_test_tasks=1, terminate_on_goal=terminate)
    cells = np.array(list(itertools.product(range(size), repeat=2)))
    for goal in cells:
        q = backward_induction(fam, goal)
        for k in range(1, horizon + 1):
            for a in range(N_ACTIONS):
                states = cells
                if terminate:
                    states = cells[~np.all(cells == goal, axis=1)]
                adv = optimal_advantage(states, np.full(len(states), a), goal, k, fam)
                qk = q[k, states[:, 0], states[:, 1]]
                np.testing.assert_allclose(adv, qk[:, a] - qk.max(-1), atol=1e-6)


def test_optimal_action_has_zero_advantage():
    fam = DarkRoomFamily()
    rng = np.random.default_rng(0)
    s = rng.integers(0, 10, size=(500, 2))
    g = rng.integers(0, 10, size=(500, 2))
    adv = optimal_advantage(s, optimal_actions(s, g), g, 100, fam)
    np.testing.assert_array_equal(adv, 0.0)


@pytest.mark.parametrize("size", [2, 5, 10])
def test_optimal_action_table_is_the_x_then_y_rule(size):
    """The sign lookup gives the rule it replaced (x gap first, then y, then NOOP) on every cell × goal."""
    cells = np.array(list(itertools.product(range(size), repeat=2)))
    s, g = np.repeat(cells, len(cells), axis=0), np.tile(cells, (len(cells), 1))
    dx, dy = g[:, 0] - s[:, 0], g[:, 1] - s[:, 1]
    rule = np.where(dx > 0, 3, np.where(dx < 0, 2, np.where(dy < 0, 1, np.where(dy > 0, 0, NOOP))))
    got = optimal_actions(s, g)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, rule)
    np.testing.assert_array_equal(optimal_actions(s.reshape(size, -1, 2), g.reshape(size, -1, 2)),
                                  rule.reshape(size, -1))


def test_calibration_hits_targets_and_is_monotone():
    fam = DarkRoomFamily()
    cal = calibrate_mixing(fam, {"low": 0.2, "medium": 0.4, "high": 0.8}, episodes_per_goal=10, seed=0)
    ps = [cal[q]["mixing"] for q in ("low", "medium", "high")]
    assert ps == sorted(ps) and 0 < ps[0] < ps[-1] < 1
    for q in cal.values():
        assert abs(q["achieved"] - q["target"]) < 0.04, q


def test_unreachable_target_is_a_clear_error():
    fam = DarkRoomFamily(terminate_on_goal=True)  # a random walk already reaches the goal often
    with pytest.raises(ValueError, match="outside what the mixed policy reaches"):
        calibrate_mixing(fam, {"low": 0.01}, episodes_per_goal=2, seed=0)
