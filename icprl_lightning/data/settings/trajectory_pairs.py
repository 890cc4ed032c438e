"""T-PRL trajectory pairs and DIT's reward trajectories, for every family (paper, section 4.1,
eq. (t-prl-pref); appendix "Pretraining Data Generation", T-PRL).

A context D^T = {ξ_a, ξ_b, y}: two episodes of the same behavior policy on one task, each from its own
start, and a label drawn from the Bradley–Terry model on their latent returns,

    P(y = 1) = σ((Σ_h r(s_h, a_h | ξ_a) − Σ_h r(s_h, a_h | ξ_b)) / bt_temperature).

Two kinds over the *same* trajectories (same draws, same bytes of states and actions):

* ``TrajectoryPairs`` (``trajectory_preference``): the reward-free data of DP²T, RewardGen and ICRG —
  pairs with a label, no reward anywhere in the dataset;
* ``RewardTrajectories`` (``reward_trajectory``): the same trajectories with their true per-step rewards
  and no label, the reward-supervised DIT baseline's data (an oracle, as DPT's reward contexts are).

Evaluation rows also roll out an unlabeled behavior trajectory {s_h, a_h} of the same policy: the one
RewardGen labels when ICRG is deployed (paper, "ICRG Deployment"). Query labels for DP²T come from the
oracle over the 2H states the pair visited. Knobs: ``train_policy`` (``"cycle"`` through the qualities,
or ``"pretraining"``: one policy at ``pretraining_target`` of the optimal return, the paper's 50% SAC
checkpoint on Meta-World) and ``annotator`` (``annotators/``; by default Bradley–Terry at
``bt_temperature``, the equation above). An annotator's EQUAL and SKIP answers are stored as fair coins
(``annotators/labels.py``) and counted in the statistics. ``RewardTrajectories`` stores no label, so it
takes no annotator (it draws the default labels and drops them, keeping the stream of ``TrajectoryPairs``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, TrajectoryQueries
from icprl_lightning.annotators.bradley_terry import BradleyTerryAnnotator
from icprl_lightning.annotators.labels import stored_labels
from icprl_lightning.contexts import RewardTrajectoryContext
from icprl_lightning.data.batches import other_rows, stored_context
from icprl_lightning.data.settings.base import (
    PRETRAINING,
    MDPSetting,
    annotator_knobs,
    choose_annotator,
    rollout_behavior,
)
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.families.base import QUALITIES, TaskFamily
from icprl_lightning.preferences import label_agreement
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_choice, check_interval

PAIR_FIELDS = ("states_a", "actions_a", "states_b", "actions_b", "preferred")
LABELED_FIELDS = ("states_a", "actions_a", "rewards_a", "states_b", "actions_b", "rewards_b")
ADVANTAGE_FIELDS = ("advantages_a", "advantages_b")  # A*(s_h, a_h), RewardTrajectories(oracle_advantages=True)


def label_trajectory_pairs(states: np.ndarray, actions: np.ndarray, rewards: np.ndarray, n: int,
                           annotator: Annotator | float, rng: np.random.Generator, behavior: bool = False,
                           tasks: np.ndarray | None = None
                           ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """Split rollouts [kN, H, ...] (rows ξ_a, then ξ_b, then the behavior trajectories) into T-PRL pairs.

    ``annotator`` labels the pairs (a number: Bradley–Terry at that temperature); ``tasks`` [n, ...] are
    the pairs' tasks, shown to it. Returns ``(arrays, rewards, stats)``: the reward-free context arrays
    (``PAIR_FIELDS``, plus ``behavior_states`` and ``behavior_actions`` when ``behavior``), the per-step
    latent rewards of each trajectory (oracle only) and the label statistics (agreement of the stored
    labels with the true return ordering, tie fraction, mean return, skip and equal counts).
    """
    if not isinstance(annotator, Annotator):
        annotator = BradleyTerryAnnotator(annotator)
    ret_a, ret_b = rewards[:n].sum(1), rewards[n:2 * n].sum(1)
    queries = TrajectoryQueries(states[:n], actions[:n], rewards[:n], states[n:2 * n], actions[n:2 * n],
                                rewards[n:2 * n], tasks)
    counts = {"skip_count": 0, "equal_count": 0}
    preferred = stored_labels(annotator.label_trajectories(queries, rng), n, type(annotator).__name__, rng, counts)
    arrays = {"states_a": states[:n], "actions_a": actions[:n], "states_b": states[n:2 * n],
              "actions_b": actions[n:2 * n], "preferred": preferred}
    oracle = {"rewards_a": rewards[:n], "rewards_b": rewards[n:2 * n]}
    if behavior:
        arrays.update(behavior_states=states[2 * n:], behavior_actions=actions[2 * n:])
        oracle["behavior_rewards"] = rewards[2 * n:]
    stats = {"label_agreement": label_agreement(ret_a, ret_b, preferred),
             "tie_fraction": float(np.mean(ret_a == ret_b)),
             "mean_return": float(np.concatenate([ret_a, ret_b]).mean()), **counts}
    return arrays, oracle, stats


class TrajectoryPairs(MDPSetting):
    """T-PRL pairs; see the module docstring. The other arguments as ``MDPSetting``."""

    kind = "trajectory_preference"
    evaluations = frozenset({"rollouts", "pair_accuracy"})

    stores_labels = True  # False: the kind keeps the true rewards instead (``RewardTrajectories``)
    oracle_advantages = False  # RewardTrajectories only: also keep each action's A*

    def __init__(self, bt_temperature: float = 1.0, pretraining_target: float = 0.5,
                 trajectories_per_task: int = 60, annotator: Annotator | None = None, **kwargs: Any) -> None:
        owner = type(self).__name__
        if annotator is not None and not self.stores_labels:
            raise HyperparameterError(f"{owner}: annotator has no effect here: this setting stores the true "
                                      f"rewards, not labels (got {type(annotator).__name__})")
        self.annotator = choose_annotator(owner, annotator, bt_temperature)
        check_interval(owner, "pretraining_target", pretraining_target, 0.0, 1.0, closed="neither")
        self.pretraining_target = pretraining_target
        super().__init__(trajectories_per_task=trajectories_per_task, **kwargs)

    def extra_targets(self) -> dict[str, float]:
        # calibrated only when used, so that cycling datasets do not pay for (or record) it
        return {PRETRAINING: self.pretraining_target} if self.train_policy == PRETRAINING else {}

    def policy_names(self) -> tuple[str, ...]:
        return (*QUALITIES, PRETRAINING)

    @property
    def bt_temperature(self) -> float | None:
        """The Bradley–Terry annotator's temperature; None for another annotator."""
        return annotator_knobs(self.annotator).get("bt_temperature")

    def annotation(self) -> dict[str, Any]:
        return {"annotator": self.annotator.config()} if self.stores_labels else {}

    def knobs(self) -> dict[str, Any]:
        out: dict[str, Any] = annotator_knobs(self.annotator)
        if self.train_policy == PRETRAINING:
            out["pretraining_target"] = self.pretraining_target
        return out

    @property
    def pair_fields(self) -> tuple[str, ...]:
        return PAIR_FIELDS  # ``pairs=True`` serves another *pair* of the same task

    def batch_fields(self) -> tuple[str, ...]:
        return PAIR_FIELDS

    def stored(self, arrays: dict[str, np.ndarray], rewards: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """What this kind writes of a generated split: the labels (here), or instead the true rewards."""
        return arrays

    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        n, k = len(tasks), 3 if evaluation else 2
        roll = rollout_behavior(family, np.tile(tasks, (k, *[1] * (tasks.ndim - 1))), np.tile(mixing[quality], k),
                                rng, episodes=True, progress=progress, description=description,
                                advantages=self.oracle_advantages)
        arrays, rewards, stats = label_trajectory_pairs(roll["states"], roll["actions"], roll["rewards"], n,
                                                        self.annotator, rng, behavior=evaluation, tasks=tasks)
        if self.oracle_advantages:
            rewards.update(advantages_a=roll["advantages"][:n], advantages_b=roll["advantages"][n:2 * n])
        visited = np.concatenate([roll["states"][:n], roll["states"][n:2 * n]], axis=1)  # ξ_a ++ ξ_b in time
        optimal = np.concatenate([roll["optimal"][:n], roll["optimal"][n:2 * n]], axis=1)
        arrays = self.stored(arrays, rewards)
        arrays.update(family.oracle.query_labels(tasks, visited, optimal, family.horizon, rng))
        return arrays, stats

    def heldout_pairs(self, data: StoredDataset) -> dict[str, ContextSamples]:
        """Per quality, the held-out tasks' pairs (``context``), each with another pair of its task (``pair``).

        The context pair is the next evaluation context of the same task and quality (the pair itself
        when there is only one per task). RewardGen's held-out pair accuracy is measured on these.
        """
        out = {}
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            rows = np.arange(len(split["preferred"]))
            other = other_rows(rows, self.eval_contexts_per_task, 1)
            out[q] = ContextSamples(stored_context(self.kind, split, rows, PAIR_FIELDS),
                                    stored_context(self.kind, split, other, PAIR_FIELDS))
        return out


class RewardTrajectories(TrajectoryPairs):
    """The same trajectories as ``TrajectoryPairs`` with their true rewards instead of labels (DIT).

    ``oracle_advantages`` also stores and serves A*(s_h, a_h) of every behavior action (``advantages_a``,
    ``advantages_b``; the oracle's ``utility`` against its own action, ``rollout_behavior``): the advantage
    stage's oracle, for DIT's ``advantage: oracle``. The states, actions and rewards stay the same bytes.
    """

    kind = "reward_trajectory"
    evaluations = frozenset({"rollouts"})  # no labels: no held-out pairs to order
    stores_labels = False

    def __init__(self, oracle_advantages: bool = False, **kwargs: Any) -> None:
        check_choice(type(self).__name__, "oracle_advantages", oracle_advantages, (True, False))
        self.oracle_advantages = oracle_advantages
        super().__init__(**kwargs)

    def knobs(self) -> dict[str, Any]:
        # recorded only when on, so that the datasets made before the option keep their identity
        return {**super().knobs(), **({"oracle_advantages": True} if self.oracle_advantages else {})}

    def batch_fields(self) -> tuple[str, ...]:
        return (*LABELED_FIELDS, *ADVANTAGE_FIELDS) if self.oracle_advantages else LABELED_FIELDS

    def stored(self, arrays: dict[str, np.ndarray], rewards: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        arrays.update(rewards)
        del arrays["preferred"]
        return arrays

    def eval_context(self, arrays: dict[str, Any]) -> RewardTrajectoryContext:
        return RewardTrajectoryContext(arrays["behavior_states"], arrays["behavior_actions"],
                                       arrays["behavior_rewards"])
