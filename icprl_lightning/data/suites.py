"""What one held-out evaluation needs, as data: the contexts, the tasks, and the references beside them.

A DataModule builds these from its stored evaluation splits; ``icprl_lightning.evaluation`` runs them
through the public ``Agent``. They sit below evaluation so that data never imports it.

* ``EvalSuite``: B in-context episodes of an MDP family at one context quality.
* ``BanditSuite``: B held-out dueling-bandit problems of one context source.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from torch import Tensor

from icprl_lightning.contexts import StepPreferenceContext


class VectorEnvLike(Protocol):
    num_envs: int

    def reset(self, *, seed: int | None = None) -> tuple[np.ndarray, dict]: ...

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]: ...


@dataclass
class EvalSuite:
    """B held-out episodes with their contexts: one context quality of one task family."""

    env_name: str
    quality: str
    context: Any                               # a typed context with batch size B
    make_env: Callable[[], VectorEnvLike]      # B episodes, aligned with the contexts
    task_index: np.ndarray                     # [B] which held-out task each episode belongs to
    horizon: int
    reference: dict[str, float] = field(default_factory=dict)  # e.g. behavior_return, optimal_return
    normalize: Callable[[np.ndarray], np.ndarray] | None = None


@dataclass
class BanditSuite:
    """B held-out problems of one context source, with what evaluation alone may see."""

    source: str                       # behaviour policy of the contexts: uniform, dirichlet or dts
    context: StepPreferenceContext    # states [B, H, 0]; H comparisons per problem
    expected_rewards: Tensor          # [B, A] r_τ(a), for scoring only
    behavior_first: Tensor            # [B, H] the behaviour's duel after h comparisons (its duel h + 1)
    behavior_second: Tensor           # [B, H]
    dts_alpha: float = 0.51
