"""Double Thompson Sampling (DTS) for dueling bandits, batched over independent problems.

The paper's dueling-bandit baseline (appendix "Dueling Bandit Experiments"): DTS of Wu & Liu (2016),
"Double Thompson Sampling for Dueling Bandits", Algorithm 1. With B_ij the number of times arm i beat
arm j, N_ij = B_ij + B_ji and t the current round:

    u_ij = B_ij / N_ij + sqrt(α log t / N_ij)   (1 when N_ij = 0),   u_ii = 1/2
    l_ij = B_ij / N_ij − sqrt(α log t / N_ij)   (0 when N_ij = 0),   l_ii = 1/2
    C    = argmax_i Σ_{j≠i} 1(u_ij > 1/2)                            (upper Copeland candidates)
    a¹   = argmax_{i ∈ C} Σ_j 1(θ¹_ij > 1/2),  θ¹_ij ~ Beta(B_ij + 1, B_ji + 1) for i < j, θ¹_ji = 1 − θ¹_ij
    a²   = argmax_{i : l_{i a¹} ≤ 1/2} θ²_{i a¹},  θ²_{i a¹} ~ Beta(B_{i a¹} + 1, B_{a¹ i} + 1) for i ≠ a¹,
           θ²_{a¹ a¹} = 1/2

The challenger a² is drawn from the champion's *column*: θ²_{i a¹} estimates P(i beats a¹). Using the
champion's row instead (P(a¹ beats i)) picks the arm the champion beats most easily, the weakest one.

P problems run side by side as ``[P, A, A]`` count arrays; every step is vectorized over problems. The
paper also lets DTS "use the same context's comparisons" as the transformer: ``observe_context``
ingests an offline preference context before selection. A self-duel (a¹ = a²) carries no information
and leaves B unchanged, but it still counts as a round in t.
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.families.dueling_bandit.bt_posterior import win_counts
from icprl_lightning.families.dueling_bandit.linear_baselines import run_online


class DoubleThompsonSampling:
    """DTS on ``n_problems`` independent ``n_arms``-armed dueling bandits; all randomness from ``rng``.

    ``alpha`` scales the confidence radius; Wu & Liu's analysis takes α > 1/2 and their experiments 0.51.
    ``wins[p, i, j]`` counts the times arm i beat arm j in problem p; ``t`` is the index of the next round.
    """

    def __init__(self, n_arms: int, n_problems: int, alpha: float = 0.51, *, rng: np.random.Generator):
        if n_arms < 2:
            raise ValueError(f"n_arms must be >= 2, got {n_arms}")
        if n_problems < 1:
            raise ValueError(f"n_problems must be >= 1, got {n_problems}")
        if alpha <= 0:
            raise ValueError(f"alpha must be > 0, got {alpha}")
        self.n_arms = n_arms
        self.n_problems = n_problems
        self.alpha = alpha
        self.rng = rng
        self.wins = np.zeros((n_problems, n_arms, n_arms), dtype=np.int64)  # wins[p, i, j] = #(i beat j)
        self.t = 1  # index of the next round; the bounds use log t
        self._problems = np.arange(n_problems)
        self._upper_i, self._upper_j = np.triu_indices(n_arms, k=1)
        self._off_diagonal = ~np.eye(n_arms, dtype=bool)
        arms = np.eye(n_arms)
        self._pair_to_first, self._pair_to_second = arms[self._upper_i], arms[self._upper_j]  # [A(A-1)/2, A]

    def confidence_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Upper and lower confidence bounds ``(u, l)``, each ``[P, A, A]``, on P(i beats j)."""
        upper, lower = self._bounds(self.wins, self.wins.transpose(0, 2, 1))
        diag = np.arange(self.n_arms)
        upper[:, diag, diag] = 0.5
        lower[:, diag, diag] = 0.5
        return upper, lower

    def select(self) -> tuple[np.ndarray, np.ndarray]:
        """The next duel of every problem: ``(first [P], second [P])`` int64 arm indices."""
        first = self._champion()
        return first, self.challenger(first)

    def challenger(self, first: np.ndarray) -> np.ndarray:
        """The second arm DTS duels against the given first arms ``[P]``; returns ``[P]`` int64."""
        first = self._check_arms("first", first)
        p = self._problems
        # The champion's column: wins[p, i, first] counts i beating the champion.
        wins_vs_first, losses_vs_first = self.wins[p, :, first], self.wins[p, first, :]  # [P, A] each
        theta = self.rng.beta(wins_vs_first + 1, losses_vs_first + 1)
        theta[p, first] = 0.5
        # l_{first, first} = 1/2 by definition, so the champion itself is always eligible.
        eligible = self._bounds(wins_vs_first, losses_vs_first)[1] <= 0.5
        eligible[p, first] = True
        return np.where(eligible, theta, -np.inf).argmax(axis=-1)

    def update(self, first: np.ndarray, second: np.ndarray, preferred: np.ndarray) -> None:
        """Record one duel per problem; ``preferred[p] = 1`` means ``first[p]`` won."""
        first = self._check_arms("first", first)
        second = self._check_arms("second", second)
        won = self._check_labels(preferred, self.n_problems)
        winner = np.where(won, first, second)
        loser = np.where(won, second, first)
        # One duel per problem, so the fancy-indexed targets are distinct and += is exact.
        self.wins[self._problems, winner, loser] += (winner != loser).astype(np.int64)
        self.t += 1

    def observe_context(self, arms_first: np.ndarray, arms_second: np.ndarray, preferred: np.ndarray) -> None:
        """Ingest an offline context of T duels per problem (each ``[P, T]``) as if DTS had played them."""
        arms_first = np.asarray(arms_first)
        if arms_first.ndim != 2 or arms_first.shape[0] != self.n_problems:
            raise ValueError(f"arms_first must have shape [P={self.n_problems}, T], got {arms_first.shape}")
        self.wins += win_counts(arms_first, arms_second, preferred, self.n_arms)
        self.t += arms_first.shape[1]

    def _bounds(self, wins: np.ndarray, losses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Elementwise (u, l) from win and loss counts, with the N = 0 conventions (1 and 0)."""
        n = wins + losses
        safe_n = np.maximum(n, 1)
        mean = wins / safe_n
        radius = np.sqrt(self.alpha * np.log(self.t) / safe_n)
        return np.where(n > 0, mean + radius, 1.0), np.where(n > 0, mean - radius, 0.0)

    def _champion(self) -> np.ndarray:
        upper = self._bounds(self.wins, self.wins.transpose(0, 2, 1))[0]
        copeland_upper = ((upper > 0.5) & self._off_diagonal).sum(axis=-1)  # [P, A]
        candidates = copeland_upper == copeland_upper.max(axis=-1, keepdims=True)
        i, j = self._upper_i, self._upper_j
        theta = self.rng.beta(self.wins[:, i, j] + 1, self.wins[:, j, i] + 1)  # [P, A(A-1)/2], i < j
        # Σ_j 1(θ_ij > 1/2) as a product with pair-to-arm incidence matrices.
        copeland = (theta > 0.5) @ self._pair_to_first + (theta < 0.5) @ self._pair_to_second  # [P, A]
        # Copeland scores are integers, so a jitter in [0, 1/2) breaks ties uniformly without reordering.
        copeland += 0.5 * self.rng.random((self.n_problems, self.n_arms))
        return np.where(candidates, copeland, -np.inf).argmax(axis=-1)

    def _check_arms(self, name: str, arms: np.ndarray) -> np.ndarray:
        arms = np.asarray(arms)
        shape = (self.n_problems,)
        if arms.shape != shape or not np.issubdtype(arms.dtype, np.integer):
            raise ValueError(f"{name} must be an integer array of shape {list(shape)}, "
                             f"got {arms.dtype} {list(arms.shape)}")
        if arms.size and (arms.min() < 0 or arms.max() >= self.n_arms):
            raise ValueError(f"{name} holds arm indices outside [0, {self.n_arms})")
        return arms.astype(np.int64, copy=False)

    @staticmethod
    def _check_labels(preferred: np.ndarray, n_problems: int) -> np.ndarray:
        preferred = np.asarray(preferred)
        if preferred.shape != (n_problems,):
            raise ValueError(f"preferred must have shape [{n_problems}], got {list(preferred.shape)}")
        if preferred.size and not np.isin(preferred, (0, 1)).all():
            raise ValueError("preferred must hold 0/1 labels (1 = first arm preferred)")
        return preferred.astype(bool)


def run_dts(preference_matrix: np.ndarray, horizon: int, rng: np.random.Generator,
            alpha: float = 0.51) -> dict[str, np.ndarray]:
    """Run DTS online for ``horizon`` rounds on P problems and return the duels it played.

    ``preference_matrix[p, i, j]`` is P(i beats j) in problem p (``[P, A, A]``); each label is drawn
    from it. Returns ``{"arms_first", "arms_second": int64 [P, H], "preferred": uint8 [P, H]}``. DTS
    duels its champion against itself once confident, so pairs are not always distinct.
    """
    preference_matrix = np.asarray(preference_matrix, dtype=np.float64)
    if preference_matrix.ndim != 3 or preference_matrix.shape[1] != preference_matrix.shape[2]:
        raise ValueError(f"preference_matrix must have shape [P, A, A], got {list(preference_matrix.shape)}")
    n_problems, n_arms, _ = preference_matrix.shape
    return run_online(DoubleThompsonSampling(n_arms, n_problems, alpha, rng=rng), preference_matrix, horizon, rng)
