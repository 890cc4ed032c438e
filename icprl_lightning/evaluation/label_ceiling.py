"""How much do DarkRoom I-PRL contexts say about the goal, and which part says it? The exact Bayesian answer.

    icprl analyze label-ceiling --config configs/icpo_darkroom.yaml \
        [--config configs/overlays/uniform_states.yaml] [--json ceiling.json]

For each held-out context of the config's dataset, the posterior over the goal cell (uniform prior over all cells)
under the generator's own model, read by three readers (``READERS``):

* ``labels``: the labels given the pairs, Bradley–Terry with A* of each candidate goal, eq. (i-prl-pref):
  P(y | s, a, a', g) = σ(± (A*_g(s, a) − A*_g(s, a')) / τ);
* ``pair``: the unlabeled pairs alone, P(a, a' | s, g) ∝ π₁(a) π₂(a') + π₂(a) π₁(a') (the slots are shuffled),
  where π_p(a) = p·[a = a*_g(s)] + (1 − p)/|A| is the mixed policy of each side (p = 0: uniform; the second side
  at the context quality's calibrated mixing level unless ``second_policy`` is uniform);
* ``everything``: labels × pair × states. The states add nothing: drawn uniformly (``state_source: uniform``) they
  are independent of the goal, and a rollout's next state is the transition of the pair's followed action from a
  goal-independent start (so it is a function of what the other two read). A family that restarts at the goal
  (``terminate_on_goal``) leaks the goal through its restarts; that reader is refused there.

Per reader and quality: the share of contexts whose most probable goal is the true one, the posterior mass on the
true goal, and the return of an agent that walks to the most probable goal and stays (the optimal return when
that goal is right; a wrong cell earns ≈ 0, since deployment observes no reward): an upper bound on what any
in-context learner can earn from that part of the context. ``everything`` is the ceiling of the learning curves
(``reproduce/figures.read_ceiling``). Privileged: it reads the oracle, for analysis only; it is not a method.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.families.darkroom.env import N_ACTIONS
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_actions, optimal_advantage, optimal_value

CEILING = "return_walking_to_map_goal"  # the key of the ceiling: the return of walking to the posterior's mode
READERS = ("labels", "pair", "everything")
CEILING_READER = "everything"  # the reader whose ceiling the learning curves draw: what the whole context holds


def _cells(family: DarkRoomFamily) -> np.ndarray:
    """Every cell [C, 2], index i·size + j for cell (i, j)."""
    return np.stack(np.meshgrid(np.arange(family.size), np.arange(family.size), indexing="ij"), -1).reshape(-1, 2)


def _normalized(logp: np.ndarray) -> np.ndarray:
    logp = logp - logp.max(1, keepdims=True)
    return logp - np.log(np.exp(logp).sum(1, keepdims=True))


def goal_posterior(family: DarkRoomFamily, states: np.ndarray, first: np.ndarray, second: np.ndarray,
                   preferred: np.ndarray, temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """log P(g | labels) over all cells [N, C] for contexts ``states`` [N, H, 2], actions [N, H], labels [N, H], and
    the cells [C, 2] in that order (index i·size + j for cell (i, j))."""
    n, horizon = preferred.shape
    cells = _cells(family)
    steps_left = family.horizon - np.arange(horizon)  # row h of a context was labeled with H − h steps left
    sign = np.where(preferred == 1, 1.0, -1.0)
    logp = np.zeros((n, len(cells)))
    for c, goal in enumerate(cells):
        goals = np.broadcast_to(goal, states.shape)
        diff = (optimal_advantage(states, first, goals, steps_left, family)
                - optimal_advantage(states, second, goals, steps_left, family)) / temperature
        logp[:, c] = -np.logaddexp(0.0, -sign * diff).sum(1)  # log σ(± diff) summed over the context
    return _normalized(logp), cells


def pair_posterior(family: DarkRoomFamily, states: np.ndarray, first: np.ndarray, second: np.ndarray,
                   mixing: tuple[float, float]) -> np.ndarray:
    """log P(g | unlabeled pairs) [N, C]: each pair one action of π_{p₁} and one of π_{p₂} in shuffled slots, with
    ``mixing`` = (p₁, p₂) and π_p = p·[a = a*_g(s)] + (1 − p)/|A| (``optimal_actions``: the generator's a*)."""
    p1, p2 = mixing
    cells = _cells(family)
    logp = np.zeros((len(states), len(cells)))
    for c, goal in enumerate(cells):
        best = optimal_actions(states, np.broadcast_to(goal, states.shape))
        pi = [[p * (a == best) + (1 - p) / N_ACTIONS for p in (p1, p2)] for a in (first, second)]
        logp[:, c] = np.log(pi[0][0] * pi[1][1] + pi[0][1] * pi[1][0]).sum(1)
    return _normalized(logp)


def _pair_mixing(dm: Any, info: dict[str, Any], quality: str) -> tuple[float, float]:
    """(p₁, p₂) of a quality's eval contexts from the setting and the manifest's calibration."""
    setting, calibration = dm.setting, info["calibration"]
    first = 0.0 if setting.first_policy == "uniform" else float(calibration[setting.first_policy]["mixing"])
    second = 0.0 if setting.second_policy == "uniform" else float(calibration[quality]["mixing"])
    return first, second


def _summary(logp: np.ndarray, true: np.ndarray, optimal: np.ndarray) -> dict[str, float]:
    best = logp.argmax(1)
    walk_to_map = np.where(best == true, optimal, 0.0)  # a wrong cell earns only what it passes through: ≈ 0
    return {"map_is_true_goal": float((best == true).mean()),
            "posterior_on_true_goal": float(np.exp(logp[np.arange(len(true)), true]).mean()),
            CEILING: float(walk_to_map.mean())}


def label_ceiling(configs: Sequence[str | Path], seed: int = 0) -> dict[str, Any]:
    """The readers of the module docstring on the dataset of ``configs`` (stacked as ``--config``), per quality.

    ``seed`` draws the start cells of the walk to the most probable goal (the same starts for every reader).
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
    if family.terminate_on_goal and dm.setting.state_source == "rollout":
        raise ValueError("--config: family terminate_on_goal with rollout states: the restarts reveal the goal, "
                         "which the `everything` reader does not model; use terminate_on_goal: false")
    dm.prepare_data()
    data = dm.load()
    test_goals = np.asarray(data["tasks"][f"test_{family.task_name}"])
    out: dict[str, Any] = {"dataset": str(dm.path), "bt_temperature": temperature,
                           "setting": {k: v for k, v in dm.setting.knobs().items() if k != "bt_temperature"}}
    rng = np.random.default_rng(seed)
    for q in QUALITIES:
        split = data[f"eval_{q}"]
        goals = test_goals[np.asarray(split["task_index"])]
        states, first, second = (np.asarray(split[k]).astype(np.int64) for k in ("states", "actions", "alt_actions"))
        labels, _ = goal_posterior(family, states, first, second, np.asarray(split["preferred"]), temperature)
        mixing = _pair_mixing(dm, data.manifest["info"], q)
        pair = pair_posterior(family, states, first, second, mixing)
        true = goals[:, 0] * family.size + goals[:, 1]
        starts = family.sample_starts(goals, rng)
        optimal = optimal_value(starts, goals, family.horizon, family.terminate_on_goal)
        posteriors = {"labels": labels, "pair": pair, "everything": _normalized(labels + pair)}
        out[q] = {**{name: _summary(posteriors[name], true, optimal) for name in READERS},
                  "pair_mixing": list(mixing), "optimal_return": float(optimal.mean()), "contexts": int(len(true))}
    return out


def ceiling_page(folder: Path) -> str | None:
    """The summary page of a folder of ``icprl analyze label-ceiling`` JSONs (``None``: it holds none)."""
    payloads = [(path.stem, json.loads(path.read_text())) for path in sorted(folder.glob("*.json"))]
    payloads = [(name, p) for name, p in payloads
                if isinstance(p, dict) and "bt_temperature" in p and all(isinstance(p.get(q), dict) for q in QUALITIES)]
    return ceiling_markdown(payloads) if payloads else None


def ceiling_markdown(payloads: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """One table of every reader's return per quality, a row per (ceiling JSON, reader), for the docs."""
    lines = ["<!-- generated by `icprl reproduce --render` from the JSON files of this folder; do not edit -->", "",
             "Return of walking to the most probable goal under each reader (`icprl analyze label-ceiling`), "
             "mean over the held-out contexts; in brackets the share whose most probable goal is the true one.", "",
             f"| data (JSON) | τ | reader | {' | '.join(QUALITIES)} |", "|---|---|---|" + "---|" * len(QUALITIES)]
    for name, payload in payloads:
        for reader in READERS:
            cells = [f"{payload[q][reader][CEILING]:.1f} ({payload[q][reader]['map_is_true_goal']:.2f})"
                     for q in QUALITIES]
            lines.append(f"| `{name}` | {payload['bt_temperature']:g} | {reader} | {' | '.join(cells)} |")
        optimal = " | ".join(f"{payload[q]['optimal_return']:.1f}" for q in QUALITIES)
        lines.append(f"| `{name}` |  | (optimal return) | {optimal} |")
    return "\n".join(lines) + "\n"

