"""Linear dueling-bandit task family (paper, appendix "Dueling Bandit Experiments").

All problems share fixed arm features φ(a) ~ N(0, I_d / d); a problem τ is a vector θ_τ ~ N(0, I_d / d)
with expected reward r_τ(a) = θ_τᵀ φ(a). A duel (a, a') is labelled by the Bradley–Terry model

    P(y = 1 | a, a', τ) = σ((r_τ(a) − r_τ(a')) / bt_temperature)        (the paper uses temperature 1)

and the goal is the best arm a* = argmax_a r_τ(a). The paper's Gaussian observation noise on r
(κ² = 0.3) plays no role here: labels depend on expected rewards only. Paper sizes: |A| = 20, d = 10,
H = 200.

Preference contexts (the paper's three behaviour policies: uniform pairs, Dirichlet, DTS) are dicts
``{"arms_first": int64 [n, H], "arms_second": int64 [n, H], "preferred": uint8 [n, H]}`` (1: the first arm
won); a context never carries θ or rewards. DTS's pairs may repeat an arm (a champion against itself).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.families.base import Family
from icprl_lightning.families.dueling_bandit.dts import run_dts
from icprl_lightning.preferences import preference_probability, sample_preferences
from icprl_lightning.validation import check_int, check_positive

Context = dict[str, np.ndarray]


class LinearDuelingBanditFamily(Family):
    """The shared-feature linear dueling bandit; the features are fixed by ``seed``.

    It has the sizes of a ``TaskFamily`` (no states: ``obs_dim`` 0; ``n_arms`` discrete actions; H) but no
    MDP: its datasets come from its own setting, ``data.settings.bandit_duels.BanditDuels``.
    """

    name = "dueling_bandit"
    metric_env = "bandit"
    obs_dim = 0

    def __init__(self, n_arms: int = 20, dim: int = 10, horizon: int = 200, seed: int = 0,
                 bt_temperature: float = 1.0, dts_alpha: float = 0.51):
        owner = "LinearDuelingBanditFamily"
        check_int(owner, "n_arms", n_arms, 2)  # a duel needs two arms
        check_int(owner, "dim", dim, 1)
        check_int(owner, "horizon", horizon, 1)
        check_positive(owner, "bt_temperature", bt_temperature)
        check_positive(owner, "dts_alpha", dts_alpha)
        self.n_arms = n_arms
        self.dim = dim
        self.horizon = horizon
        self.seed = seed
        self.bt_temperature = bt_temperature
        self.dts_alpha = dts_alpha
        self.features = np.random.default_rng(seed).normal(0.0, 1.0 / np.sqrt(dim), size=(n_arms, dim))
        self._sources: dict[str, Callable[[np.ndarray, np.random.Generator], Context]] = {
            "uniform": self.uniform_pairs_context,
            "dirichlet": self.dirichlet_context,
            "dts": self.dts_context,
        }

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=True, size=self.n_arms)

    def with_horizon(self, horizon: int) -> LinearDuelingBanditFamily:
        """The same problems (same features) with another horizon."""
        return LinearDuelingBanditFamily(self.n_arms, self.dim, horizon, self.seed, self.bt_temperature, self.dts_alpha)

    def config(self) -> dict[str, Any]:
        return {"family": self.name, "n_arms": self.n_arms, "dim": self.dim, "horizon": self.horizon,
                "bt_temperature": self.bt_temperature, "dts_alpha": self.dts_alpha, "seed": self.seed}

    @property
    def context_sources(self) -> tuple[str, ...]:
        """Names accepted by ``make_context``."""
        return tuple(self._sources)

    # --- tasks and their (privileged) rewards ----------------------------------------------------------

    def sample_tasks(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """θ ~ N(0, I_d / d) for ``n`` problems: ``[n, d]`` float64."""
        return rng.normal(0.0, 1.0 / np.sqrt(self.dim), size=(n, self.dim))

    def expected_rewards(self, theta: np.ndarray) -> np.ndarray:
        """r(a) = θᵀ φ(a) for every arm: ``[n, A]``."""
        return self._check_theta(theta) @ self.features.T

    def preference_probability(self, theta: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        """P(first ≻ second) = σ((r(first) − r(second)) / T); ``first``/``second`` are ``[n, ...]`` int."""
        rewards = self.expected_rewards(theta)
        return preference_probability(self._gather(rewards, first), self._gather(rewards, second),
                                      self.bt_temperature)

    def preference_matrix(self, theta: np.ndarray) -> np.ndarray:
        """P(i ≻ j) for every pair of arms: ``[n, A, A]`` with 1/2 on the diagonal."""
        rewards = self.expected_rewards(theta)
        return preference_probability(rewards[:, :, None], rewards[:, None, :], self.bt_temperature)

    def sample_labels(self, theta: np.ndarray, first: np.ndarray, second: np.ndarray,
                      rng: np.random.Generator) -> np.ndarray:
        """Bradley–Terry labels for duels ``[n, ...]``: uint8, 1 = the first arm is preferred."""
        rewards = self.expected_rewards(theta)
        return sample_preferences(self._gather(rewards, first), self._gather(rewards, second),
                                  self.bt_temperature, rng)

    # --- preference contexts (what a learner may see) --------------------------------------------------

    def make_context(self, source: str, theta: np.ndarray, rng: np.random.Generator) -> Context:
        """A context from the named behaviour policy (one of ``context_sources``)."""
        if source not in self._sources:
            raise ValueError(f"unknown context source {source!r}; expected one of {self.context_sources}")
        return self._sources[source](theta, rng)

    def uniform_pairs_context(self, theta: np.ndarray, rng: np.random.Generator) -> Context:
        """Each step duels a uniformly random ordered pair of distinct arms."""
        n = self._check_theta(theta).shape[0]
        first = rng.integers(0, self.n_arms, size=(n, self.horizon))
        # A uniform non-zero offset makes second uniform over the other A − 1 arms.
        second = (first + rng.integers(1, self.n_arms, size=(n, self.horizon))) % self.n_arms
        return self._labelled(theta, first, second, rng)

    def dirichlet_context(self, theta: np.ndarray, rng: np.random.Generator) -> Context:
        """Each problem draws w ~ Dirichlet(1_A); each step draws two distinct arms from w.

        The pair is sampled without replacement via the Gumbel-top-2 trick: the two largest of
        log w + Gumbel are distributed as first ~ w, second ~ w restricted to the other arms.
        Memory is ``n × H × A`` floats; chunk over problems for very large ``n``.
        """
        n = self._check_theta(theta).shape[0]
        weights = rng.dirichlet(np.ones(self.n_arms), size=n)  # [n, A]
        with np.errstate(divide="ignore"):  # a zero weight (never in practice) means "never drawn"
            keys = np.log(weights)[:, None, :] + rng.gumbel(size=(n, self.horizon, self.n_arms))
        top2 = np.argpartition(-keys, 1, axis=-1)[..., :2]  # [n, H, 2], unordered
        top2_keys = np.take_along_axis(keys, top2, axis=-1)
        order = np.argsort(-top2_keys, axis=-1)
        ranked = np.take_along_axis(top2, order, axis=-1)
        return self._labelled(theta, ranked[..., 0], ranked[..., 1], rng)

    def dts_context(self, theta: np.ndarray, rng: np.random.Generator) -> Context:
        """Double Thompson Sampling played online for H steps on each problem, BT labels."""
        return run_dts(self.preference_matrix(theta), self.horizon, rng, alpha=self.dts_alpha)

    def _labelled(self, theta: np.ndarray, first: np.ndarray, second: np.ndarray,
                  rng: np.random.Generator) -> Context:
        first = first.astype(np.int64)
        second = second.astype(np.int64)
        return {"arms_first": first, "arms_second": second,
                "preferred": self.sample_labels(theta, first, second, rng)}

    def _check_theta(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=np.float64)
        if theta.ndim != 2 or theta.shape[1] != self.dim:
            raise ValueError(f"theta must have shape [n, d={self.dim}], got {list(theta.shape)}")
        return theta

    def _gather(self, rewards: np.ndarray, arms: np.ndarray) -> np.ndarray:
        arms = np.asarray(arms)
        if arms.shape[:1] != rewards.shape[:1] or not np.issubdtype(arms.dtype, np.integer):
            raise ValueError(f"arms must be an integer array of shape [n={rewards.shape[0]}, ...], "
                             f"got {arms.dtype} {list(arms.shape)}")
        if arms.size and (arms.min() < 0 or arms.max() >= self.n_arms):
            raise ValueError(f"arm indices must lie in [0, {self.n_arms})")
        flat = np.take_along_axis(rewards, arms.reshape(arms.shape[0], -1), axis=1)
        return flat.reshape(arms.shape)
