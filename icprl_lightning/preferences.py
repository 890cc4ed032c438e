"""Bradley–Terry preference annotators (paper, appendix "Synthetic Preference Generation").

I-PRL:  P(y = 1 | s, a, a') = σ((A*(s, a) − A*(s, a')) / bt_temperature)
T-PRL:  P(y = 1 | ξ, ξ')    = σ((Σ_h R(s_h, a_h) − Σ_h R(s'_h, a'_h)) / bt_temperature)

The paper uses a temperature of 1. The temperature is explicit because the scale of A* or of the
return differences depends on the task family (Meta-World per-step differences are tiny, so labels at
temperature 1 would be near coin flips). ``y = 1`` always means the *first* item of the pair won.

These functions are used only by data generation: the utility they receive (A*, returns) never leaves
the generator.
"""

from __future__ import annotations

import numpy as np


def preference_probability(utility_first: np.ndarray, utility_second: np.ndarray,
                           bt_temperature: float) -> np.ndarray:
    """σ((u − u') / temperature), elementwise."""
    if bt_temperature <= 0:
        raise ValueError(f"bt_temperature must be > 0, got {bt_temperature}")
    z = (np.asarray(utility_first, dtype=np.float64) - np.asarray(utility_second, dtype=np.float64))
    # σ saturates to 0/1 in float64 long before |z| = 700, where exp would overflow
    z = np.clip(z / bt_temperature, -700.0, 700.0)
    return 1.0 / (1.0 + np.exp(-z))


def sample_preferences(utility_first: np.ndarray, utility_second: np.ndarray, bt_temperature: float,
                       rng: np.random.Generator) -> np.ndarray:
    """Draw y ~ Bernoulli(σ((u − u') / temperature)); returns uint8 with 1 = first preferred."""
    p = preference_probability(utility_first, utility_second, bt_temperature)
    return (rng.random(p.shape) < p).astype(np.uint8)


BT_TEMPERATURE_LADDER = (1.0, 0.3, 0.1, 0.05, 0.02, 0.01)


def expected_agreement(utility_first: np.ndarray, utility_second: np.ndarray,
                       temperatures: tuple[float, ...] = BT_TEMPERATURE_LADDER) -> dict[str, float]:
    """The label agreement Bradley–Terry labels would have at each temperature T, in expectation, on these pairs:
    mean σ(|ΔU| / T) over the pairs whose utilities differ (``label_agreement``'s population). Says how much
    signal a temperature leaves in labels of utility gaps this small; NaN when every pair is a tie.
    """
    gap = np.abs(np.asarray(utility_first, dtype=np.float64) - np.asarray(utility_second, dtype=np.float64))
    gap = gap[gap != 0]
    if gap.size == 0:
        return {str(t): float("nan") for t in temperatures}
    return {str(t): float(np.mean(0.5 * (1.0 + np.tanh(gap / (2.0 * t))))) for t in temperatures}


def label_agreement(utility_first: np.ndarray, utility_second: np.ndarray, preferred: np.ndarray) -> float:
    """Share of labels that agree with the true ordering, over pairs whose utilities differ.

    Ties carry no ordering and are left out. 0.5 means the labels are noise; 1.0 means noiseless.
    Returns NaN when every pair is a tie.
    """
    diff = np.asarray(utility_first, dtype=np.float64) - np.asarray(utility_second, dtype=np.float64)
    strict = diff != 0
    if not strict.any():
        return float("nan")
    agree = (diff[strict] > 0) == (np.asarray(preferred)[strict] == 1)
    return float(agree.mean())
