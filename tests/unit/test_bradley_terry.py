import numpy as np
import pytest

from icprl_lightning.preferences import label_agreement, preference_probability, sample_preferences


def test_probability_formula_and_temperature():
    u = np.array([0.0, 1.0, -2.0, 40.0, -40.0])
    p = preference_probability(u, np.zeros_like(u), 1.0)
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-u)))
    np.testing.assert_allclose(preference_probability(np.array([1.0]), np.array([0.0]), 0.5), 1 / (1 + np.exp(-2)))
    with pytest.raises(ValueError, match="bt_temperature"):
        preference_probability(u, u, 0.0)


@pytest.mark.parametrize("diff,temperature", [(1.0, 1.0), (2.0, 1.0), (-1.0, 0.5), (0.3, 2.0)])
def test_label_rate_matches_bradley_terry(diff, temperature):
    """Empirical P(y = 1) within 4 binomial standard deviations of σ(diff / temperature) (fixed seed)."""
    n = 200_000
    y = sample_preferences(np.full(n, diff), np.zeros(n), temperature, np.random.default_rng(0))
    p = 1 / (1 + np.exp(-diff / temperature))
    assert abs(y.mean() - p) < 4 * np.sqrt(p * (1 - p) / n)


def test_label_agreement_ignores_ties():
    u1 = np.array([1.0, 2.0, 0.0, 5.0])
    u2 = np.array([0.0, 3.0, 0.0, 1.0])
    y = np.array([1, 1, 0, 0])
    assert label_agreement(u1, u2, y) == pytest.approx(1 / 3)
    assert np.isnan(label_agreement(u2[2:3], u2[2:3], y[2:3]))
