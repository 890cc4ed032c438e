"""MaxInP ("Maximum Informative Pair"), a UCB-style linear dueling bandit, batched over problems.

Saha (2021), "Optimal Algorithms for Stochastic Contextual Preference Bandits", NeurIPS, algorithm
MaxInP. With x_ij = (φ(i) − φ(j)) / T the scaled feature difference of arms i and j, θ̂_t the regularized
maximum-likelihood estimate of the Bradley–Terry (logistic) model on the duels so far and
V_t = λI + Σ_s x_s x_sᵀ their Gram matrix:

    active set   C_t = { i : θ̂_tᵀ x_ij + β ‖x_ij‖_{V_t⁻¹} ≥ 0 for every arm j }
    duel         (a_t, a'_t) = argmax_{i, j ∈ C_t} ‖x_ij‖_{V_t⁻¹}

An arm stays active while no other arm beats it with confidence; among the active arms the pair whose
comparison is most uncertain is played. Once a single arm is left, it duels itself (weak regret 0, as
DTS's self-duels).

Choices of this implementation, beside the paper's:
* θ̂_t is the posterior mode under N(0, v·I) (``bt_posterior.laplace``), i.e. the MLE with ridge λ = 1/v,
  and V_t uses the same λ, so no initial random-exploration phase is needed to make V_t invertible (the
  paper explores uniformly until it is). With no data every arm is active and the first duel is the pair
  farthest apart in feature space.
* β, the confidence-width scale, is a tuned constant. The paper's β_t grows like √(d log t)/κ
  (κ = min σ′ over the parameter set), which is valid but very conservative at H = 200.
* The pair is ordered so that the first arm has the higher estimated utility; ties go to the lowest index.

Knobs: ``beta`` (β), ``prior_var`` (v = 1/λ), ``newton_steps`` (warm-started Newton steps per round);
choose them on training problems only (``tuning.py``).
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.families.dueling_bandit.linear_baselines import Duels, LinearDuelingLearner
from icprl_lightning.validation import check_nonnegative


class MaxInP(LinearDuelingLearner):
    """MaxInP on ``n_problems`` problems sharing ``features`` [A, d]; see the module docstring.

    It is deterministic given the duels it has seen; ``rng`` is kept for the common interface.
    """

    def __init__(self, features: np.ndarray, n_problems: int, *, beta: float = 1.0, prior_var: float = 0.1,
                 temperature: float = 1.0, newton_steps: int = 5, rng: np.random.Generator):
        super().__init__(features, n_problems, prior_var=prior_var, temperature=temperature,
                         newton_steps=newton_steps, rng=rng)
        self.beta = check_nonnegative("MaxInP", "beta", beta)
        self._scaled = self.posterior.features / self.posterior.temperature  # φ / T, [A, d]

    def widths(self) -> np.ndarray:
        """‖x_ij‖_{V_t⁻¹} for every ordered pair: ``[P, A, A]`` (0 on the diagonal)."""
        inverse = np.linalg.inv(self.posterior.gram(self.wins))  # [P, d, d]
        inner = self._scaled @ inverse @ self._scaled.T  # φ_aᵀ V⁻¹ φ_b / T², [P, A, A]
        diagonal = np.diagonal(inner, axis1=1, axis2=2)
        squared = diagonal[:, :, None] + diagonal[:, None, :] - 2.0 * inner
        return np.sqrt(np.maximum(squared, 0.0))

    def active_set(self, widths: np.ndarray | None = None) -> np.ndarray:
        """C_t as a mask ``[P, A]``: arms no other arm beats with confidence (the estimated best is always in)."""
        widths = self.widths() if widths is None else widths
        utility = self.utilities() / self.posterior.temperature  # θ̂ᵀφ / T, [P, A]
        optimistic_gap = utility[:, :, None] - utility[:, None, :] + self.beta * widths  # [P, i, j]
        return (optimistic_gap >= 0.0).all(-1)

    def select(self) -> Duels:
        widths = self.widths()
        active = self.active_set(widths)
        both = active[:, :, None] & active[:, None, :]
        score = np.where(both, widths, -np.inf).reshape(self.n_problems, -1)
        i, j = np.divmod(score.argmax(-1), self.n_arms)  # flat argmax: ties go to the lowest (i, j)
        utility = self.utilities()
        i_first = utility[self._problems, i] >= utility[self._problems, j]
        return np.where(i_first, i, j), np.where(i_first, j, i)
