"""The Bayes reference: the best any learner can do from the same comparisons, in the offline setting.

A held-out problem's θ is drawn from the family's prior N(0, I_d / d) and its context's labels from the
Bradley–Terry model, so given a context D the exact posterior is p(θ | D) ∝ N(θ; 0, I/d) Π σ(±θᵀx / T)
(``bt_posterior.py``). Averaged over problems drawn from the prior, no rule mapping D to a duel (a, a')
has lower expected regret than the Bayes rule, which minimizes the posterior expected regret:

* ``"weak"``: argmax_{a ≠ a'} E[max(r(a), r(a')) | D], since E[min(R* − r(a), R* − r(a')) | D] =
  E[R* | D] − E[max(r(a), r(a')) | D]; the Bayes-optimal duel for weak regret.
* ``"strong"``: a = a' = argmax_a E[θ | D]ᵀφ(a), the Bayes-optimal duel for strong regret when self-duels are
  allowed: E[(Δ(a) + Δ(a')) / 2 | D] is the mean of two terms each minimized by that arm (Δ(a) = R* − r(a)).
  It is also the Bayes-optimal single arm, the reference for ICPO's first arm.
* ``"random_second"``: the Bayes-optimal arm and a uniformly random other arm, ICPO's protocol (paper:
  the first arm by argmax, the second at random), so ICPO's weak regret has a like-for-like floor.

How the posterior expectations are computed (``posterior``):

* ``"laplace"`` (default): N(mode, precision⁻¹); E[θ | D] is the mode and E[max(·,·) | D] the average
  over ``n_samples`` Gaussian draws. Cheap enough for every prefix h = 1..H.
* ``"importance"``: the same draws from a widened Laplace proposal, self-normalized importance weights
  (``bt_posterior.importance_sample``), so the expectations converge to the exact posterior's.

``laplace_check`` compares the two. The reference is an expectation over problems: on a finite set of
held-out problems a learner can beat it by chance, within the standard error.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.families.dueling_bandit.bt_posterior import gaussian_samples, importance_sample
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.linear_baselines import Duels, LinearDuelingLearner, duel_regrets
from icprl_lightning.validation import check_choice, check_int

PAIR_RULES = ("weak", "strong", "random_second")
POSTERIORS = ("laplace", "importance")


class BayesReference(LinearDuelingLearner):
    """The Bayes rule's duel after the comparisons seen so far, under the prior N(0, ``prior_var``·I).

    Use ``for_family`` to take the prior and temperature from the family (v = 1/d, its T): only then is it
    the Bayes rule for the family's problems. ``newton_steps`` are warm-started per refit; ``rng`` draws
    the posterior samples (and the random second arm).
    """

    def __init__(self, features: np.ndarray, n_problems: int, *, prior_var: float, temperature: float = 1.0,
                 rule: str = "weak", posterior: str = "laplace", n_samples: int = 256, newton_steps: int = 5,
                 rng: np.random.Generator):
        super().__init__(features, n_problems, prior_var=prior_var, temperature=temperature,
                         newton_steps=newton_steps, rng=rng)
        self.rule = check_choice("BayesReference", "rule", rule, PAIR_RULES)
        self.posterior_kind = check_choice("BayesReference", "posterior", posterior, POSTERIORS)
        self.n_samples = check_int("BayesReference", "n_samples", n_samples, 1)
        self._duel = {"weak": self._weak_duel, "strong": self._strong_duel,
                      "random_second": self._random_second_duel}[rule]
        self._samples = {"laplace": self._laplace_samples, "importance": self._importance_samples}[posterior]

    @classmethod
    def for_family(cls, family: LinearDuelingBanditFamily, n_problems: int, *, rng: np.random.Generator,
                   **kwargs: Any) -> BayesReference:
        """The reference under the family's own prior (v = 1/d), features and temperature."""
        return cls(family.features, n_problems, prior_var=1.0 / family.dim, temperature=family.bt_temperature,
                   rng=rng, **kwargs)

    def posterior_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior draws of θ ``[P, S, d]`` and their weights ``[P, S]`` (each row sums to 1)."""
        return self._samples(*self.fit())

    def posterior_mean(self) -> np.ndarray:
        """E[θ | D], ``[P, d]``: the mode under ``"laplace"``, the weighted sample mean under ``"importance"``."""
        if self.posterior_kind == "laplace":
            return self.fit()[0]
        samples, weights = self.posterior_samples()
        return np.einsum("ps,psd->pd", weights, samples)

    def bayes_arm(self) -> np.ndarray:
        """argmax_a E[θ | D]ᵀφ(a), ``[P]``: the Bayes-optimal single arm."""
        return (self.posterior_mean() @ self.posterior.features.T).argmax(-1)

    def select(self) -> Duels:
        return self._duel()

    def _weak_duel(self) -> Duels:
        return weak_pair(*self.posterior_samples(), self.posterior.features)

    def _strong_duel(self) -> Duels:
        best = self.bayes_arm()
        return best, best.copy()

    def _random_second_duel(self) -> Duels:
        best = self.bayes_arm()
        # A uniform non-zero offset makes the second arm uniform over the other A − 1 arms.
        return best, (best + self.rng.integers(1, self.n_arms, size=self.n_problems)) % self.n_arms

    def _laplace_samples(self, mode: np.ndarray, precision: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        noise = self.rng.standard_normal((self.n_problems, self.n_samples, self.dim))
        return gaussian_samples(mode, precision, noise), np.full((self.n_problems, self.n_samples), 1 / self.n_samples)

    def _importance_samples(self, mode: np.ndarray, precision: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        samples, weights, _ = importance_sample(self.posterior, self.wins, mode, precision, self.n_samples, self.rng)
        return samples, weights


def weak_pair(samples: np.ndarray, weights: np.ndarray, features: np.ndarray) -> Duels:
    """argmax over distinct arms a, a' of Σ_s w_s max(u_s(a), u_s(a')), u_s = θ_sᵀφ; the first arm of the
    duel is the one of higher posterior mean utility. ``samples [P, S, d]``, ``weights [P, S]``."""
    utility = samples @ np.asarray(features).T  # [P, S, A]
    n_problems, _, n_arms = utility.shape
    score = np.empty((n_problems, n_arms, n_arms))
    for arm in range(n_arms):  # one arm at a time keeps memory at [P, S, A]
        score[:, arm] = (weights[:, None] @ np.maximum(utility[:, :, arm:arm + 1], utility))[:, 0]
    score[:, np.arange(n_arms), np.arange(n_arms)] = -np.inf
    i, j = np.divmod(score.reshape(n_problems, -1).argmax(-1), n_arms)
    mean = np.einsum("ps,psa->pa", weights, utility)
    problems = np.arange(n_problems)
    i_first = mean[problems, i] >= mean[problems, j]
    return np.where(i_first, i, j), np.where(i_first, j, i)


def laplace_check(family: LinearDuelingBanditFamily, theta: np.ndarray, context: dict[str, np.ndarray],
                  rng: np.random.Generator, n_samples: int = 4000) -> dict[str, float]:
    """How close the Laplace approximation is on these problems, after their whole ``context`` (``[P, H]``).

    Returns the mean and minimum effective sample size as a share of ``n_samples``, the mean and maximum
    Mahalanobis distance (in Laplace posterior standard deviations) of the importance-sampled posterior mean
    from the Laplace mode, the share of problems whose Bayes arm is the same under both, and the mean regret
    of the Bayes arm under each.
    """
    reference = BayesReference.for_family(family, len(theta), rng=rng, rule="strong", n_samples=n_samples,
                                          newton_steps=50)
    reference.observe_context(context["arms_first"], context["arms_second"], context["preferred"])
    mode, precision = reference.fit()
    samples, weights, ess = importance_sample(reference.posterior, reference.wins, mode, precision, n_samples, rng)
    mean = (weights[..., None] * samples).sum(1)
    offset = mean - mode
    distance = np.sqrt(np.einsum("pd,pde,pe->p", offset, precision, offset))
    features = family.features.T
    laplace_arm, exact_arm = (mode @ features).argmax(-1), (mean @ features).argmax(-1)
    rewards = family.expected_rewards(theta)
    laplace_regret = duel_regrets(rewards, laplace_arm, laplace_arm)[0]
    exact_regret = duel_regrets(rewards, exact_arm, exact_arm)[0]
    return {"problems": len(theta), "comparisons": int(np.shape(context["preferred"])[1]),
            "ess_share_mean": float((ess / n_samples).mean()), "ess_share_min": float((ess / n_samples).min()),
            "mean_offset_sd_mean": float(distance.mean()), "mean_offset_sd_max": float(distance.max()),
            "same_bayes_arm": float((laplace_arm == exact_arm).mean()),
            "regret_laplace_arm": float(laplace_regret.mean()), "regret_importance_arm": float(exact_regret.mean())}
