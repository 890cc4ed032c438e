"""DPT's reward contexts, for every family (the oracle baseline; paper, section 3 "DPT" and appendix
"Pretraining Data Generation"): transitions (s, a, r, s') of one mixed behavior policy per context, from
the family's context process, r the latent reward. Only DPT receives rewards; the query labels for its
supervised loss come from the oracle.

``state_source``: ``"rollout"`` (the behavior process, as the paper) or ``"uniform"`` (every state drawn
independently over the state space, DPT's own DarkRoom data), the same knob as the I-PRL setting's, so
that DPT can be compared with the preference methods on the same kind of states.

``pretraining_target``: the paper generates DPT's Meta-World training contexts with the *converged* SAC
policy. Set it (a share of the optimal return in (0, 1]; 1.0 is the optimal/converged policy itself) with
``train_policy: pretraining`` and the training and validation contexts come from that policy, while the
held-out contexts stay low/medium/high.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.data.settings.base import PRETRAINING, STATE_SOURCES, MDPSetting, rollout_behavior
from icprl_lightning.families.base import QUALITIES, TaskFamily
from icprl_lightning.validation import HyperparameterError, check_choice, check_interval


class RewardContexts(MDPSetting):
    """(s, a, r, s') contexts; ``state_source`` as the module docstring, the other arguments as ``MDPSetting``."""

    kind = "reward"

    def __init__(self, state_source: str = "rollout", pretraining_target: float | None = None,
                 **kwargs: Any) -> None:
        owner = type(self).__name__
        if pretraining_target is not None:
            check_interval(owner, "pretraining_target", pretraining_target, 0.0, 1.0, closed="right")
        self.pretraining_target = pretraining_target
        super().__init__(**kwargs)
        if (pretraining_target is None) != (self.train_policy != PRETRAINING):
            raise HyperparameterError(f"{owner}: pretraining_target and train_policy='{PRETRAINING}' go together "
                                      f"(got pretraining_target={pretraining_target}, "
                                      f"train_policy={self.train_policy!r})")
        self.state_source = check_choice(owner, "state_source", state_source, STATE_SOURCES)

    def policy_names(self) -> tuple[str, ...]:
        return (*QUALITIES, PRETRAINING)

    def extra_targets(self) -> dict[str, float]:
        return {} if self.pretraining_target is None else {PRETRAINING: self.pretraining_target}

    def knobs(self) -> dict[str, Any]:
        out: dict[str, Any] = {"state_source": self.state_source}
        if self.pretraining_target is not None:
            out["pretraining_target"] = self.pretraining_target
        return out

    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        roll = rollout_behavior(family, tasks, mixing[quality], rng, episodes=False, progress=progress,
                                description=description, state_source=self.state_source)
        arrays = {k: roll[k] for k in ("states", "actions", "rewards", "next_states")}
        arrays.update(family.oracle.query_labels(tasks, roll["states"], roll["optimal"], family.horizon, rng))
        return arrays, {"mean_context_return": float(roll["rewards"].sum(1, dtype=np.float64).mean())}
