"""Typed training samples: what one batch of a DataModule holds, as NamedTuples with documented shapes.

Stable-Baselines3's ``ReplayBufferSamples`` habit: ``data/batches.py`` builds them from the stored rows; methods
and losses read them by attribute (``batch.context``). A field the data does not serve is None. Lightning moves a
batch as a whole (it maps over a NamedTuple's fields; a typed context moves itself, ``contexts._Context.to``).

Sizes: B contexts per batch, T steps per context (H, a trajectory's length, for T-PRL pairs and reward
trajectories), S the state size, A the action dimension. Discrete actions are int64 [B, T]; continuous float32
[B, T, A]. Every tensor is on the same device.
"""

from __future__ import annotations

from typing import NamedTuple

from torch import Tensor

from icprl_lightning.contexts import Context, RewardTrajectoryContext


class ContextSamples(NamedTuple):
    """B stored contexts and what a loss scores against them; see the module docstring.

    * ``context``: each row's own context: ``StepPreferenceContext`` [B, T, ...], ``RewardContext`` [B, T, ...] or
      ``TrajectoryPreferenceContext`` [B, H, ...] (its behavior trajectory None).
    * ``pair``: another context of the same kind and the same task per row (``pairs: true``), else None: ICPO's
      scored comparisons (``pair_source: other_trajectory``), RewardGen's and ICRG's conditioning pair.
    * ``query_states``: [B, T, S] float32, the query states of DPT/DP²T (``query_labels: true``), else None.
    * ``optimal_actions``: [B, T] int64 | [B, T, A] float32, the optimal action at each query state, else None.
    * ``task``: [B] int64, each row's training-task index (settings with folds), else None. It names a training
      task, never its goal or reward; no model reads it as input (ICRG's cross-fitting picks a labeler by it).
    """

    context: Context
    pair: Context | None = None
    query_states: Tensor | None = None
    optimal_actions: Tensor | None = None
    task: Tensor | None = None

    @property
    def batch_size(self) -> int:
        """B (what a method logs its metrics per: the unserved fields are None, which Lightning cannot size)."""
        return self.context.batch_size


class RewardTrajectorySamples(NamedTuple):
    """B pairs of two trajectories of one task each, with their true per-step rewards (DIT); each trajectory is
    the other's context.

    * ``trajectory_a``, ``trajectory_b``: ``RewardTrajectoryContext`` [B, H, ...].
    * ``advantages_a``, ``advantages_b``: [B, H] float32, the oracle's A*(s_h, a_h) of every behavior action
      (``RewardTrajectories(oracle_advantages=True)``), else None.
    * ``task``: [B] int64, each row's training-task index, as ``ContextSamples.task``.
    """

    trajectory_a: RewardTrajectoryContext
    trajectory_b: RewardTrajectoryContext
    advantages_a: Tensor | None = None
    advantages_b: Tensor | None = None
    task: Tensor | None = None

    @property
    def batch_size(self) -> int:
        """B, as ``ContextSamples.batch_size``."""
        return self.trajectory_a.batch_size


# Any training batch.
Samples = ContextSamples | RewardTrajectorySamples
