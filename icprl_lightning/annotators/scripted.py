"""B-Pref's scripted teachers (Lee et al. 2021, "B-Pref: Benchmarking Preference-Based RL"): a
Bradley–Terry oracle with explicit irrationality knobs.

For a trajectory pair the teacher's utility is the *myopic* return U(ξ) = Σ_h γ^(H−1−h) r_h (γ < 1
weighs the last steps most, as a person remembering the end of a clip); for a step pair it is the
oracle's A*(s, a) (one step: no myopia). With d = U(first) − U(second):

1. skip (``SKIP``) when both utilities are below ``skip_threshold``;
2. equal (``EQUAL``) when |d| < ``equal_threshold``;
3. otherwise y ~ Bernoulli(σ(β d)) (rationality β; β = inf: y = 1[d > 0], a fair coin at d = 0),
   then flipped with probability ε (a mistake).

B-Pref's thresholds are fractions of a segment's average return; here they are absolute values on the
utility's own scale (family-dependent: DarkRoom's A* is ≤ 0, its returns count steps on the goal).
Defaults make the perfectly rational oracle (β = inf, γ = 1, ε = 0, never skip, never equal). How a
stored context resolves EQUAL and SKIP: ``labels.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.labels import EQUAL, SKIP
from icprl_lightning.preferences import preference_probability
from icprl_lightning.validation import HyperparameterError, check_interval, check_nonnegative


class ScriptedTeacher(Annotator):
    """A B-Pref teacher; see the module docstring.

    Args:
        beta: rationality β > 0 (the Bradley–Terry temperature is 1/β); ``inf`` is deterministic.
        gamma: myopia γ in (0, 1]: trajectory step h of H weighs γ^(H−1−h).
        epsilon: mistake rate ε in [0, 1]: each decided label is flipped with this probability.
        skip_threshold: skip a pair when both utilities are below it (``-inf``: never).
        equal_threshold: call a pair equal when its utilities differ by less than it (0: never).
    """

    def __init__(self, beta: float = math.inf, gamma: float = 1.0, epsilon: float = 0.0,
                 skip_threshold: float = -math.inf, equal_threshold: float = 0.0) -> None:
        owner = type(self).__name__
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) or math.isnan(beta) or not beta > 0:
            raise HyperparameterError(f"{owner}: beta must be > 0 (inf for a deterministic teacher), got {beta!r}")
        if isinstance(skip_threshold, bool) or not isinstance(skip_threshold, (int, float)) or \
                math.isnan(skip_threshold) or skip_threshold == math.inf:
            raise HyperparameterError(f"{owner}: skip_threshold must be a number < inf (-inf: never skip), got "
                                      f"{skip_threshold!r}")
        self.beta = float(beta)
        self.gamma = check_interval(owner, "gamma", gamma, 0.0, 1.0, closed="right")
        self.epsilon = check_interval(owner, "epsilon", epsilon, 0.0, 1.0)
        self.skip_threshold = float(skip_threshold)
        self.equal_threshold = check_nonnegative(owner, "equal_threshold", equal_threshold)

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        return self._label(np.asarray(queries.utility, np.float64), np.asarray(queries.alt_utility, np.float64), rng)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        return self._label(self.myopic_return(queries.rewards_a), self.myopic_return(queries.rewards_b), rng)

    def myopic_return(self, rewards: np.ndarray) -> np.ndarray:
        """Σ_h γ^(H−1−h) r_h per row of ``rewards`` [n, H]."""
        horizon = rewards.shape[1]
        weights = self.gamma ** np.arange(horizon - 1, -1, -1, dtype=np.float64)
        return np.asarray(rewards, np.float64) @ weights

    def _label(self, first: np.ndarray, second: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        diff = first - second
        if math.isinf(self.beta):
            p = np.where(diff > 0, 1.0, np.where(diff < 0, 0.0, 0.5))
        else:
            p = preference_probability(first, second, 1.0 / self.beta)
        labels = (rng.random(diff.shape) < p).astype(np.uint8)
        mistake = rng.random(diff.shape) < self.epsilon
        labels[mistake] = 1 - labels[mistake]
        labels[np.abs(diff) < self.equal_threshold] = EQUAL
        labels[(first < self.skip_threshold) & (second < self.skip_threshold)] = SKIP
        return labels

    def init_args(self) -> dict[str, Any]:
        return {"beta": self.beta, "gamma": self.gamma, "epsilon": self.epsilon,
                "skip_threshold": self.skip_threshold, "equal_threshold": self.equal_threshold}
