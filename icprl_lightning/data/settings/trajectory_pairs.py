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
checkpoint on Meta-World) and ``bt_temperature``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from icprl_lightning.contexts import RewardTrajectoryContext
from icprl_lightning.data.batches import other_rows, to_tensor
from icprl_lightning.data.settings.base import PRETRAINING, MDPSetting, rollout_behavior
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.families.base import QUALITIES, TaskFamily
from icprl_lightning.preferences import label_agreement, sample_preferences
from icprl_lightning.validation import check_interval, check_positive

PAIR_FIELDS = ("states_a", "actions_a", "states_b", "actions_b", "preferred")
LABELED_FIELDS = ("states_a", "actions_a", "rewards_a", "states_b", "actions_b", "rewards_b")


def label_trajectory_pairs(states: np.ndarray, actions: np.ndarray, rewards: np.ndarray, n: int,
                           bt_temperature: float, rng: np.random.Generator, behavior: bool = False
                           ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """Split rollouts [kN, H, ...] (rows ξ_a, then ξ_b, then the behavior trajectories) into T-PRL pairs.

    Returns ``(arrays, rewards, stats)``: the reward-free context arrays (``PAIR_FIELDS``, plus
    ``behavior_states`` and ``behavior_actions`` when ``behavior``), the per-step latent rewards of each
    trajectory (oracle only) and the label statistics (agreement with the true return ordering, tie
    fraction, mean return).
    """
    ret_a, ret_b = rewards[:n].sum(1), rewards[n:2 * n].sum(1)
    preferred = sample_preferences(ret_a, ret_b, bt_temperature, rng)
    arrays = {"states_a": states[:n], "actions_a": actions[:n], "states_b": states[n:2 * n],
              "actions_b": actions[n:2 * n], "preferred": preferred}
    oracle = {"rewards_a": rewards[:n], "rewards_b": rewards[n:2 * n]}
    if behavior:
        arrays.update(behavior_states=states[2 * n:], behavior_actions=actions[2 * n:])
        oracle["behavior_rewards"] = rewards[2 * n:]
    stats = {"label_agreement": label_agreement(ret_a, ret_b, preferred),
             "tie_fraction": float(np.mean(ret_a == ret_b)),
             "mean_return": float(np.concatenate([ret_a, ret_b]).mean())}
    return arrays, oracle, stats


class TrajectoryPairs(MDPSetting):
    """T-PRL pairs; see the module docstring. The other arguments as ``MDPSetting``."""

    kind = "trajectory_preference"

    def __init__(self, bt_temperature: float = 1.0, pretraining_target: float = 0.5,
                 trajectories_per_task: int = 60, **kwargs: Any) -> None:
        owner = type(self).__name__
        check_positive(owner, "bt_temperature", bt_temperature)
        check_interval(owner, "pretraining_target", pretraining_target, 0.0, 1.0, closed="neither")
        self.bt_temperature = bt_temperature
        self.pretraining_target = pretraining_target
        super().__init__(trajectories_per_task=trajectories_per_task, **kwargs)

    def extra_targets(self) -> dict[str, float]:
        # calibrated only when used, so that cycling datasets do not pay for (or record) it
        return {PRETRAINING: self.pretraining_target} if self.train_policy == PRETRAINING else {}

    def policy_names(self) -> tuple[str, ...]:
        return (*QUALITIES, PRETRAINING)

    def knobs(self) -> dict[str, Any]:
        out: dict[str, Any] = {"bt_temperature": self.bt_temperature}
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
                                rng, episodes=True, progress=progress, description=description)
        arrays, rewards, stats = label_trajectory_pairs(roll["states"], roll["actions"], roll["rewards"], n,
                                                        self.bt_temperature, rng, behavior=evaluation)
        visited = np.concatenate([roll["states"][:n], roll["states"][n:2 * n]], axis=1)  # ξ_a ++ ξ_b in time
        optimal = np.concatenate([roll["optimal"][:n], roll["optimal"][n:2 * n]], axis=1)
        arrays = self.stored(arrays, rewards)
        arrays.update(family.oracle.query_labels(tasks, visited, optimal, family.horizon, rng))
        return arrays, stats

    def heldout_pairs(self, data: StoredDataset) -> dict[str, dict[str, torch.Tensor]]:
        """Per quality, the held-out tasks' pairs, each with another pair of its task as ``pair_*``.

        The context pair is the next evaluation context of the same task and quality (the pair itself
        when there is only one per task). RewardGen's held-out pair accuracy is measured on these.
        """
        out = {}
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            rows = np.arange(len(split["preferred"]))
            other = other_rows(rows, self.eval_contexts_per_task, 1)
            batch = {k: to_tensor(np.asarray(split[k])) for k in PAIR_FIELDS}
            batch.update({f"pair_{k}": to_tensor(np.asarray(split[k])[other]) for k in PAIR_FIELDS})
            out[q] = batch
        return out


class RewardTrajectories(TrajectoryPairs):
    """The same trajectories as ``TrajectoryPairs`` with their true rewards instead of labels (DIT)."""

    kind = "reward_trajectory"

    def batch_fields(self) -> tuple[str, ...]:
        return LABELED_FIELDS

    def stored(self, arrays: dict[str, np.ndarray], rewards: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        arrays.update(rewards)
        del arrays["preferred"]
        return arrays

    def eval_context(self, arrays: dict[str, Any]) -> RewardTrajectoryContext:
        return RewardTrajectoryContext(arrays["behavior_states"], arrays["behavior_actions"],
                                       arrays["behavior_rewards"])

    def heldout_pairs(self, data: StoredDataset) -> dict[str, dict[str, torch.Tensor]]:
        raise ValueError("held-out pairs exist in trajectory_preference datasets only")
