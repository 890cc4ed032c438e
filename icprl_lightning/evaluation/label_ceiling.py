"""How much do DarkRoom I-PRL contexts' labels say about the goal? The exact Bayesian answer.

    icprl analyze label-ceiling --config configs/icpo_darkroom.yaml \
        [--config configs/overlays/uniform_states.yaml] [--json ceiling.json]

For each held-out context of the config's dataset, the posterior over the goal cell given the context's
labels, under the generator's own Bradley–Terry model (eq. (i-prl-pref) with A* of each candidate goal,
uniform prior over all cells): P(g | D) ∝ Π_h σ(± (A*_g(s_h, a_h) − A*_g(s_h, a'_h)) / τ). Per context
quality: the share of contexts whose most probable goal is the true one, the posterior mass on the true
goal, and the return of an agent that walks to the most probable goal and stays (the optimal return when
that goal is right; a wrong cell earns ≈ 0, since deployment observes no reward): an upper bound on what any
in-context learner can earn from the labels alone, given the states as they are (the likelihood ignores
where the states came from, so with the paper's rollout states the states' own evidence is left out).
Privileged: it reads the oracle, for analysis only; it is not a method.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_advantage, optimal_value

CEILING = "return_walking_to_map_goal"  # the key of the ceiling: the return of walking to the posterior's mode


def goal_posterior(family: DarkRoomFamily, states: np.ndarray, first: np.ndarray, second: np.ndarray,
                   preferred: np.ndarray, temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """log P(g | D) over all cells [N, C] for contexts ``states`` [N, H, 2], actions [N, H], labels [N, H], and
    the cells [C, 2] in that order (index i·size + j for cell (i, j))."""
    n, horizon = preferred.shape
    cells = np.stack(np.meshgrid(np.arange(family.size), np.arange(family.size), indexing="ij"), -1).reshape(-1, 2)
    steps_left = family.horizon - np.arange(horizon)  # row h of a context was labeled with H − h steps left
    sign = np.where(preferred == 1, 1.0, -1.0)
    logp = np.zeros((n, len(cells)))
    for c, goal in enumerate(cells):
        goals = np.broadcast_to(goal, states.shape)
        diff = (optimal_advantage(states, first, goals, steps_left, family)
                - optimal_advantage(states, second, goals, steps_left, family)) / temperature
        logp[:, c] = -np.logaddexp(0.0, -sign * diff).sum(1)  # log σ(± diff) summed over the context
    logp -= logp.max(1, keepdims=True)
    return logp - np.log(np.exp(logp).sum(1, keepdims=True)), cells


def label_ceiling(configs: Sequence[str | Path], seed: int = 0) -> dict[str, Any]:
    """The ceiling of the module docstring for the dataset of ``configs`` (stacked as ``--config``), per quality.

    ``seed`` draws the start cells of the walk to the most probable goal.
    """
    dm = datamodule_from_config(*configs, progress=False)
    family = dm.family
    if not isinstance(family, DarkRoomFamily):
        raise ValueError(f"--config: the label ceiling is DarkRoom's (closed-form A*), the family is "
                         f"{type(family).__name__}")
    temperature = getattr(dm.setting, "bt_temperature", None)
    if dm.context_kind != "step_preference" or temperature is None:
        raise ValueError(f"--config: the label ceiling needs I-PRL step preferences labeled by the Bradley–Terry "
                         f"annotator (bt_temperature), got {type(dm.setting).__name__}")
    dm.prepare_data()
    data = dm.load()
    test_goals = np.asarray(data["tasks"][f"test_{family.task_name}"])
    out: dict[str, Any] = {"dataset": str(dm.path), "bt_temperature": temperature}
    rng = np.random.default_rng(seed)
    for q in QUALITIES:
        split = data[f"eval_{q}"]
        goals = test_goals[np.asarray(split["task_index"])]
        logp, _ = goal_posterior(family, np.asarray(split["states"]).astype(np.int64),
                                 np.asarray(split["actions"]).astype(np.int64),
                                 np.asarray(split["alt_actions"]).astype(np.int64),
                                 np.asarray(split["preferred"]), temperature)
        true = goals[:, 0] * family.size + goals[:, 1]
        best = logp.argmax(1)
        starts = family.sample_starts(goals, rng)
        optimal = optimal_value(starts, goals, family.horizon, family.terminate_on_goal)
        walk_to_map = np.where(best == true, optimal, 0.0)  # a wrong cell earns only what it passes through: ≈ 0
        out[q] = {"map_is_true_goal": float((best == true).mean()),
                  "posterior_on_true_goal": float(np.exp(logp[np.arange(len(true)), true]).mean()),
                  CEILING: float(walk_to_map.mean()), "optimal_return": float(optimal.mean()),
                  "contexts": int(len(true))}
    return out
