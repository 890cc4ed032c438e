"""Learning histories on linear dueling bandits: Double Thompson Sampling (``dts.py``) from scratch on many
problems at once, recorded duel by duel (the data of Algorithm Distillation, Laskin et al. 2022, "In-context
Reinforcement Learning with Algorithm Distillation", for a preference learner).

A history is what DTS itself sees and does: round t's duel (a_t, a'_t) and its outcome y_t ~ Bradley–Terry, and
nothing else (no rewards, utilities or θ), so AD trained on these histories is reward-free. Round 1 is DTS from
empty counts, so a history shows the whole of its learning.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from icprl_lightning.families.dueling_bandit.dts import run_dts
from icprl_lightning.validation import check_int

if TYPE_CHECKING:
    from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily

HISTORY_FIELDS = ("arms_first", "arms_second", "preferred")  # what a history holds: the duels and their outcomes


@dataclass(frozen=True)
class DTSHistories:
    """DTS (α: the family's ``dts_alpha``) on dueling-bandit problems, recorded round by round.

    ``rounds``: duels per history; evaluating R rounds with the recommendation after the last answer (the first
    arm of duel R + 1) needs R + 1 trained positions, hence 201 for the paper's H = 200.
    """

    rounds: int = 201

    def __post_init__(self) -> None:
        check_int(type(self).__name__, "rounds", self.rounds, 1)

    def config(self) -> dict[str, Any]:
        return {"learner": type(self).__name__, "rounds": self.rounds}

    def run(self, family: LinearDuelingBanditFamily, theta: np.ndarray, rng: np.random.Generator
            ) -> dict[str, np.ndarray]:
        """One history per row of ``theta`` [P, d]: ``arms_first``, ``arms_second`` int64 and ``preferred`` uint8
        (1 = the first arm won), each [P, rounds]."""
        return run_dts(family.preference_matrix(theta), self.rounds, rng, alpha=family.dts_alpha)
