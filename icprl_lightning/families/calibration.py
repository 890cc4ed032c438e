"""Behavior calibration and held-out references by simulation, written once for every family.

The paper's context qualities are behavior policies at ≈ 20/40/80% of the optimal return (appendix
"Pretraining Data Generation"). With a mixing level p (the optimal action with probability p, else a
uniform one) quality is the normalized return

    q(p) = (R(π_p) − R(uniform)) / (R(optimal) − R(uniform)),

measured here by simulation on the training tasks with common random numbers (every p sees the same
tasks, starts and coins), made monotone and inverted (``invert_quality_curve``). This is the default
``TaskFamily.calibrate`` / ``references``; the built-in families override them, each giving its reason.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from icprl_lightning.metrics import mean_sem, per_task_mean


class Simulated(Protocol):
    """What the simulation reads of a family (every ``families.base.TaskFamily`` has it): its horizon, its oracle's
    uniform and optimal actions, its task splits and its episode rollouts."""

    horizon: int

    @property
    def oracle(self) -> Any: ...

    def tasks(self, split: str) -> np.ndarray: ...

    def episode_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> Any: ...

CALIBRATION_GRID = tuple(np.round(np.linspace(0.0, 1.0, 21), 2))


def invert_quality_curve(mixing: np.ndarray, quality: np.ndarray, targets: Mapping[str, float]) -> dict[str, float]:
    """The calibration step shared by every family: the mixing level that reaches each target quality.

    ``quality`` [G] is a measured quality (share of the optimal return) of the mixing levels [G]; it is
    made monotone (a higher p never hurts, up to noise), and each target is inverted by interpolation.
    A target outside the measured range is an error naming the quality and the range.
    """
    curve = np.maximum.accumulate(np.asarray(quality, dtype=np.float64))
    out = {}
    for name, target in targets.items():
        if not curve[0] <= target <= curve[-1]:
            raise ValueError(f"quality {name!r}: target {target} of the optimal return is outside what the "
                             f"mixed policy reaches here [{curve[0]:.3f}, {curve[-1]:.3f}]")
        out[name] = float(np.interp(target, curve, mixing))
    return out


def simulate_returns(family: Simulated, tasks: np.ndarray, mixing: np.ndarray, seed: int) -> np.ndarray:
    """Latent returns [P, E] of the mixed policies ``mixing`` [P] on episodes of ``tasks`` [E].

    Common random numbers: every policy meets the same starts (one env seed) and, on episode e at step
    h, the same coin and the same uniform action, so differences between p are not drowned in noise.
    """
    ps, n = np.asarray(mixing, dtype=np.float64), len(tasks)
    env_seed, action_seed = np.random.SeedSequence(seed).generate_state(2)
    rng = np.random.default_rng(action_seed)
    total = np.zeros(len(ps) * n)
    rows = np.tile(tasks, (len(ps), *[1] * (tasks.ndim - 1)))
    with family.episode_rollouts(rows, np.random.default_rng(env_seed)) as roll:
        for _ in range(family.horizon):
            state = roll.oracle_state()
            follow = np.tile(rng.random(n), len(ps)) < np.repeat(ps, n)
            uniform = np.concatenate([family.oracle.uniform_actions(state, rng)[:n]] * len(ps))
            optimal = family.oracle.optimal_actions(state)
            actions = np.where(follow.reshape(-1, *[1] * (optimal.ndim - 1)), optimal, uniform)
            total += roll.step(actions)[1]
    return total.reshape(len(ps), n)


def calibrate_by_simulation(family: Simulated, targets: Mapping[str, float], episodes: int, seed: int,
                            grid: tuple[float, ...] = CALIBRATION_GRID) -> dict[str, dict[str, float]]:
    """The mixing level of each target normalized return, measured on ``episodes`` training episodes."""
    fit_seed, check_seed = np.random.SeedSequence(seed).generate_state(2)
    train = family.tasks("train")
    tasks = train[np.resize(np.arange(len(train)), episodes)]
    ps = np.asarray(grid, dtype=np.float64)
    mean = simulate_returns(family, tasks, ps, int(fit_seed)).mean(axis=1)
    chosen = invert_quality_curve(ps, (mean - mean[0]) / (mean[-1] - mean[0]), targets)
    check = simulate_returns(family, tasks, np.array([0.0, *chosen.values(), 1.0]), int(check_seed)).mean(axis=1)
    achieved = (check - check[0]) / (check[-1] - check[0])
    return {name: {"target": float(targets[name]), "mixing": p, "achieved": float(q),
                   "uniform_return": float(check[0]), "optimal_return": float(check[-1])}
            for (name, p), q in zip(chosen.items(), achieved[1:-1], strict=True)}


def references_by_simulation(family: Simulated, tasks: np.ndarray, mixing: Mapping[str, float], episodes: int,
                             rng: np.random.Generator) -> dict[str, Any]:
    """Behavior, uniform and optimal returns on each held-out task (``episodes`` each), and their means."""
    task_of = np.repeat(np.arange(len(tasks)), episodes)
    returns = simulate_returns(family, np.repeat(tasks, episodes, axis=0), np.array([0.0, *mixing.values(), 1.0]),
                               int(rng.integers(2**31)))
    per_task = [per_task_mean(r, task_of) for r in returns]  # uniform, the behaviors, optimal
    uniform, optimal = per_task[0], per_task[-1]
    reference = {}
    for i, q in enumerate(mixing, start=1):
        b_mean, b_sem = mean_sem(per_task[i])
        reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem,
                        "behavior_normalized_return": mean_sem((per_task[i] - uniform) / (optimal - uniform))[0],
                        "optimal_return": mean_sem(optimal)[0], "uniform_return": mean_sem(uniform)[0]}
    return {"test_reference": reference,
            "test_reference_per_task": {"uniform_return": uniform.tolist(), "optimal_return": optimal.tolist()}}
