"""Double Thompson Sampling: counts, confidence bounds, arm selection, and finding a Condorcet winner."""

from __future__ import annotations

import numpy as np
import pytest

from icprl_lightning.families.dueling_bandit.dts import DoubleThompsonSampling, run_dts

# P[i, j] = P(arm i beats arm j) for 5 arms. Copeland scores 3, 2, 2, 1, 2: arm 0 is the unique Copeland
# winner but loses to arm 4. In the champion's column (P(i beats 0)) the best challenger is arm 4; in its
# row (P(0 beats i)) the "best" is arm 2, the arm the champion beats most easily.
_COPELAND = np.array([
    [0.5, 0.8, 0.9, 0.7, 0.4],
    [0.2, 0.5, 0.7, 0.7, 0.3],
    [0.1, 0.3, 0.5, 0.7, 0.7],
    [0.3, 0.3, 0.3, 0.5, 0.7],
    [0.6, 0.7, 0.3, 0.3, 0.5],
])


def _duels_from_rates(rates: np.ndarray, per_pair: int, n_problems: int) -> tuple[np.ndarray, ...]:
    """A context in which every pair i < j was duelled ``per_pair`` times, i winning round(rate·n) of them."""
    firsts, seconds, labels = [], [], []
    for i, j in zip(*np.triu_indices(len(rates), k=1), strict=True):
        wins = round(rates[i, j] * per_pair)
        firsts.append(np.full(per_pair, i))
        seconds.append(np.full(per_pair, j))
        labels.append(np.arange(per_pair) < wins)
    row = (np.concatenate(firsts), np.concatenate(seconds), np.concatenate(labels).astype(np.uint8))
    return tuple(np.tile(x, (n_problems, 1)) for x in row)


def test_update_counts_hand_made_duels() -> None:
    dts = DoubleThompsonSampling(3, 2, rng=np.random.default_rng(0))
    dts.update(np.array([0, 2]), np.array([1, 1]), np.array([1, 0]))  # p0: 0 beats 1; p1: 1 beats 2
    dts.update(np.array([1, 2]), np.array([0, 2]), np.array([1, 1]))  # p0: 1 beats 0; p1: self-duel
    dts.update(np.array([0, 0]), np.array([1, 2]), np.array([1, 0]))  # p0: 0 beats 1; p1: 2 beats 0
    expected = np.zeros((2, 3, 3), dtype=np.int64)
    expected[0, 0, 1] = 2
    expected[0, 1, 0] = 1
    expected[1, 1, 2] = 1
    expected[1, 2, 0] = 1
    np.testing.assert_array_equal(dts.wins, expected)
    assert dts.t == 4  # three rounds played, the self-duel included


def test_confidence_bounds_hand_computed() -> None:
    dts = DoubleThompsonSampling(3, 1, alpha=0.51, rng=np.random.default_rng(0))
    for first, second, won in [(0, 1, 1), (0, 1, 1), (1, 0, 0), (1, 0, 1)]:
        dts.update(np.array([first]), np.array([second]), np.array([won]))
    upper, lower = dts.confidence_bounds()
    radius = np.sqrt(0.51 * np.log(5) / 4)  # t = 5, N_01 = 4, B_01 = 3
    assert upper[0, 0, 1] == pytest.approx(0.75 + radius)
    assert lower[0, 0, 1] == pytest.approx(0.75 - radius)
    assert upper[0, 1, 0] == pytest.approx(0.25 + radius)
    assert lower[0, 1, 0] == pytest.approx(0.25 - radius)
    assert upper[0, 0, 2] == 1.0 and lower[0, 0, 2] == 0.0  # never compared
    np.testing.assert_array_equal(np.diagonal(upper[0]), 0.5)
    np.testing.assert_array_equal(np.diagonal(lower[0]), 0.5)


def test_observe_context_matches_sequential_updates() -> None:
    rng = np.random.default_rng(3)
    n_problems, n_arms, horizon = 4, 6, 50
    first = rng.integers(0, n_arms, size=(n_problems, horizon))
    second = rng.integers(0, n_arms, size=(n_problems, horizon))  # includes some self-duels
    preferred = rng.integers(0, 2, size=(n_problems, horizon)).astype(np.uint8)
    offline = DoubleThompsonSampling(n_arms, n_problems, rng=np.random.default_rng(0))
    offline.observe_context(first, second, preferred)
    online = DoubleThompsonSampling(n_arms, n_problems, rng=np.random.default_rng(0))
    for h in range(horizon):
        online.update(first[:, h], second[:, h], preferred[:, h])
    np.testing.assert_array_equal(offline.wins, online.wins)
    assert offline.t == online.t == horizon + 1
    # Each informative duel is counted exactly once.
    assert offline.wins.sum() == (first != second).sum()


def test_observe_context_exact_counts() -> None:
    dts = DoubleThompsonSampling(3, 1, rng=np.random.default_rng(0))
    dts.observe_context(np.array([[0, 0, 2]]), np.array([[1, 1, 0]]), np.array([[1, 0, 1]]))
    assert dts.wins[0, 0, 1] == 1 and dts.wins[0, 1, 0] == 1 and dts.wins[0, 2, 0] == 1
    assert dts.wins.sum() == 3


def test_challenger_uses_the_champions_column() -> None:
    # Huge counts make every Beta draw near-deterministic (std ≈ 0.004, margins ≥ 0.1); a huge alpha makes
    # every confidence interval wide, so all arms are Copeland candidates and all are eligible challengers.
    n_problems = 8
    dts = DoubleThompsonSampling(5, n_problems, alpha=1000.0, rng=np.random.default_rng(0))
    dts.observe_context(*_duels_from_rates(_COPELAND, per_pair=20_000, n_problems=n_problems))
    first, second = dts.select()
    np.testing.assert_array_equal(first, 0)
    # Column (P(i beats 0)): arm 4. The row bug (P(0 beats i)) would give arm 2; a self-duel would give 0.
    np.testing.assert_array_equal(second, 4)
    np.testing.assert_array_equal(dts.challenger(np.full(n_problems, 1)), 0)  # max P(i beats 1) = 0.8


def test_challenger_restricted_by_lower_bound() -> None:
    # With alpha = 0.51 the same counts are conclusive: l_{4,0} ≈ 0.58 > 1/2 rules arm 4 out, every other
    # arm loses to the champion, so DTS duels the champion against itself.
    n_problems = 8
    dts = DoubleThompsonSampling(5, n_problems, alpha=0.51, rng=np.random.default_rng(0))
    dts.observe_context(*_duels_from_rates(_COPELAND, per_pair=20_000, n_problems=n_problems))
    first, second = dts.select()
    np.testing.assert_array_equal(first, 0)
    np.testing.assert_array_equal(second, 0)


def test_first_arm_ties_are_broken_uniformly() -> None:
    n_problems, n_arms = 4000, 5
    first, _ = DoubleThompsonSampling(n_arms, n_problems, rng=np.random.default_rng(1)).select()
    counts = np.bincount(first, minlength=n_arms)
    expected = n_problems / n_arms
    assert np.all(np.abs(counts - expected) < 5 * np.sqrt(expected * (1 - 1 / n_arms)))


def test_finds_condorcet_winner() -> None:
    n_problems, n_arms = 200, 5
    rates = np.full((n_problems, n_arms, n_arms), 0.5)
    rates[:, 0, 1:] = 0.8  # arm 0 beats every other arm with probability 0.8
    rates[:, 1:, 0] = 0.2
    context = run_dts(rates, horizon=300, rng=np.random.default_rng(0))
    assert (context["arms_first"][:, -1] == 0).mean() > 0.9


def test_run_dts_shapes_and_determinism() -> None:
    rates = np.random.default_rng(0).uniform(size=(6, 4, 4))
    rates = np.triu(rates, 1) + np.tril(1 - rates.transpose(0, 2, 1), -1) + 0.5 * np.eye(4)
    a = run_dts(rates, horizon=30, rng=np.random.default_rng(7))
    b = run_dts(rates, horizon=30, rng=np.random.default_rng(7))
    assert set(a) == {"arms_first", "arms_second", "preferred"}
    for key, dtype in [("arms_first", np.int64), ("arms_second", np.int64), ("preferred", np.uint8)]:
        assert a[key].shape == (6, 30) and a[key].dtype == dtype
        np.testing.assert_array_equal(a[key], b[key])
    assert a["arms_first"].max() < 4 and set(np.unique(a["preferred"])) <= {0, 1}


def test_rejects_bad_inputs() -> None:
    dts = DoubleThompsonSampling(3, 2, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="shape"):
        dts.update(np.array([0]), np.array([1, 1]), np.array([1, 1]))
    with pytest.raises(ValueError, match="outside"):
        dts.update(np.array([0, 3]), np.array([1, 1]), np.array([1, 1]))
    with pytest.raises(ValueError, match="0/1"):
        dts.update(np.array([0, 0]), np.array([1, 1]), np.array([2, 1]))
    with pytest.raises(ValueError, match=r"\[P=2, T\]"):
        dts.observe_context(np.zeros((3, 4), dtype=np.int64), np.zeros((3, 4), dtype=np.int64),
                            np.zeros((3, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="alpha"):
        DoubleThompsonSampling(3, 2, alpha=0.0, rng=np.random.default_rng(0))
