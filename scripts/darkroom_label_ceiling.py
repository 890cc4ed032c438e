"""How much do DarkRoom I-PRL contexts' labels say about the goal? The exact Bayesian answer.

    python scripts/darkroom_label_ceiling.py --config configs/icpo_darkroom.yaml \
        --config configs/overlays/uniform_states.yaml [--ignore-states]

For each held-out context of the config's dataset, the posterior over the goal cell given the context's
labels, under the generator's own Bradley–Terry model (eq. (i-prl-pref) with A* of each candidate goal,
uniform prior over all cells): P(g | D) ∝ Π_h σ(± (A*_g(s_h, a_h) − A*_g(s_h, a'_h)) / τ). It prints, per
context quality, the share of contexts whose most probable goal is the true one, the posterior mass on
the true goal, and the return of an agent that walks to the most probable goal and stays (the optimal
return when that goal is right): an upper bound on what any in-context learner can earn from the labels
alone, given the states as they are (the likelihood ignores where the states came from, so with the
paper's rollout states the states' own evidence is left out). Privileged: it reads the oracle, for
analysis only; it is not a method. Prints JSON.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.families.darkroom.oracle import optimal_advantage, optimal_value


def goal_posterior(family, states: np.ndarray, first: np.ndarray, second: np.ndarray, preferred: np.ndarray,
                   temperature: float) -> np.ndarray:
    """log P(g | D) over all cells [N, C] for contexts ``states`` [N, H, 2], actions [N, H], labels [N, H]."""
    n, horizon = preferred.shape
    cells = np.stack(np.meshgrid(np.arange(family.size), np.arange(family.size), indexing="ij"), -1).reshape(-1, 2)
    steps_left = family.horizon - np.arange(horizon)  # row h of a context was labeled with H − h steps left
    logp = np.zeros((n, len(cells)))
    for c, goal in enumerate(cells):
        goals = np.broadcast_to(goal, states.shape)
        diff = (optimal_advantage(states, first, goals, steps_left, family)
                - optimal_advantage(states, second, goals, steps_left, family)) / temperature
        sign = np.where(preferred == 1, 1.0, -1.0)
        logp[:, c] = -np.logaddexp(0.0, -sign * diff).sum(1)  # log σ(± diff) summed over the context
    logp -= logp.max(1, keepdims=True)
    return logp - np.log(np.exp(logp).sum(1, keepdims=True)), cells


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", action="append", required=True)
    args = parser.parse_args(argv)
    dm = datamodule_from_config(*args.config, progress=False)
    dm.prepare_data()
    data, family = dm.load(), dm.family
    temperature = dm.setting.bt_temperature
    test_goals = np.asarray(data["tasks"][f"test_{family.task_name}"])
    out = {"dataset": str(dm.path), "bt_temperature": temperature}
    rng = np.random.default_rng(0)
    for q in QUALITIES:
        split = data[f"eval_{q}"]
        goals = test_goals[np.asarray(split["task_index"])]
        logp, cells = goal_posterior(family, np.asarray(split["states"]).astype(np.int64),
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
                  "return_walking_to_map_goal": float(walk_to_map.mean()), "optimal_return": float(optimal.mean()),
                  "contexts": int(len(true))}
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
