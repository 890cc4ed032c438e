"""Thompson sampling on the features: a Laplace posterior over θ of Bradley–Terry regression, two samples.

The posterior over θ given the duels so far is approximated by N(θ̂, s²·H⁻¹), with θ̂ the mode of the log
posterior under the prior N(0, v·I) and H its negative Hessian there (``bt_posterior.laplace``; Laplace
approximation for Thompson sampling in logistic models: Chapelle & Li 2011, "An Empirical Evaluation of
Thompson Sampling", NeurIPS). Each round draws two independent samples θ¹, θ² and plays

    a  = argmax_a θ¹ᵀφ(a)
    a' = argmax_{b ≠ a} θ²ᵀφ(b)          (always a different arm)

the two-sample structure of Double Thompson Sampling (Wu & Liu 2016, "Double Thompson Sampling for
Dueling Bandits", NeurIPS) with the K-armed Beta posteriors replaced by the shared linear model (a different
posterior and pair rule: Li et al. 2024, "Feel-Good Thompson Sampling for Contextual Dueling Bandits", ICML).
It never self-duels, so the weak regret is 0 as soon as θ¹ ranks the best arm first. ``scale`` is the
posterior inflation of Agrawal & Goyal 2013 ("Thompson Sampling for Contextual Bandits with Linear Payoffs",
ICML; 1: the Laplace posterior); the knobs are chosen on training problems only (``tuning.py``).
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.families.dueling_bandit.bt_posterior import gaussian_samples
from icprl_lightning.families.dueling_bandit.linear_baselines import Duels, LinearDuelingLearner
from icprl_lightning.validation import check_positive


class BTThompsonSampling(LinearDuelingLearner):
    """Two-sample Thompson sampling on a Laplace Bradley–Terry posterior; see the module docstring."""

    def __init__(self, features: np.ndarray, n_problems: int, *, prior_var: float = 0.1, scale: float = 1.0,
                 temperature: float = 1.0, newton_steps: int = 5, rng: np.random.Generator):
        super().__init__(features, n_problems, prior_var=prior_var, temperature=temperature,
                         newton_steps=newton_steps, rng=rng)
        self.scale = check_positive("BTThompsonSampling", "scale", scale)

    def select(self) -> Duels:
        return self.pair_from_noise(self.rng.standard_normal((self.n_problems, 2, self.dim)))

    def pair_from_noise(self, noise: np.ndarray) -> Duels:
        """The duel for standard normal ``noise`` ``[P, 2, d]`` (sample 1 picks the first arm, sample 2 the second)."""
        if np.shape(noise) != (self.n_problems, 2, self.dim):
            raise ValueError(f"noise must have shape [{self.n_problems}, 2, {self.dim}], got {list(np.shape(noise))}")
        mode, precision = self.fit()
        utility = gaussian_samples(mode, precision, noise, self.scale) @ self.posterior.features.T  # [P, 2, A]
        first = utility[:, 0].argmax(-1)
        other = utility[:, 1].copy()
        other[self._problems, first] = -np.inf
        return first, other.argmax(-1)
