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

from typing import Any

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


class AgreementTally:
    """``label_agreement``, the tie fraction, the median utility gap and ``expected_agreement`` of many pairs,
    added a block at a time (the I-PRL generator adds one step of every trajectory), so that the
    utilities themselves are never stored: at DarkRoom's paper scale they were 128 MB written once and
    read three times, for four numbers. ``summary()`` equals the whole-array functions on the same pairs
    (up to the order of floating-point sums).
    """

    def __init__(self, temperatures: tuple[float, ...] = BT_TEMPERATURE_LADDER) -> None:
        self.temperatures = temperatures
        self.pairs = self.strict = self.agree = 0
        self.tanh_sums = np.zeros(len(temperatures))
        self.gaps: list[np.ndarray] = []  # the nonzero |ΔU| of each block, for the median

    def add(self, utility_first: np.ndarray, utility_second: np.ndarray, preferred: np.ndarray) -> None:
        diff = np.asarray(utility_first, dtype=np.float64) - np.asarray(utility_second, dtype=np.float64)
        strict = diff != 0
        gap = np.abs(diff[strict])
        self.pairs += diff.size
        self.strict += gap.size
        self.agree += int(np.count_nonzero(((diff > 0) == (np.asarray(preferred) == 1)) & strict))
        for i, t in enumerate(self.temperatures):
            self.tanh_sums[i] += np.tanh(gap / (2.0 * t)).sum()
        self.gaps.append(gap)

    def summary(self) -> dict:
        """label_agreement, tie_fraction, median_utility_gap (0 when all tie), expected_agreement_by_bt_temperature."""
        if not self.strict:
            nan = float("nan")
            return {"label_agreement": nan, "tie_fraction": 1.0 if self.pairs else nan, "median_utility_gap": 0.0,
                    "expected_agreement_by_bt_temperature": {str(t): nan for t in self.temperatures}}
        mean_tanh = self.tanh_sums / self.strict
        return {"label_agreement": self.agree / self.strict,
                "tie_fraction": 1.0 - self.strict / self.pairs,
                "median_utility_gap": float(np.median(np.concatenate(self.gaps), overwrite_input=True)),
                "expected_agreement_by_bt_temperature": {str(t): float(0.5 * (1.0 + m))
                                                         for t, m in zip(self.temperatures, mean_tanh, strict=True)}}


def has_soft_labels(preferred: Any) -> bool:
    """Whether some label (a numpy array or a tensor) lies strictly between 0 and 1: a tie stored as 0.5."""
    return bool(((preferred > 0) & (preferred < 1)).any())
