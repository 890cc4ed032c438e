"""What every T-PRL dataset shares, whatever its task family (paper, eq. (t-prl-pref); appendix
"Pretraining Data Generation", T-PRL).

* ``label_trajectory_pairs``: given rollouts stacked as [ξ_a rows; ξ_b rows; (behavior rows)], the
  reward-free context arrays, a Bradley–Terry label per pair on the return difference

      P(y = 1) = σ((Σ_h r(s_h, a_h | ξ_a) − Σ_h r(s_h, a_h | ξ_b)) / bt_temperature),

  the per-step latent rewards kept apart (oracle only) and the label statistics.
* ``TrajectoryPreferenceData``: the DataModule side, mixed in before a family's DataModule. Two kinds
  over the *same* trajectories: ``trajectory_preference`` (pairs with a label, no rewards: DP²T,
  RewardGen, ICRG) and ``reward_trajectory`` (the same trajectories with their true rewards and no
  label: the DIT oracle baseline); ``heldout_pairs()`` for RewardGen's held-out pair accuracy.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from icprl_lightning.contexts import RewardTrajectoryContext
from icprl_lightning.data.batches import other_rows, to_tensor
from icprl_lightning.preferences import label_agreement, sample_preferences

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


class TrajectoryPreferenceData:
    """Mixin for a family's DataModule (listed first among the bases); see the module docstring.

    The T-PRL arguments its hosts share:

    * ``context_kind``: ``trajectory_preference`` (DP²T, RewardGen, ICRG) or ``reward_trajectory`` (DIT on
      true rewards);
    * ``trajectories_per_task``: T-PRL pairs per training goal (paper: 5000); ``val_trajectories_per_task``:
      extra pairs per training goal for the validation loss;
    * ``eval_contexts_per_task``: contexts (= evaluation episodes) per held-out goal and quality; RewardGen's
      held-out pair accuracy scores each against the next one of its goal, so use at least 2;
    * ``bt_temperature``: the Bradley–Terry temperature on return differences.

    The host sets ``kind``, ``eval_per_task`` and ``quality_targets`` (the evaluation qualities, in order)
    and stores evaluation splits ``eval_<quality>`` whose rows are task-major, ``eval_per_task`` per goal.
    """

    context_kinds: tuple[str, ...] = ("trajectory_preference", "reward_trajectory")
    pair_fields = PAIR_FIELDS  # ``pairs=True`` serves another *pair* of the same task
    kind: str
    eval_per_task: int
    quality_targets: dict[str, float]

    def batch_fields(self) -> tuple[str, ...]:
        return PAIR_FIELDS if self.kind == "trajectory_preference" else LABELED_FIELDS

    def stored_arrays(self, arrays: dict[str, np.ndarray], rewards: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """What this kind writes of a generated split: the labels, or instead the true rewards (DIT)."""
        if self.kind == "reward_trajectory":
            arrays.update(rewards)
            del arrays["preferred"]
        return arrays

    def eval_context(self, arrays: dict[str, Any]):
        if self.kind == "reward_trajectory":
            return RewardTrajectoryContext(arrays["behavior_states"], arrays["behavior_actions"],
                                           arrays["behavior_rewards"])
        return super().eval_context(arrays)  # type: ignore[misc]

    def heldout_pairs(self) -> dict[str, dict[str, torch.Tensor]]:
        """Per quality, the held-out goals' pairs, each with another pair of its goal as ``pair_*``.

        The context pair is the next evaluation context of the same goal and quality (the pair itself
        when there is only one per goal). RewardGen's held-out pair accuracy is measured on these.
        """
        if self.kind != "trajectory_preference":
            raise ValueError("held-out pairs exist in trajectory_preference datasets only")
        data = self.load()  # type: ignore[attr-defined]
        out = {}
        for q in self.quality_targets:
            split = data[f"eval_{q}"]
            rows = np.arange(len(split["preferred"]))
            other = other_rows(rows, self.eval_per_task, 1)
            batch = {k: to_tensor(np.asarray(split[k])) for k in PAIR_FIELDS}
            batch.update({f"pair_{k}": to_tensor(np.asarray(split[k])[other]) for k in PAIR_FIELDS})
            out[q] = batch
        return out
