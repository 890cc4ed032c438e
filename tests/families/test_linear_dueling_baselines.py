"""Feature-aware dueling-bandit baselines (MaxInP, BT Thompson sampling) and the Bayes reference.

Small cases checked by hand or by brute force: the Laplace mode against a closed-form MLE and a grid
maximum, importance sampling against a grid posterior mean, the Thompson pair rule, MaxInP's widths and
active set, the Bayes weak-regret pair; then learning, determinism and vectorized-vs-loop equality.
"""

from __future__ import annotations

import numpy as np
import pytest

from icprl_lightning.data.settings.bandit_duels import BanditDuels
from icprl_lightning.families.dueling_bandit.bayes import BayesReference, weak_pair
from icprl_lightning.families.dueling_bandit.bt_posterior import (
    BradleyTerryPosterior,
    gaussian_samples,
    importance_sample,
    win_counts,
)
from icprl_lightning.families.dueling_bandit.bt_thompson import BTThompsonSampling
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.linear_baselines import (
    duel_regrets,
    prefix_duels,
    prefix_recommendations,
    run_online,
)
from icprl_lightning.families.dueling_bandit.maxinp import MaxInP
from icprl_lightning.families.dueling_bandit.tuning import training_problems, tune

# Three arms in the plane: the origin and the two unit vectors.
UNIT = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def _context(first: list[int], second: list[int], preferred: list[int]) -> tuple[np.ndarray, ...]:
    return tuple(np.array([x]) for x in (first, second, preferred))


def _grid_posterior(posterior: BradleyTerryPosterior, wins: np.ndarray, half_width: float, step: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Points ``[G, 2]`` of a square grid and their unnormalized log posterior ``[G]`` (one problem)."""
    axis = np.arange(-half_width, half_width + step / 2, step)
    points = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    return points, posterior.log_posterior(points[None], wins)[0]


def _random_context(rng: np.random.Generator, n_problems: int, n_arms: int, horizon: int) -> tuple[np.ndarray, ...]:
    first = rng.integers(0, n_arms, size=(n_problems, horizon))
    second = rng.integers(0, n_arms, size=(n_problems, horizon))
    return first, second, rng.integers(0, 2, size=(n_problems, horizon)).astype(np.uint8)


def _easy_problems(n_problems: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Five arms on the unit circle, θ = 4 φ(a*) for a random a*: a* leads the next arm by 4(1 − cos 72°) ≈ 2.8."""
    angles = 2 * np.pi * np.arange(5) / 5
    features = np.stack([np.cos(angles), np.sin(angles)], -1)
    return features, 4.0 * features[rng.integers(0, 5, size=n_problems)]


def _bt_matrix(features: np.ndarray, theta: np.ndarray) -> np.ndarray:
    rewards = theta @ features.T
    return 1.0 / (1.0 + np.exp(-(rewards[:, :, None] - rewards[:, None, :])))


# ---- the posterior ------------------------------------------------------------------------------------

def test_win_counts_hand_made_and_self_duels_dropped() -> None:
    wins = win_counts(*_context([1, 1, 2, 0, 2], [0, 0, 0, 2, 2], [1, 0, 1, 1, 0]), n_arms=3)
    expected = np.zeros((1, 3, 3), dtype=np.int64)
    expected[0, 1, 0], expected[0, 0, 1], expected[0, 2, 0], expected[0, 0, 2] = 1, 1, 1, 1
    np.testing.assert_array_equal(wins, expected)  # the self-duel (2, 2) counts for nothing


def test_laplace_mode_is_the_closed_form_mle() -> None:
    # Arm 1 beats arm 0 in 3 of 4 duels, arm 2 beats arm 0 in 1 of 4; x = φ(i) − φ(0) = e_i, so the
    # likelihood separates: σ(θ₁) = 3/4 and σ(θ₂) = 1/4, i.e. θ = (log 3, −log 3) under a flat prior.
    wins = win_counts(*_context([1, 1, 1, 0, 2, 0, 0, 0], [0, 0, 0, 1, 0, 2, 2, 2], [1, 1, 1, 1, 1, 1, 1, 1]), 3)
    mode, precision = BradleyTerryPosterior(UNIT, prior_var=1e8).laplace(wins, newton_steps=30)
    np.testing.assert_allclose(mode[0], [np.log(3), -np.log(3)], atol=1e-6)
    # Fisher information: 4 · σ(1 − σ) = 4 · 3/16 on each axis
    np.testing.assert_allclose(precision[0], np.diag([0.75, 0.75]), atol=1e-6)


def test_laplace_mode_and_precision_match_brute_force() -> None:
    posterior = BradleyTerryPosterior(np.array([[0.3, -1.0], [1.2, 0.4], [-0.5, 0.9]]), prior_var=0.5,
                                      temperature=0.7)
    wins = win_counts(*_context([0, 1, 1, 2, 2, 0, 1, 2], [1, 0, 2, 1, 0, 2, 2, 0], [1, 1, 1, 0, 1, 0, 1, 1]), 3)
    mode, precision = posterior.laplace(wins)
    points, log_post = _grid_posterior(posterior, wins, half_width=3.0, step=0.005)
    np.testing.assert_allclose(mode[0], points[log_post.argmax()], atol=0.005)
    # the precision is the negative Hessian of the log posterior: central finite differences
    eps, hessian = 1e-4, np.zeros((2, 2))
    for a in range(2):
        for b in range(2):
            shift_a, shift_b = eps * np.eye(2)[a], eps * np.eye(2)[b]
            probes = np.stack([mode[0] + shift_a + shift_b, mode[0] + shift_a - shift_b,
                               mode[0] - shift_a + shift_b, mode[0] - shift_a - shift_b])
            f = posterior.log_posterior(probes[None], wins)[0]
            hessian[a, b] = (f[0] - f[1] - f[2] + f[3]) / (4 * eps ** 2)
    np.testing.assert_allclose(precision[0], -hessian, rtol=1e-4)


def test_importance_sampling_matches_grid_posterior_mean() -> None:
    posterior = BradleyTerryPosterior(UNIT * 2.0, prior_var=1.0)
    # few duels: the posterior is visibly skewed, its mean away from the Laplace mode
    wins = win_counts(*_context([1, 2, 1], [0, 0, 2], [1, 1, 1]), 3)
    mode, precision = posterior.laplace(wins)
    points, log_post = _grid_posterior(posterior, wins, half_width=6.0, step=0.02)
    weights = np.exp(log_post - log_post.max())
    grid_mean = (weights[:, None] * points).sum(0) / weights.sum()
    samples, is_weights, ess = importance_sample(posterior, wins, mode, precision, 40_000, np.random.default_rng(0))
    np.testing.assert_allclose((is_weights[0, :, None] * samples[0]).sum(0), grid_mean, atol=0.02)
    assert np.abs(grid_mean - mode[0]).max() > 0.05  # the check can tell the mean from the mode
    assert ess[0] > 0.3 * 40_000


def test_gaussian_samples_use_the_inverse_precision() -> None:
    noise = np.array([[[1.0, 1.0], [-2.0, 0.5]]])
    samples = gaussian_samples(np.array([[1.0, -1.0]]), np.array([[[4.0, 0.0], [0.0, 1.0]]]), noise, scale=2.0)
    np.testing.assert_allclose(samples[0], [[1.0 + 1.0, -1.0 + 2.0], [1.0 - 2.0, -1.0 + 1.0]])


# ---- the learners' rules ------------------------------------------------------------------------------

def test_thompson_pair_hand_computed_and_always_distinct() -> None:
    features = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    ts = BTThompsonSampling(features, 1, prior_var=1.0, scale=1.0, rng=np.random.default_rng(0))
    # no data: mode 0, precision I, so θ¹ = (0.5, 2) -> utilities (0.5, 2, −0.5), first = arm 1; θ² = (0.5, 3)
    # would pick arm 1 again, so the second is the best of the others: arm 0.
    first, second = ts.pair_from_noise(np.array([[[0.5, 2.0], [0.5, 3.0]]]))
    assert (first[0], second[0]) == (1, 0)
    many = BTThompsonSampling(np.random.default_rng(1).normal(size=(6, 3)), 40, rng=np.random.default_rng(2))
    many.observe_context(*_random_context(np.random.default_rng(3), 40, 6, 30))
    for _ in range(20):
        first, second = many.select()
        assert (first != second).all()


def test_maxinp_widths_and_first_duel_hand_computed() -> None:
    maxinp = MaxInP(UNIT, 1, beta=1.0, prior_var=4.0, temperature=0.5, rng=np.random.default_rng(0))
    # no data: V = I / 4, so ‖x_ij‖_{V⁻¹} = 2 · ‖φ(i) − φ(j)‖ / T
    expected = 4.0 * np.linalg.norm(UNIT[:, None] - UNIT[None], axis=-1)
    np.testing.assert_allclose(maxinp.widths()[0], expected)
    assert maxinp.active_set().all()
    assert sorted(int(a[0]) for a in maxinp.select()) == [1, 2]  # the farthest pair, √2 apart


def test_maxinp_active_set_shrinks_to_the_best_arm_without_noise() -> None:
    features = np.array([[1.0, 0.0], [0.6, 0.5], [0.0, 1.0], [-0.7, 0.2]])
    theta = np.array([[1.0, 0.3]])  # rewards 1.0, 0.75, 0.3, −0.64: arm 0 is best
    rewards = theta @ features.T
    noiseless = (rewards[:, :, None] > rewards[:, None, :]).astype(float) + 0.5 * np.eye(4)
    maxinp = MaxInP(features, 1, beta=1.0, prior_var=1.0, rng=np.random.default_rng(0))
    sizes = []
    for _ in range(60):
        active = maxinp.active_set()[0]
        assert active[0], "the best arm left the active set"
        sizes.append(int(active.sum()))
        first, second = maxinp.select()
        label = (noiseless[0, first, second] > 0.5).astype(np.uint8)
        maxinp.update(first, second, label)
    assert sizes[0] == 4 and sizes[-1] == 1
    assert sizes == sorted(sizes, reverse=True), sizes  # never grows back
    assert tuple(int(a[0]) for a in maxinp.select()) == (0, 0)  # a single arm left duels itself


def test_bayes_weak_pair_is_not_the_top_two_by_mean() -> None:
    # Two equally likely θ's over three one-hot arms: E[max(u₀, u₁)] = 1 beats 0.95 for either pair with
    # arm 2, although arm 2 has the highest mean utility (0.9 vs 0.5).
    samples = np.array([[[1.0, 0.0, 0.9], [0.0, 1.0, 0.9]]])
    first, second = weak_pair(samples, np.full((1, 2), 0.5), np.eye(3))
    assert sorted([int(first[0]), int(second[0])]) == [0, 1]
    reference = BayesReference(UNIT, 1, prior_var=1.0, rule="strong", rng=np.random.default_rng(0))
    reference.observe_context(*_context([1, 1], [2, 0], [1, 1]))
    best = int(reference.utilities().argmax())
    assert best == 1 and [int(a[0]) for a in reference.select()] == [1, 1]


def test_bayes_weak_pair_matches_a_grid_posterior() -> None:
    features = np.array([[1.0, 0.2], [0.1, 1.0], [-0.8, 0.3], [0.6, -0.9]])
    reference = BayesReference(features, 1, prior_var=1.0, posterior="importance", n_samples=20_000,
                               rng=np.random.default_rng(0))
    reference.observe_context(*_context([0, 1, 3, 2, 0], [1, 3, 2, 0, 3], [0, 1, 1, 0, 1]))
    points, log_post = _grid_posterior(reference.posterior, reference.wins, half_width=6.0, step=0.02)
    weights = np.exp(log_post - log_post.max())
    utility = points @ features.T  # [G, A]
    score = np.array([[weights @ np.maximum(utility[:, a], utility[:, b]) for b in range(4)] for a in range(4)])
    score /= weights.sum()
    np.fill_diagonal(score, -np.inf)
    ranked = np.sort(score.ravel())[::-2]  # each unordered pair once, best first
    assert ranked[0] - ranked[1] > 0.02  # a clear winner, well above the Monte Carlo error
    best = set(np.unravel_index(score.argmax(), score.shape))
    assert {int(a[0]) for a in reference.select()} == best
    grid_mean = (weights[:, None] * points).sum(0) / weights.sum()
    assert int(reference.bayes_arm()[0]) == int((grid_mean @ features.T).argmax())


def test_bayes_reference_beats_the_baselines_on_problems_from_the_prior() -> None:
    family = LinearDuelingBanditFamily(n_arms=6, dim=3, horizon=10, seed=3)
    theta = family.sample_tasks(2000, np.random.default_rng(0))
    context = family.uniform_pairs_context(theta, np.random.default_rng(1))
    learners = {"bayes": BayesReference.for_family(family, 2000, rng=np.random.default_rng(2), n_samples=128),
                "maxinp": MaxInP(family.features, 2000, beta=0.3, prior_var=0.1, rng=np.random.default_rng(2)),
                "bt_thompson": BTThompsonSampling(family.features, 2000, prior_var=0.3, scale=0.3,
                                                  rng=np.random.default_rng(2))}
    weak = {}
    for name, learner in learners.items():
        learner.observe_context(context["arms_first"], context["arms_second"], context["preferred"])
        weak[name] = duel_regrets(family.expected_rewards(theta), *learner.select())[0]
    for name in ("maxinp", "bt_thompson"):
        gap = weak[name] - weak["bayes"]  # paired over problems
        assert gap.mean() > 3 * gap.std(ddof=1) / np.sqrt(len(gap)), name


def test_duel_regrets_hand_computed() -> None:
    weak, strong = duel_regrets(np.array([[1.0, 0.5, -1.0]]), np.array([[0, 1, 2]]), np.array([[2, 2, 1]]))
    np.testing.assert_allclose(weak, [[0.0, 0.5, 0.5]])
    np.testing.assert_allclose(strong, [[1.0, 1.25, 1.25]])  # Δ = [0, 0.5, 2]: (0 + 2) / 2, (0.5 + 2) / 2 twice


# ---- learning, determinism, vectorization -------------------------------------------------------------

@pytest.mark.parametrize("make", [
    lambda f, n, rng: MaxInP(f, n, beta=2.0, prior_var=10.0, rng=rng),
    lambda f, n, rng: BTThompsonSampling(f, n, prior_var=10.0, rng=rng),
    lambda f, n, rng: BayesReference(f, n, prior_var=10.0, rng=rng, n_samples=64),
], ids=["maxinp", "bt_thompson", "bayes_weak"])
def test_weak_regret_vanishes_on_an_easy_problem(make) -> None:
    rng = np.random.default_rng(0)
    features, theta = _easy_problems(20, rng)
    duels = run_online(make(features, 20, np.random.default_rng(1)), _bt_matrix(features, theta), 120, rng)
    weak = duel_regrets(theta @ features.T, duels["arms_first"], duels["arms_second"])[0]
    assert weak[:, 0].mean() > 0.5  # not solved before it has data
    assert weak[:, -30:].mean() < 0.02


def test_runs_are_deterministic_under_a_seed() -> None:
    family = LinearDuelingBanditFamily(n_arms=6, dim=3, horizon=15, seed=2)
    theta = family.sample_tasks(8, np.random.default_rng(0))

    def run(learner_seed: int) -> dict[str, np.ndarray]:
        ts = BTThompsonSampling(family.features, 8, rng=np.random.default_rng(learner_seed))
        return run_online(ts, family.preference_matrix(theta), 15, np.random.default_rng(9))

    one, again, other = run(5), run(5), run(6)
    for key in one:
        np.testing.assert_array_equal(one[key], again[key])
    assert any((one[k] != other[k]).any() for k in one)


def test_vectorized_equals_a_per_problem_loop() -> None:
    rng = np.random.default_rng(4)
    features = rng.normal(size=(7, 3)) / np.sqrt(3)
    first, second, preferred = _random_context(rng, 3, 7, 25)
    vectorized = prefix_duels(MaxInP(features, 3, beta=0.5, rng=np.random.default_rng(0)), first, second, preferred)
    for p in range(3):
        alone = prefix_duels(MaxInP(features, 1, beta=0.5, rng=np.random.default_rng(0)),
                             first[p:p + 1], second[p:p + 1], preferred[p:p + 1])
        for got, want in zip(vectorized, alone, strict=True):
            np.testing.assert_array_equal(got[p], want[0])
    noise = rng.normal(size=(3, 2, 3))
    ts = BTThompsonSampling(features, 3, scale=0.7, rng=np.random.default_rng(0))
    ts.observe_context(first, second, preferred)
    pair = ts.pair_from_noise(noise)
    for p in range(3):
        one = BTThompsonSampling(features, 1, scale=0.7, rng=np.random.default_rng(0))
        one.observe_context(first[p:p + 1], second[p:p + 1], preferred[p:p + 1])
        np.testing.assert_allclose(one.fit()[0][0], ts.fit()[0][p], atol=1e-10)
        assert tuple(int(a[0]) for a in one.pair_from_noise(noise[p:p + 1])) == (pair[0][p], pair[1][p])


def test_observe_context_matches_sequential_updates() -> None:
    features = np.random.default_rng(0).normal(size=(5, 2))
    context = _random_context(np.random.default_rng(1), 4, 5, 30)
    offline = MaxInP(features, 4, rng=np.random.default_rng(0))
    offline.observe_context(*context)
    online = MaxInP(features, 4, rng=np.random.default_rng(0))
    for h in range(30):
        online.update(*(x[:, h] for x in context))
    np.testing.assert_array_equal(offline.wins, online.wins)
    assert offline.t == online.t == 31
    np.testing.assert_allclose(offline.fit()[0], online.fit()[0], atol=1e-8)


def test_prefix_recommendations_are_the_mode_argmax_after_each_prefix() -> None:
    features = np.random.default_rng(0).normal(size=(5, 2))
    context = _random_context(np.random.default_rng(1), 3, 5, 12)
    got = prefix_recommendations(BTThompsonSampling(features, 3, rng=np.random.default_rng(0)), *context)
    for h in (1, 6, 12):
        learner = BTThompsonSampling(features, 3, newton_steps=50, rng=np.random.default_rng(0))
        learner.observe_context(*(x[:, :h] for x in context))
        np.testing.assert_array_equal(got[:, h - 1], learner.recommend())


# ---- tuning on training problems ----------------------------------------------------------------------

def test_training_problems_are_the_settings_training_split() -> None:
    family = LinearDuelingBanditFamily(n_arms=4, dim=3, horizon=3, seed=7)
    splits, _ = BanditDuels(n_train_problems=9, n_val_problems=2, n_eval_problems=2,
                            eval_sources=("uniform",)).generate(family, progress=False)
    np.testing.assert_array_equal(training_problems(family, 5), splits["tasks"]["train_theta"][:5])


def test_tune_returns_the_lowest_auc_point() -> None:
    family = LinearDuelingBanditFamily(n_arms=5, dim=2, horizon=8, seed=1)
    theta = training_problems(family, 12)
    context = family.uniform_pairs_context(theta, np.random.default_rng(0))
    best, rows = tune(MaxInP, {"beta": (0.0, 3.0)}, family, theta, context)
    assert len(rows) == 2 and best["beta"] == min(rows, key=lambda r: r["auc"])["beta"]
    assert {"auc", "auc_sem", "final", "final_sem", "beta"} <= set(rows[0])


# ---- guards -------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("call", "message"), [
    (lambda: win_counts(np.zeros((1, 2), int), np.zeros((1, 3), int), np.zeros((1, 2), int), 3), "share one shape"),
    (lambda: win_counts(*_context([0, 3], [1, 1], [1, 0]), 3), r"first arms must lie in \[0, 3\)"),
    (lambda: win_counts(*_context([0, 1], [1.0, 0.0], [1, 0]), 3), "second arms must be integers"),
    (lambda: win_counts(*_context([0, 1], [1, 0], [1, 2]), 3), "0/1 labels"),
    (lambda: BradleyTerryPosterior(UNIT, prior_var=0.0), "prior_var must be > 0"),
    (lambda: BradleyTerryPosterior(UNIT[:1], prior_var=1.0), r"features must have shape \[A >= 2, d\]"),
    (lambda: BradleyTerryPosterior(UNIT, 1.0).laplace(np.zeros((1, 3, 3)), start=np.zeros((2, 2))),
     "start must have shape"),
    (lambda: BradleyTerryPosterior(UNIT, 1.0).pair_counts(np.zeros((1, 2, 2))), r"wins must have shape \[P, 3, 3\]"),
    (lambda: MaxInP(UNIT, 2, rng=np.random.default_rng(0)).update(np.array([0]), np.array([1]), np.array([1])),
     r"first must have shape \[P=2\]"),
    (lambda: MaxInP(UNIT, 1, rng=0), "rng must be a numpy Generator"),
    (lambda: MaxInP(UNIT, 1, beta=-1.0, rng=np.random.default_rng(0)), "beta must be >= 0"),
    (lambda: BTThompsonSampling(UNIT, 1, scale=0.0, rng=np.random.default_rng(0)), "scale must be > 0"),
    (lambda: BTThompsonSampling(UNIT, 1, rng=np.random.default_rng(0)).pair_from_noise(np.zeros((1, 1, 2))),
     "noise must have shape"),
    (lambda: BayesReference(UNIT, 1, prior_var=1.0, rule="best", rng=np.random.default_rng(0)), "rule must be one of"),
    (lambda: run_online(MaxInP(UNIT, 1, rng=np.random.default_rng(0)), np.zeros((1, 2, 2)), 3,
                        np.random.default_rng(0)), r"preference_matrix must have shape \[1, 3, 3\]"),
    (lambda: prefix_duels(MaxInP(UNIT, 2, rng=np.random.default_rng(0)), *_context([0], [1], [1])),
     r"arms_first must have shape \[P=2, H\]"),
    (lambda: tune(MaxInP, {}, LinearDuelingBanditFamily(n_arms=3, dim=2), np.zeros((1, 2)), {}), "grid must name"),
    (lambda: BradleyTerryPosterior(UNIT, 1.0, temperature=0.0), "temperature must be > 0"),
    (lambda: BradleyTerryPosterior(UNIT, 1.0).laplace(np.zeros((1, 3, 3)), newton_steps=0),
     "newton_steps must be >= 1"),
    (lambda: MaxInP(UNIT, 0, rng=np.random.default_rng(0)), "n_problems must be >= 1"),
    (lambda: MaxInP(UNIT, 1, newton_steps=0, rng=np.random.default_rng(0)), "newton_steps must be >= 1"),
    (lambda: MaxInP(UNIT, 2, rng=np.random.default_rng(0)).observe_context(*_context([0], [1], [1])),
     r"arms_first must have shape \[P=2, T\]"),
    (lambda: BayesReference(UNIT, 1, prior_var=1.0, posterior="exact", rng=np.random.default_rng(0)),
     "posterior must be one of"),
    (lambda: BayesReference(UNIT, 1, prior_var=1.0, n_samples=0, rng=np.random.default_rng(0)),
     "n_samples must be >= 1"),
    (lambda: importance_sample(BradleyTerryPosterior(UNIT, 1.0), np.zeros((1, 3, 3)), np.zeros((1, 2)),
                               np.eye(2)[None], 10, np.random.default_rng(0), widen=0.0), "widen must be > 0"),
    (lambda: importance_sample(BradleyTerryPosterior(UNIT, 1.0), np.zeros((1, 3, 3)), np.zeros((1, 2)),
                               np.eye(2)[None], 0, np.random.default_rng(0)), "n_samples must be >= 1"),
    (lambda: run_online(MaxInP(UNIT, 1, rng=np.random.default_rng(0)), np.full((1, 3, 3), 0.5), 0,
                        np.random.default_rng(0)), "horizon must be >= 1"),
    (lambda: duel_regrets(np.zeros((2, 3)), np.zeros((2, 4), int), np.zeros((2, 5), int)),
     "first/second"),
    (lambda: training_problems(LinearDuelingBanditFamily(n_arms=3, dim=2), 0), "n must be >= 1"),
    (lambda: prefix_recommendations(MaxInP(UNIT, 2, rng=np.random.default_rng(0)), *_context([0], [1], [1])),
     r"arms_first must have shape \[P=2, H\]"),
], ids=lambda x: x if isinstance(x, str) else "")
def test_invalid_input_fails_with_one_clear_line(call, message: str) -> None:
    with pytest.raises((ValueError, TypeError), match=message):
        call()
