"""DPT's reward contexts, for every family (the oracle baseline; paper, section 3 "DPT" and appendix
"Pretraining Data Generation"): transitions (s, a, r, s') of one mixed behavior policy per context, from
the family's context process, r the latent reward. Only DPT receives rewards; the query labels for its
supervised loss come from the oracle.

``state_source``: ``"rollout"`` (the behavior process, as the paper) or ``"uniform"`` (every state drawn
independently over the state space, DPT's own DarkRoom data), the same knob as the I-PRL setting's, so
that DPT can be compared with the preference methods on the same kind of states.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.data.settings.base import STATE_SOURCES, MDPSetting, rollout_behavior
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.validation import check_choice


class RewardContexts(MDPSetting):
    """(s, a, r, s') contexts; ``state_source`` as the module docstring, the other arguments as ``MDPSetting``."""

    kind = "reward"

    def __init__(self, state_source: str = "rollout", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.state_source = check_choice(type(self).__name__, "state_source", state_source, STATE_SOURCES)

    def knobs(self) -> dict[str, Any]:
        return {"state_source": self.state_source}

    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        roll = rollout_behavior(family, tasks, mixing[quality], rng, episodes=False, progress=progress,
                                description=description, state_source=self.state_source)
        arrays = {k: roll[k] for k in ("states", "actions", "rewards", "next_states")}
        arrays.update(family.oracle.query_labels(tasks, roll["states"], roll["optimal"], family.horizon, rng))
        return arrays, {"mean_context_return": float(roll["rewards"].sum(1, dtype=np.float64).mean())}
