"""Interval estimates for the results tables: IQM and mean with stratified bootstrap 95% confidence intervals,
the difference of two methods' means, and the probability of improvement (Agarwal et al., 2021, "Deep RL at the
Edge of the Statistical Precipice", the ``rliable`` library).

A method's scores are a matrix ``[runs, tasks]``: one row per training seed, one column per held-out task, each
cell that seed's mean over its episodes on that task (``per_task`` of an ``icprl evaluate`` JSON); an older JSON
gives ``[seeds, 1]`` (``per_seed``), whose interval covers the training seeds only (``Scores.tasks_recorded``).

* ``iqm``: the interquartile mean of all runs × tasks (rliable's ``metrics.aggregate_iqm``).
* ``interval``: point and percentile 95% interval under the stratified bootstrap: runs resampled *within* every
  task (rliable's ``StratifiedBootstrap``) and, with ``tasks=True``, the tasks too (``task_bootstrap``).
* ``difference``: ``statistic(A) − statistic(B)`` on the same resampled tasks (paired over tasks, independent
  over runs): "A beats B" holds only where the interval excludes 0.
* ``probability_of_improvement``: P(X > Y) per task over (run of A, run of B) pairs, ties ½ (Mann–Whitney U
  over n·m), averaged over tasks (rliable's ``metrics.probability_of_improvement``), with the same interval.
* ``performance_profile``: the fraction of runs × tasks above each threshold τ, with its bootstrap band.

The bootstrap is ours, vectorized over replicates with numpy: rliable's (``get_interval_estimates``, on ``arch``)
loops in Python per replicate and task, minutes per cell for the 200 bandit problems where this takes
milliseconds. Point estimates are rliable's functions; a test checks the intervals against rliable's.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rliable import metrics as rliable_metrics

REPS = 2000
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Scores:
    """A method's score matrix ``[runs, tasks]`` and whether its columns are held-out tasks (else seed means)."""

    values: np.ndarray
    tasks_recorded: bool

    @property
    def runs(self) -> int:
        return self.values.shape[0]

    @property
    def tasks(self) -> int:
        return self.values.shape[1]


@dataclass(frozen=True)
class Estimate:
    """A point estimate and its bootstrap ``CONFIDENCE`` interval (``low``, ``high``); one run: no interval."""

    point: float
    low: float
    high: float

    def excludes(self, value: float) -> bool:
        return bool(self.low > value or self.high < value)

    def as_dict(self) -> dict[str, float]:
        return {"point": self.point, "low": self.low, "high": self.high}


def scores_of(row: Mapping[str, Any], metric: str) -> Scores | None:
    """The score matrix of one results cell (``results[method][column]`` of an ``icprl evaluate`` JSON).

    ``per_task`` (seeds × tasks) when recorded, else ``per_seed`` as a column, else the single value
    (a reference row, a one-seed row without per-task values); None when the cell lacks ``metric``.
    """
    if "per_task" in row and metric in row["per_task"]:
        return Scores(np.asarray(row["per_task"][metric], dtype=np.float64), True)
    if "per_seed" in row and metric in row["per_seed"]:
        return Scores(np.asarray(row["per_seed"][metric], dtype=np.float64)[:, None], False)
    if metric in row and row[metric] is not None:
        return Scores(np.array([[float(row[metric])]]), False)
    return None


def iqm(values: np.ndarray) -> float:
    """Interquartile mean of every entry (rliable's ``aggregate_iqm``)."""
    return float(rliable_metrics.aggregate_iqm(np.asarray(values, dtype=np.float64)))


def _trimmed_means(samples: np.ndarray) -> np.ndarray:
    """IQM of each replicate: ``samples [reps, ...]`` -> ``[reps]``, scipy's ``trim_mean(·, 0.25)`` cut."""
    flat = np.sort(samples.reshape(len(samples), -1), axis=1)
    n = flat.shape[1]
    cut = int(0.25 * n)
    return flat[:, cut:n - cut].mean(axis=1)


STATISTICS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "iqm": _trimmed_means,
    "mean": lambda samples: samples.reshape(len(samples), -1).mean(axis=1),
}


def _resample(values: np.ndarray, rng: np.random.Generator, reps: int,
              task_index: np.ndarray | None) -> np.ndarray:
    """``[reps, runs, tasks]``: runs drawn with replacement within each task, then the tasks ``task_index``."""
    runs, tasks = values.shape
    rows = rng.integers(0, runs, size=(reps, runs, tasks))
    samples = values[rows, np.arange(tasks)[None, None, :]]
    if task_index is not None:
        samples = np.take_along_axis(samples, task_index[:, None, :].repeat(runs, axis=1), axis=2)
    return samples


def _tasks(rng: np.random.Generator, reps: int, tasks: int, resample: bool) -> np.ndarray | None:
    return rng.integers(0, tasks, size=(reps, tasks)) if resample and tasks > 1 else None


def _percentiles(replicates: np.ndarray) -> tuple[float, float]:
    alpha = (1 - CONFIDENCE) / 2
    low, high = np.quantile(replicates, [alpha, 1 - alpha])
    return float(low), float(high)


def interval(scores: Scores, statistic: str = "iqm", reps: int = REPS, seed: int = 0, tasks: bool = True) -> Estimate:
    """``statistic`` ("iqm" or "mean") of ``scores`` with its stratified bootstrap interval."""
    values = scores.values
    point = iqm(values) if statistic == "iqm" else float(values.mean())
    if values.size == 1:
        return Estimate(point, point, point)
    rng = np.random.default_rng(seed)
    samples = _resample(values, rng, reps, _tasks(rng, reps, scores.tasks, tasks))
    return Estimate(point, *_percentiles(STATISTICS[statistic](samples)))


def difference(a: Scores, b: Scores, statistic: str = "mean", reps: int = REPS, seed: int = 0) -> Estimate:
    """``statistic(a) − statistic(b)``; with the same tasks both are resampled on the same tasks (paired)."""
    stat = STATISTICS[statistic]
    point = float(stat(a.values[None])[0] - stat(b.values[None])[0])
    if a.values.size == 1 and b.values.size == 1:
        return Estimate(point, point, point)
    rng = np.random.default_rng(seed)
    if a.tasks == b.tasks:
        index_a = index_b = _tasks(rng, reps, a.tasks, True)
    else:
        index_a, index_b = _tasks(rng, reps, a.tasks, True), _tasks(rng, reps, b.tasks, True)
    replicates = stat(_resample(a.values, rng, reps, index_a)) - stat(_resample(b.values, rng, reps, index_b))
    return Estimate(point, *_percentiles(replicates))


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) of replicates ``x [reps, n, T]``, ``y [reps, m, T]`` -> ``[reps]`` (ties ½, mean over tasks)."""
    greater = (x[:, :, None, :] > y[:, None, :, :]).mean(axis=(1, 2))
    ties = (x[:, :, None, :] == y[:, None, :, :]).mean(axis=(1, 2))
    return (greater + 0.5 * ties).mean(axis=1)


def probability_of_improvement(a: Scores, b: Scores, higher_is_better: bool = True, reps: int = REPS,
                               seed: int = 0) -> Estimate:
    """P(a run of ``a`` beats a run of ``b`` on a task), averaged over the shared tasks, with its interval.

    ``higher_is_better=False`` (regret) compares the negated scores. Needs the same tasks in both.
    """
    if a.tasks != b.tasks:
        raise ValueError(f"probability of improvement needs the same tasks: {a.tasks} vs {b.tasks}")
    sign = 1.0 if higher_is_better else -1.0
    x, y = sign * a.values, sign * b.values
    point = float(_improvement(x[None], y[None])[0])
    rng = np.random.default_rng(seed)
    shared = _tasks(rng, reps, a.tasks, True)
    replicates = _improvement(_resample(x, rng, reps, shared), _resample(y, rng, reps, shared))
    return Estimate(point, *_percentiles(replicates))


def performance_profile(scores: Scores, thresholds: Sequence[float], reps: int = REPS, seed: int = 0
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction of runs × tasks with a score above each threshold τ, and its bootstrap band (low, high)."""
    taus = np.asarray(thresholds, dtype=np.float64)
    values = scores.values
    point = (values.reshape(-1)[:, None] > taus[None, :]).mean(axis=0)
    if values.size == 1:
        return point, point, point
    rng = np.random.default_rng(seed)
    samples = _resample(values, rng, reps, _tasks(rng, reps, scores.tasks, True)).reshape(reps, -1)
    fractions = (samples[:, :, None] > taus[None, None, :]).mean(axis=1)
    alpha = (1 - CONFIDENCE) / 2
    low, high = np.quantile(fractions, [alpha, 1 - alpha], axis=0)
    return point, low, high


def verdict(diff: Estimate, higher_is_better: bool = True) -> str:
    """"holds" when the interval of A − B excludes 0 on A's side, "reversed" on B's side, else "tie"."""
    if not diff.excludes(0.0):
        return "tie"
    better = diff.low > 0 if higher_is_better else diff.high < 0
    return "holds" if better else "reversed"


@dataclass(frozen=True)
class Metric:
    """The number a table is read by, and which way is better."""

    key: str
    label: str
    higher_is_better: bool


def main_metric(payload: dict[str, Any]) -> Metric:
    """Weak regret for bandit tables, else normalized return where the rows have it, else return."""
    first_row = next(iter(next(iter(payload["results"].values())).values()))
    if "weak_regret" in first_row:
        return Metric("weak_regret", "weak regret at h = H (lower is better)", False)
    if "normalized_return" in first_row:
        return Metric("normalized_return", "normalized return (higher is better)", True)
    return Metric("return", "return (higher is better)", True)
