"""Feature-aware dueling-bandit baselines (``maxinp.MaxInP``, ``bt_thompson.BTThompsonSampling``): their shared
state and how they are run, online (``run_online``) and offline (``prefix_duels``, the protocol of
``evaluation/duels.py``; ``prefix_recommendations`` for ICPO's).

Unlike the K-armed DTS (``dts.py``) they model the family's structure, P(a ≻ a') = σ(θᵀ(φ(a) − φ(a')) / T), and
estimate θ from the comparisons (``bt_posterior.py``). They follow DTS's protocol (``update``,
``observe_context``, ``select``, ``recommend``), vectorized over P problems. Their hyperparameters are chosen
on training problems only (``tuning.py``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Protocol

import numpy as np

from icprl_lightning.families.dueling_bandit.bt_posterior import BradleyTerryPosterior, check_duels, win_counts
from icprl_lightning.validation import check_int


class Dueler(Protocol):
    """What ``run_online`` and ``prefix_duels`` play: a ``LinearDuelingLearner`` or DTS (``dts.py``)."""

    n_problems: int
    n_arms: int

    def select(self) -> tuple[np.ndarray, np.ndarray]: ...

    def update(self, first: np.ndarray, second: np.ndarray, preferred: np.ndarray) -> None: ...

    def recommend(self) -> np.ndarray: ...


Duels = tuple[np.ndarray, np.ndarray]


class LinearDuelingLearner(ABC):
    """Win counts and a warm-started Laplace fit of θ for ``n_problems`` problems sharing ``features`` [A, d].

    ``prior_var`` is the variance v of the Gaussian prior N(0, v·I) on θ (equivalently a ridge 1/v on the
    estimate); ``temperature`` the Bradley–Terry temperature the learner assumes; ``newton_steps`` the
    damped Newton steps per refit, warm-started from the previous mode. Subclasses define ``select``.
    """

    def __init__(self, features: np.ndarray, n_problems: int, *, prior_var: float, temperature: float = 1.0,
                 newton_steps: int = 5, rng: np.random.Generator):
        owner = type(self).__name__
        check_int(owner, "n_problems", n_problems, 1)
        check_int(owner, "newton_steps", newton_steps, 1)
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"{owner}: rng must be a numpy Generator, got {type(rng).__name__}")
        self.posterior = BradleyTerryPosterior(features, prior_var, temperature)
        self.n_arms, self.dim = self.posterior.n_arms, self.posterior.dim
        self.n_problems = n_problems
        self.newton_steps = newton_steps
        self.rng = rng
        self.wins = np.zeros((n_problems, self.n_arms, self.n_arms), dtype=np.int64)  # wins[p, i, j] = #(i beat j)
        self.t = 1  # index of the next round
        self._problems = np.arange(n_problems)
        self._mode = np.zeros((n_problems, self.dim))
        self._precision: np.ndarray | None = None  # None: the counts changed since the last fit

    def update(self, first: np.ndarray, second: np.ndarray, preferred: np.ndarray) -> None:
        """Record one duel per problem (each ``[P]``); ``preferred[p] = 1`` means ``first[p]`` won."""
        for name, x in (("first", first), ("second", second), ("preferred", preferred)):
            if np.shape(x) != (self.n_problems,):
                raise ValueError(f"{name} must have shape [P={self.n_problems}], got {list(np.shape(x))}")
        check_duels(first, second, preferred, self.n_arms)
        won = np.asarray(preferred).astype(bool)
        winner, loser = np.where(won, first, second), np.where(won, second, first)
        # One duel per problem, so the fancy-indexed targets are distinct and += is exact.
        self.wins[self._problems, winner, loser] += (winner != loser).astype(np.int64)
        self.t += 1
        self._precision = None

    def observe_context(self, arms_first: np.ndarray, arms_second: np.ndarray, preferred: np.ndarray) -> None:
        """Ingest T duels per problem (each ``[P, T]``) as if they had been played."""
        if np.ndim(arms_first) != 2 or np.shape(arms_first)[0] != self.n_problems:
            raise ValueError(f"arms_first must have shape [P={self.n_problems}, T], got {list(np.shape(arms_first))}")
        self.wins += win_counts(arms_first, arms_second, preferred, self.n_arms)
        self.t += np.shape(arms_first)[1]
        self._precision = None

    def fit(self) -> tuple[np.ndarray, np.ndarray]:
        """The Laplace posterior ``(mode [P, d], precision [P, d, d])`` of the current counts."""
        if self._precision is None:
            self._mode, self._precision = self.posterior.laplace(self.wins, self._mode, self.newton_steps)
        return self._mode, self._precision

    def utilities(self) -> np.ndarray:
        """Estimated utilities θ̂ᵀφ(a) at the posterior mode: ``[P, A]``."""
        return self.fit()[0] @ self.posterior.features.T

    def recommend(self) -> np.ndarray:
        """The arm with the highest estimated utility, ``[P]`` int64."""
        return self.utilities().argmax(-1)

    @abstractmethod
    def select(self) -> Duels:
        """The next duel of every problem: ``(first [P], second [P])`` int64 arm indices."""


def run_online(learner: Dueler, preference_matrix: np.ndarray, horizon: int,
               rng: np.random.Generator, recommend: bool = False) -> dict[str, np.ndarray]:
    """Play ``horizon`` rounds; labels y ~ Bernoulli(``preference_matrix[p, first, second]``) from ``rng``, drawn
    after each ``select`` (for DTS, ``dts.run_dts``, the same generator as its own draws).

    ``preference_matrix`` is ``[P, A, A]`` (``LinearDuelingBanditFamily.preference_matrix``); returns
    ``{"arms_first", "arms_second": int64 [P, H], "preferred": uint8 [P, H]}`` and, with
    ``recommend``, ``"recommended"`` int64 [P, H]: the learner's ``recommend``-ed arm after answer h.
    """
    check_int("run_online", "horizon", horizon, 1)
    matrix = np.asarray(preference_matrix, dtype=np.float64)
    if matrix.shape != (learner.n_problems, learner.n_arms, learner.n_arms):
        raise ValueError(f"preference_matrix must have shape [{learner.n_problems}, {learner.n_arms}, "
                         f"{learner.n_arms}], got {list(matrix.shape)}")
    out = {"arms_first": np.empty((learner.n_problems, horizon), dtype=np.int64),
           "arms_second": np.empty((learner.n_problems, horizon), dtype=np.int64),
           "preferred": np.empty((learner.n_problems, horizon), dtype=np.uint8)}
    if recommend:
        out["recommended"] = np.empty((learner.n_problems, horizon), dtype=np.int64)
    problems = np.arange(learner.n_problems)
    for h in range(horizon):
        first, second = learner.select()
        label = (rng.random(learner.n_problems) < matrix[problems, first, second]).astype(np.uint8)
        learner.update(first, second, label)
        out["arms_first"][:, h], out["arms_second"][:, h], out["preferred"][:, h] = first, second, label
        if recommend:  # the refit it needs is the one the next select uses
            out["recommended"][:, h] = learner.recommend()
    return out


def prefix_duels(learner: Dueler, arms_first: np.ndarray,
                 arms_second: np.ndarray, preferred: np.ndarray) -> Duels:
    """The learner's duel after each prefix D_{1:h}, h = 1..H, of a fixed context (each ``[P, H]``).

    Returns ``(first, second)`` int64 ``[P, H]``: observe comparison h, then select — as
    ``evaluation.duels.dts_duels`` does for DTS.
    """
    arms_first, arms_second, preferred = (np.asarray(x) for x in (arms_first, arms_second, preferred))
    if arms_first.ndim != 2 or arms_first.shape[0] != learner.n_problems:
        raise ValueError(f"arms_first must have shape [P={learner.n_problems}, H], got {list(arms_first.shape)}")
    first = np.empty(arms_first.shape, dtype=np.int64)
    second = np.empty(arms_first.shape, dtype=np.int64)
    for h in range(arms_first.shape[1]):
        learner.update(arms_first[:, h], arms_second[:, h], preferred[:, h])
        first[:, h], second[:, h] = learner.select()
    return first, second


def prefix_recommendations(learner: LinearDuelingLearner, arms_first: np.ndarray, arms_second: np.ndarray,
                           preferred: np.ndarray) -> np.ndarray:
    """The learner's ``recommend``-ed arm after each prefix D_{1:h} (``[P, H]`` int64): the first arm of
    ICPO's protocol, to be paired with a uniformly random other arm as ICPO's is."""
    arms_first = np.asarray(arms_first)
    if arms_first.ndim != 2 or arms_first.shape[0] != learner.n_problems:
        raise ValueError(f"arms_first must have shape [P={learner.n_problems}, H], got {list(arms_first.shape)}")
    best = np.empty(arms_first.shape, dtype=np.int64)
    for h in range(arms_first.shape[1]):
        learner.update(arms_first[:, h], np.asarray(arms_second)[:, h], np.asarray(preferred)[:, h])
        best[:, h] = learner.recommend()
    return best


def duel_regrets(expected_rewards: np.ndarray, first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weak min(Δ(a), Δ(a')) and strong (Δ(a) + Δ(a')) / 2 regret of duels ``[P, ...]`` given rewards ``[P, A]``."""
    rewards = np.asarray(expected_rewards, dtype=np.float64)
    first, second = np.asarray(first), np.asarray(second)
    if rewards.ndim != 2 or first.shape != second.shape or first.shape[:1] != rewards.shape[:1]:
        raise ValueError(f"expected_rewards must be [P, A] and first/second [P, ...] of one shape, got "
                         f"{list(rewards.shape)}, {list(first.shape)}, {list(second.shape)}")
    gap = rewards.max(-1, keepdims=True) - rewards  # Δ(a) ≥ 0, [P, A]
    flat = first.reshape(len(first), -1), second.reshape(len(second), -1)
    gap_first, gap_second = (np.take_along_axis(gap, arms, axis=1).reshape(first.shape) for arms in flat)
    return np.minimum(gap_first, gap_second), (gap_first + gap_second) / 2
