r"""What one T-PRL pair can tell about DarkRoom's rewards: the Bayes-optimal R(s, a | ξ_a, ξ_b, y), beside RewardGen.

    icprl analyze reward-bayes --data-config <RewardGen run>/config.yaml [--json PATH]

RewardGen (paper section 5.3, eq. (L_R^T)) infers per-step rewards r̂(s, a | D^T) from one labeled pair. How
good can such rewards be? On DarkRoom the answer is computable: the task is the goal cell g, r_g(s, a) = 1
when the move lands on g, and the pair's label was drawn from the Bradley–Terry model of the data
(``annotators/bradley_terry.py``):

    P(y = 1 | g) = σ((R_g(ξ_a) − R_g(ξ_b)) / temperature),   R_g(ξ) = Σ_h r_g(s_h, a_h).

The pair's trajectories are evidence too: both were drawn from the mixed behavior policy π_g (the optimal
action toward g with probability p, the quality's calibrated mixing, else a uniform action), so

    p(g | D^T) ∝ P(y | g) · Π_h π_g(a^a_h | s^a_h) · Π_h π_g(a^b_h | s^b_h),

with a uniform prior over all grid cells (the held-out goals are not in the training set, so no prior
learned from training goals could put mass on them). ``posteriors`` gives the posterior from each evidence
(``EVIDENCE``): the label alone, the trajectories alone, and the whole pair, the exact posterior. The
Bayes reward is its expectation, r̄(s, a | D^T) = p(g = s' | D^T) for the cell s' the move lands on; from
the whole pair, no reward model conditioned on the same pair ranks transitions better on average. It is
measured with ``reward_quality``'s two fair measures (``icprl analyze reward-quality``), on the same held-out data:

* ``other_pair_accuracy``: the posterior predictive's winner of another pair of the task,
  argmax over y of Σ_g p(g | D^T) P(y | g), against that pair's label;
* ``reward_correlation``: Pearson correlation, pooled over steps and tasks, of r̄ on the held-out unlabeled
  behavior trajectories (each with its evaluation pair as D^T) with their latent rewards;

plus ``posterior_on_goal``, the posterior mass on the true goal (1/cells under the prior).

This is an oracle of the reward stage: it reads the family's dynamics and reward form, which ICRG never
does. It bounds what a better RewardGen objective can reach with one pair as context.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from icprl_lightning.contexts import TrajectoryPreferenceContext
from icprl_lightning.evaluation.trajectory_data import tprl_datamodule
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.families.darkroom.env import N_ACTIONS, transition
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_actions

# what the posterior conditions on: the label alone, the two trajectories alone (the behavior policy is
# goal-directed, so its moves point at the goal), or the whole pair
EVIDENCE = {"label": "the label only", "trajectories": "the trajectories only (no label)", "pair": "the whole pair"}


def landing_cells(states: torch.Tensor, actions: torch.Tensor, size: int) -> np.ndarray:
    """Index y·size + x of the cell each move lands on: states [B, H, 2], actions [B, H] -> [B, H]."""
    nxt = transition(states.numpy().astype(np.int64), actions.numpy().astype(np.int64), size)
    return nxt[..., 1] * size + nxt[..., 0]


def goal_returns(cells: np.ndarray, n_cells: int) -> np.ndarray:
    """R_g(ξ) for every goal cell g: landings per cell, [B, H] -> [B, n_cells]."""
    out = np.zeros((len(cells), n_cells))
    np.add.at(out, (np.repeat(np.arange(len(cells)), cells.shape[1]), cells.ravel()), 1.0)
    return out


def log_sigmoid(x: np.ndarray) -> np.ndarray:
    """log σ(x), stable for large |x|."""
    return -np.logaddexp(0.0, -x)


def grid_goals(size: int) -> np.ndarray:
    """Every cell as a goal [size², 2], in the order of ``landing_cells``' index (y·size + x)."""
    y, x = np.divmod(np.arange(size * size), size)
    return np.stack([x, y], axis=1)


def behavior_loglik(states: torch.Tensor, actions: torch.Tensor, p_optimal: float, size: int) -> np.ndarray:
    """log π_g(ξ) of trajectories [B, H] under the mixed behavior policy for every goal g -> [B, size²]."""
    cells = states.numpy().astype(np.int64)[:, :, None, :]  # [B, H, 1, 2]
    best = optimal_actions(cells, grid_goals(size)[None, None])  # [B, H, G]
    match = best == actions.numpy().astype(np.int64)[:, :, None]
    step = np.log(np.where(match, p_optimal + (1 - p_optimal) / N_ACTIONS, (1 - p_optimal) / N_ACTIONS))
    return step.sum(1)


def label_loglik(context: TrajectoryPreferenceContext, size: int, temperature: float) -> np.ndarray:
    """log P(y | ξ_a, ξ_b, g) of the Bradley–Terry label for every goal g -> [B, size²]."""
    n = size * size
    diff = (goal_returns(landing_cells(context.states_a, context.actions_a, size), n)
            - goal_returns(landing_cells(context.states_b, context.actions_b, size), n)) / temperature
    sign = np.where(context.preferred.numpy()[:, None] > 0.5, 1.0, -1.0)
    return log_sigmoid(sign * diff)


def normalize(logp: np.ndarray) -> np.ndarray:
    """Rows of log-weights [B, G] -> probabilities summing to 1."""
    p = np.exp(logp - logp.max(1, keepdims=True))
    return p / p.sum(1, keepdims=True)


def posteriors(context: TrajectoryPreferenceContext, size: int, temperature: float, p_optimal: float
               ) -> dict[str, np.ndarray]:
    """p(g | evidence) [B, size²] under a uniform prior over cells, for each evidence of ``EVIDENCE``."""
    label = label_loglik(context, size, temperature)
    paths = (behavior_loglik(context.states_a, context.actions_a, p_optimal, size)
             + behavior_loglik(context.states_b, context.actions_b, p_optimal, size))
    return {"label": normalize(label), "trajectories": normalize(paths), "pair": normalize(paths + label)}


def bayes_rewards(post: np.ndarray, states: torch.Tensor, actions: torch.Tensor, size: int) -> np.ndarray:
    """r̄(s_h, a_h | D^T) = p(g = s'_h | D^T) for trajectories [B, T] -> [B, T]."""
    cells = landing_cells(states, actions, size)
    return np.take_along_axis(post, cells, axis=1)


def other_pair_accuracy(post: np.ndarray, scored: TrajectoryPreferenceContext, size: int, temperature: float) -> float:
    """The posterior predictive's winner of ``scored`` (another pair of the task) against its label."""
    n = size * size
    diff = (goal_returns(landing_cells(scored.states_a, scored.actions_a, size), n)
            - goal_returns(landing_cells(scored.states_b, scored.actions_b, size), n)) / temperature
    p_a = (post * (1.0 / (1.0 + np.exp(-diff)))).sum(1)
    return float(((p_a > 0.5) == (scored.preferred.numpy() > 0.5)).mean())


def goal_cells(family: DarkRoomFamily, task_index: np.ndarray) -> np.ndarray:
    """The held-out goal cell index y·size + x of each context."""
    goals = family.test_goals[task_index]
    return goals[:, 1] * family.size + goals[:, 0]


def reward_bayes(data_config: str | Path, data_root: str | None = None) -> dict[str, Any]:
    """The Bayes reward's measures from each evidence of ``EVIDENCE``, per quality, on ``data_config``'s held-out
    data (a DarkRoom T-PRL config labeled by the Bradley–Terry annotator)."""
    labeled = tprl_datamodule(data_config, "trajectory_preference", data_root)
    family = labeled.family
    if not isinstance(family, DarkRoomFamily):
        raise ValueError(f"--data-config {data_config}: the Bayes reward is computed for DarkRoom only, got "
                         f"{type(family).__name__}")
    temperature = labeled.setting.bt_temperature
    if temperature is None:
        raise ValueError(f"--data-config {data_config}: the labels must come from the Bradley–Terry annotator "
                         "(bt_temperature)")
    rewarded = tprl_datamodule(data_config, "reward_trajectory", data_root)
    labeled.prepare_data()
    rewarded.prepare_data()
    mixing = {q: c["mixing"] for q, c in labeled.load().manifest["info"]["calibration"].items()}
    suites = {s.quality: s for s in labeled.held_out("rollouts")}
    rewards = {s.quality: s.context.rewards for s in rewarded.held_out("rollouts")}
    pairs = labeled.held_out("pair_accuracy")
    out: dict[str, dict[str, dict[str, float]]] = {e: {} for e in EVIDENCE}
    for q in QUALITIES:
        context = suites[q].context
        post = posteriors(context, family.size, temperature, mixing[q])
        goals = goal_cells(family, np.asarray(suites[q].task_index))
        scored = pairs[q].context
        post_other = posteriors(pairs[q].pair, family.size, temperature, mixing[q])
        for e in EVIDENCE:
            r_bar = bayes_rewards(post[e], context.behavior_states, context.behavior_actions, family.size)
            out[e][q] = {
                "other_pair_accuracy": other_pair_accuracy(post_other[e], scored, family.size, temperature),
                "reward_correlation": float(np.corrcoef(r_bar.ravel(), rewards[q].numpy().ravel())[0, 1]),
                "posterior_on_goal": float(post[e][np.arange(len(goals)), goals].mean())}
    return {"data_config": str(data_config), "prior": f"uniform over the {family.size ** 2} cells",
            "temperature": temperature, "mixing": mixing, "evidence": EVIDENCE, "bayes": out}
