"""DPT's reward contexts, for every family (the oracle baseline; paper, section 3 "DPT" and appendix
"Pretraining Data Generation"): transitions (s, a, r, s') of one mixed behavior policy per context, from
the family's context process, r the latent reward. Only DPT receives rewards; the query labels for its
supervised loss come from the oracle.
"""

from __future__ import annotations

import numpy as np

from icprl_lightning.data.settings.base import MDPSetting, rollout_behavior
from icprl_lightning.families.base import TaskFamily


class RewardContexts(MDPSetting):
    """(s, a, r, s') contexts; the arguments as ``MDPSetting``."""

    kind = "reward"

    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        roll = rollout_behavior(family, tasks, mixing[quality], rng, episodes=False, progress=progress,
                                description=description)
        arrays = {k: roll[k] for k in ("states", "actions", "rewards", "next_states")}
        arrays.update(family.oracle.query_labels(tasks, roll["states"], roll["optimal"], family.horizon, rng))
        return arrays, {"mean_context_return": float(roll["rewards"].sum(1, dtype=np.float64).mean())}
