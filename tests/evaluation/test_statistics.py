"""The interval estimates of ``reproduce.statistics`` against rliable's own and against hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest
from rliable import library as rly
from rliable import metrics as rliable_metrics

from icprl_lightning.reproduce.statistics import (
    Estimate,
    Scores,
    difference,
    interval,
    iqm,
    performance_profile,
    probability_of_improvement,
    scores_of,
    verdict,
)


def matrix(seed: int, runs: int = 3, tasks: int = 8, shift: float = 0.0) -> np.ndarray:
    return np.random.default_rng(seed).normal(shift, 1.0, size=(runs, tasks))


def test_point_estimates_are_rliables():
    x, y = matrix(0), matrix(1, shift=0.3)
    assert iqm(x) == pytest.approx(rliable_metrics.aggregate_iqm(x))
    poi = probability_of_improvement(Scores(x, True), Scores(y, True), reps=10)
    assert poi.point == pytest.approx(rliable_metrics.probability_of_improvement(x, y))


@pytest.mark.filterwarnings("ignore:random_state is deprecated:FutureWarning")  # arch, on what rliable passes it
def test_intervals_agree_with_rliables_stratified_bootstrap():
    """Same resampling scheme (runs within tasks), so the 95% intervals agree up to Monte Carlo error."""
    x = matrix(2, runs=5, tasks=6)
    ours = interval(Scores(x, True), "mean", reps=4000, tasks=False)
    _, theirs = rly.get_interval_estimates({"x": x}, lambda s: np.array([s.mean()]), reps=4000,
                                           random_state=np.random.RandomState(0))
    low, high = theirs["x"][:, 0]
    width = high - low
    assert ours.low == pytest.approx(low, abs=0.1 * width)
    assert ours.high == pytest.approx(high, abs=0.1 * width)


def test_the_interval_covers_the_point_and_widens_with_the_tasks_resampled():
    x = Scores(matrix(3, tasks=20), True)
    runs_only = interval(x, "mean", tasks=False)
    both = interval(x, "mean", tasks=True)
    assert runs_only.low <= runs_only.point <= runs_only.high
    assert both.high - both.low > runs_only.high - runs_only.low


def test_a_constant_matrix_has_a_zero_width_interval_and_a_single_value_no_interval():
    assert interval(Scores(np.full((3, 4), 2.5), True)) == Estimate(2.5, 2.5, 2.5)
    assert interval(Scores(np.array([[7.0]]), False)) == Estimate(7.0, 7.0, 7.0)


def test_difference_and_verdict_follow_the_interval():
    a, b = Scores(matrix(4, shift=3.0), True), Scores(matrix(5), True)
    diff = difference(a, b)
    assert diff.point == pytest.approx(a.values.mean() - b.values.mean())
    assert diff.low > 0 and verdict(diff) == "holds"
    assert verdict(difference(b, a)) == "reversed"
    assert verdict(difference(b, a), higher_is_better=False) == "holds"  # a regret: lower is better
    same = difference(Scores(matrix(6), True), Scores(matrix(6)[::-1], True))  # the same runs, reordered
    assert verdict(same) == "tie" and same.low < 0 < same.high


def test_probability_of_improvement_of_a_dominating_method_is_one():
    x = Scores(np.arange(12.0).reshape(3, 4) + 100, True)
    y = Scores(np.arange(12.0).reshape(3, 4), True)
    assert probability_of_improvement(x, y) == Estimate(1.0, 1.0, 1.0)
    assert probability_of_improvement(x, y, higher_is_better=False).point == 0.0
    tie = probability_of_improvement(y, y)
    assert tie.point == 0.5
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement(x, Scores(np.zeros((3, 5)), True))


def test_performance_profile_counts_runs_and_tasks_above_each_threshold():
    scores = Scores(np.array([[0.0, 1.0], [2.0, 3.0]]), True)
    point, low, high = performance_profile(scores, [-1.0, 0.5, 2.5, 9.0], reps=200)
    np.testing.assert_allclose(point, [1.0, 0.75, 0.25, 0.0])
    assert np.all(low <= point) and np.all(point <= high)


def test_scores_of_reads_per_task_then_per_seed_then_the_value():
    per_task = {"return": 1.0, "per_task": {"return": [[1.0, 2.0], [3.0, 4.0]]}, "per_seed": {"return": [1.5, 3.5]}}
    assert scores_of(per_task, "return").tasks_recorded
    assert scores_of(per_task, "return").values.shape == (2, 2)
    seeds = scores_of({"return": 2.5, "per_seed": {"return": [1.5, 3.5]}}, "return")
    assert not seeds.tasks_recorded and seeds.values.shape == (2, 1)
    assert scores_of({"return": 2.0}, "return").values.shape == (1, 1)
    assert scores_of({"return": 2.0}, "success") is None
