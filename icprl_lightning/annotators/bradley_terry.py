"""The paper's synthetic annotator: Bradley–Terry labels on the oracle's utility (paper, appendix
"Synthetic Preference Generation"; ``preferences.py``):

    I-PRL  P(y = 1) = σ((A*(s, a) − A*(s, a')) / temperature)
    T-PRL  P(y = 1) = σ((Σ_h r_h(ξ_a) − Σ_h r_h(ξ_b)) / temperature)

It draws exactly what the settings drew before annotators existed (one ``rng.random(n)`` per batch), so a
dataset made with it has the same bytes as before. It always decides (no EQUAL, no SKIP).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.preferences import sample_preferences
from icprl_lightning.validation import check_positive


class BradleyTerryAnnotator(Annotator):
    """Bradley–Terry labels at ``temperature`` (the settings' ``bt_temperature``; paper: 1)."""

    def __init__(self, temperature: float = 1.0) -> None:
        self.temperature = check_positive(type(self).__name__, "temperature", temperature)

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        return sample_preferences(queries.utility, queries.alt_utility, self.temperature, rng)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        return sample_preferences(queries.returns_a, queries.returns_b, self.temperature, rng)

    def init_args(self) -> dict[str, Any]:
        return {"temperature": self.temperature}
