"""Bayesian Bradley–Terry regression on arm-feature differences, batched over problems.

The linear dueling bandit (``env.py``) labels a duel (a, a') by P(y = 1) = σ(θᵀ(φ(a) − φ(a')) / T), so a
context of comparisons is a logistic regression on the scaled differences x = (φ(a) − φ(a')) / T. With a
Gaussian prior θ ~ N(0, v·I) the log posterior is, up to a constant,

    log p(θ | D) = Σ_{i<j} [ B_ij log σ(θᵀx_ij) + B_ji log σ(−θᵀx_ij) ] − ‖θ‖² / (2v),

where B_ij counts the times arm i beat arm j. The counts are a sufficient statistic, so a context of any
length is held as a fixed ``[P, A, A]`` array (as in ``dts.py``) and every pass over the data costs
O(P · A² · d), not O(P · H · d). With v = 1/d this is the family's own prior.

* ``laplace``: the posterior mode by damped Newton steps (the log posterior is strictly concave, and a
  step is halved until the log posterior does not fall, so it cannot overshoot), and the precision
  (negative Hessian) there: the Laplace approximation N(mode, precision⁻¹) (MacKay 1992; used for
  Thompson sampling in logistic models by Chapelle & Li 2011, "An Empirical Evaluation of Thompson
  Sampling", NeurIPS).
* ``importance_sample``: self-normalized importance sampling with the (widened) Laplace Gaussian as the
  proposal, to check the approximation or to correct it.

Self-duels (a = a') carry no information (x = 0) and are dropped from the counts.
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.validation import check_int, check_positive

_STEP_SCALES = 0.5 ** np.arange(8)  # Newton step sizes tried, longest first
_CONVERGED = 1e-10  # a Newton step no longer than this in every coordinate ends the iterations


def win_counts(arms_first: np.ndarray, arms_second: np.ndarray, preferred: np.ndarray, n_arms: int) -> np.ndarray:
    """``wins[p, i, j]`` = times arm i beat arm j in problem p, from duels ``[P, H]``; self-duels dropped."""
    arms_first, arms_second, preferred = (np.asarray(x) for x in (arms_first, arms_second, preferred))
    if arms_first.ndim != 2 or arms_second.shape != arms_first.shape or preferred.shape != arms_first.shape:
        raise ValueError("arms_first, arms_second and preferred must share one shape [P, H], got "
                         f"{list(arms_first.shape)}, {list(arms_second.shape)}, {list(preferred.shape)}")
    check_duels(arms_first, arms_second, preferred, n_arms)
    won = preferred.astype(bool)
    winner = np.where(won, arms_first, arms_second).astype(np.int64)
    loser = np.where(won, arms_second, arms_first).astype(np.int64)
    problem = np.broadcast_to(np.arange(arms_first.shape[0])[:, None], arms_first.shape)
    informative = winner != loser
    flat = (problem * n_arms + winner) * n_arms + loser
    counts = np.bincount(flat[informative], minlength=arms_first.shape[0] * n_arms * n_arms)
    return counts.reshape(arms_first.shape[0], n_arms, n_arms)


def check_duels(first: np.ndarray, second: np.ndarray, preferred: np.ndarray, n_arms: int) -> None:
    """Arms are integers in [0, n_arms) and labels are 0/1 (1 = the first arm won); one line on failure."""
    for name, arms in (("first", first), ("second", second)):
        if not np.issubdtype(np.asarray(arms).dtype, np.integer):
            raise ValueError(f"{name} arms must be integers, got {np.asarray(arms).dtype}")
        if np.size(arms) and (np.min(arms) < 0 or np.max(arms) >= n_arms):
            raise ValueError(f"{name} arms must lie in [0, {n_arms}), got values in [{np.min(arms)}, {np.max(arms)}]")
    if np.size(preferred) and not np.isin(preferred, (0, 1)).all():
        raise ValueError("preferred must hold 0/1 labels (1 = first arm preferred)")


class BradleyTerryPosterior:
    """p(θ | wins) under the prior N(0, ``prior_var``·I) and the Bradley–Terry likelihood at ``temperature``.

    ``features`` is ``[A, d]`` (the family's φ); ``wins`` arrays are ``[P, A, A]``; θ arrays are ``[P, d]``
    or ``[P, S, d]`` (S samples per problem).
    """

    def __init__(self, features: np.ndarray, prior_var: float, temperature: float = 1.0):
        features = np.asarray(features, dtype=np.float64)
        if features.ndim != 2 or features.shape[0] < 2:
            raise ValueError(f"features must have shape [A >= 2, d], got {list(features.shape)}")
        self.prior_var = check_positive("BradleyTerryPosterior", "prior_var", prior_var)
        self.temperature = check_positive("BradleyTerryPosterior", "temperature", temperature)
        self.features = features
        self.n_arms, self.dim = features.shape
        self._i, self._j = np.triu_indices(self.n_arms, k=1)
        self.differences = (features[self._i] - features[self._j]) / temperature  # [M, d], M = A(A−1)/2 pairs i < j

    def pair_counts(self, wins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(B_ij, N_ij)`` for the pairs i < j, each ``[P, M]``: i's wins over j and the duels between them."""
        wins = np.asarray(wins)
        if wins.ndim != 3 or wins.shape[1:] != (self.n_arms, self.n_arms):
            raise ValueError(f"wins must have shape [P, {self.n_arms}, {self.n_arms}], got {list(wins.shape)}")
        forward, backward = wins[:, self._i, self._j], wins[:, self._j, self._i]
        return forward.astype(np.float64), (forward + backward).astype(np.float64)

    def log_posterior(self, theta: np.ndarray, wins: np.ndarray) -> np.ndarray:
        """Unnormalized log p(θ | wins) for θ ``[P, S, d]`` -> ``[P, S]``."""
        forward, total = self.pair_counts(wins)
        return self._log_posterior(theta, forward, total)

    def _log_posterior(self, theta: np.ndarray, forward: np.ndarray, total: np.ndarray) -> np.ndarray:
        z = theta @ self.differences.T  # [P, S, M]
        # B log σ(z) + (N − B) log σ(−z) = B z − N log(1 + e^z); the softplus is written to be stable
        softplus = np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z)))
        loglik = (forward[:, None] * z).sum(-1) - (total[:, None] * softplus).sum(-1)
        return loglik - 0.5 * (theta ** 2).sum(-1) / self.prior_var

    def gram(self, wins: np.ndarray) -> np.ndarray:
        """Σ over duels of x xᵀ plus the prior precision I/v: ``[P, d, d]`` (MaxInP's V_t)."""
        return self._weighted_gram(self.pair_counts(wins)[1])

    def laplace(self, wins: np.ndarray, start: np.ndarray | None = None, newton_steps: int = 20
                ) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mode ``[P, d]`` by at most ``newton_steps`` damped Newton steps from ``start`` (zeros if None),
        and the precision at the mode ``[P, d, d]``. The steps stop early once no coordinate of any problem's
        step exceeds ``_CONVERGED`` (the mode is then exact to rounding; warm starts get there in a few)."""
        check_int("BradleyTerryPosterior.laplace", "newton_steps", newton_steps, 1)
        forward, total = self.pair_counts(wins)
        theta = np.zeros((len(forward), self.dim)) if start is None else np.array(start, dtype=np.float64)
        if theta.shape != (len(forward), self.dim):
            raise ValueError(f"start must have shape [P={len(forward)}, d={self.dim}], got {list(theta.shape)}")
        current = self._log_posterior(theta[:, None], forward, total)[:, 0]
        for _ in range(newton_steps):
            gradient, precision = self._gradient_precision(theta, forward, total)
            step = np.linalg.solve(precision, gradient[..., None])[..., 0]  # [P, d]
            if not np.abs(step).max(initial=0.0) > _CONVERGED:
                return theta, precision
            # The full step where it does not lower the log posterior; elsewhere the longest of 1/2, 1/4, ...
            # that does not (no step if none does).
            full = self._log_posterior((theta + step)[:, None], forward, total)[:, 0]
            scale, value = np.ones(len(theta)), full
            short = ~self._no_worse(full, current)
            if short.any():
                candidates = theta[short, None] + _STEP_SCALES[None, 1:, None] * step[short, None]  # [p, K − 1, d]
                tried = self._log_posterior(candidates, forward[short], total[short])
                ok = self._no_worse(tried, current[short, None])
                pick = ok.argmax(-1)
                scale[short] = np.where(ok.any(-1), _STEP_SCALES[1:][pick], 0.0)
                value[short] = np.where(ok.any(-1), tried[np.arange(len(pick)), pick], current[short])
            theta, current = theta + scale[:, None] * step, value
        return theta, self._gradient_precision(theta, forward, total)[1]

    @staticmethod
    def _no_worse(new: np.ndarray, old: np.ndarray) -> np.ndarray:
        """new ≥ old up to rounding: a step that does not lower the log posterior."""
        return new >= old - 1e-12 * (1.0 + np.abs(old))

    def _gradient_precision(self, theta: np.ndarray, forward: np.ndarray, total: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
        """∇ log p(θ | D) ``[P, d]`` and −∇² log p(θ | D) ``[P, d, d]``."""
        prob = 1.0 / (1.0 + np.exp(-np.clip(theta @ self.differences.T, -700.0, 700.0)))  # σ(θᵀx), [P, M]
        gradient = (forward - total * prob) @ self.differences - theta / self.prior_var
        return gradient, self._weighted_gram(total * prob * (1.0 - prob))

    def _weighted_gram(self, weight: np.ndarray) -> np.ndarray:
        """Σ_m weight[p, m] x_m x_mᵀ + I/v, ``[P, d, d]`` (a batched matrix product, for BLAS speed)."""
        weighted = self.differences.T[None] * weight[:, None, :]  # [P, d, M]
        return weighted @ self.differences + np.eye(self.dim) / self.prior_var


def gaussian_samples(mean: np.ndarray, precision: np.ndarray, noise: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """θ = mean + scale · Σ^{1/2} z for standard normal ``noise`` ``[P, S, d]``, Σ = precision⁻¹ (Cholesky factor)."""
    root = np.linalg.cholesky(np.linalg.inv(precision))  # [P, d, d], root rootᵀ = Σ
    return mean[:, None] + scale * np.einsum("pde,pse->psd", root, noise)


def importance_sample(posterior: BradleyTerryPosterior, wins: np.ndarray, mode: np.ndarray, precision: np.ndarray,
                      n_samples: int, rng: np.random.Generator, widen: float = 1.2
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Self-normalized importance sampling of p(θ | wins) with proposal N(mode, widen² · precision⁻¹).

    Widening the proposal keeps the weights bounded where the true posterior's tails are heavier than the
    Laplace Gaussian's. Returns ``(samples [P, S, d], weights [P, S] summing to 1, effective sample size
    [P])``; an effective sample size near S means the Laplace approximation is already close.
    """
    check_int("importance_sample", "n_samples", n_samples, 1)
    check_positive("importance_sample", "widen", widen)
    noise = rng.standard_normal((len(mode), n_samples, posterior.dim))
    samples = gaussian_samples(mode, precision, noise, widen)
    # log q(θ) up to the same constant for every sample of a problem: −‖z‖²/2 (the Jacobian is shared)
    log_weights = posterior.log_posterior(samples, wins) + 0.5 * (noise ** 2).sum(-1)
    log_weights -= log_weights.max(-1, keepdims=True)
    weights = np.exp(log_weights)
    weights /= weights.sum(-1, keepdims=True)
    return samples, weights, 1.0 / (weights ** 2).sum(-1)
