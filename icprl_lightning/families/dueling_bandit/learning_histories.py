"""Learning histories on linear dueling bandits: Double Thompson Sampling from scratch on many problems at once,
recorded duel by duel (the data of Algorithm Distillation, Laskin et al. 2022, "In-context Reinforcement Learning
with Algorithm Distillation", for a preference learner).

The source learner is DTS (Wu & Liu 2016, "Double Thompson Sampling for Dueling Bandits"; ``dts.py``), the paper's
dueling-bandit baseline. A history is what DTS itself sees and does: round t's duel (a_t, a'_t) and its outcome
y_t ~ Bradley–Terry(r_τ(a_t) − r_τ(a'_t)) (``LinearDuelingBanditFamily.preference_matrix``), and nothing else:
no rewards, utilities or θ are recorded, so AD trained on these histories is reward-free, a direct competitor of
ICPO asked online (``evaluation/online_bandit.py``). DTS never sees the arm features either.

``run_dts`` plays all P problems side by side (``[P, A, A]`` win counts, every round one vectorized step): the
only Python loop is over rounds. Round 1 is DTS from empty counts, so a history shows the whole of its learning,
from uniform duels to duelling its champion against itself.
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
    """DTS on dueling-bandit problems, recorded round by round (see the module docstring).

    Args:
        rounds: duels per history. A model that proposes duel r + 1 after r answers needs a trained position for
            each proposal it makes: evaluating R rounds with the recommendation after the last answer (the first
            arm of duel R + 1, as for DTS) takes R + 1, hence the default 201 for the paper's H = 200.

    DTS's own knob, α of its confidence bounds, is the family's ``dts_alpha`` (the same DTS as the baseline rows).
    """

    rounds: int = 201

    def __post_init__(self) -> None:
        check_int(type(self).__name__, "rounds", self.rounds, 1)

    def config(self) -> dict[str, Any]:
        return {"learner": type(self).__name__, "rounds": self.rounds}

    def run(self, family: LinearDuelingBanditFamily, theta: np.ndarray, rng: np.random.Generator
            ) -> dict[str, np.ndarray]:
        """One DTS history per row of ``theta`` [P, d], each from empty counts, every draw from ``rng``.

        Returns ``arms_first``, ``arms_second`` int64 [P, rounds] (round t's duel) and ``preferred`` uint8
        [P, rounds] (1 = the first arm won): the duels and outcomes only.
        """
        return run_dts(family.preference_matrix(theta), self.rounds, rng, alpha=family.dts_alpha)
