"""The mixed behavior policy simulated on Meta-World Reach: its returns, the calibration of its mixing levels to
the quality targets, and the agreement of I-PRL step labels (``family.py`` calls the first two; they take the
family by the three things they use, ``Simulator``, so this file imports the oracle and never the family).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from icprl_lightning.families.calibration import invert_quality_curve
from icprl_lightning.families.metaworld_reach.env import ACTION_DIM
from icprl_lightning.families.metaworld_reach.oracle import (
    CALIBRATION_GRID,
    QUALITY_TARGETS,
    advantage,
    expert_actions,
    normalized_return,
)
from icprl_lightning.preferences import label_agreement, sample_preferences


class Simulator(Protocol):
    """What the simulation reads of a Reach family (``ReachTaskFamily`` is one)."""

    train_goals: np.ndarray

    @property
    def oracle(self) -> Any: ...

    def make_env(self, goals: np.ndarray, num_workers: int = ...) -> Any: ...


def rollout_returns(family: Simulator, goals: np.ndarray, p_expert: np.ndarray, seed: int,
                    num_workers: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Latent returns [P, E] and success [P, E] of the mixed policy for each p on each goal.

    Success is metaworld's episode criterion, as ``evaluation.rollout_in_context`` counts it: the TCP
    came within 0.05 of the goal at some step.

    The P policies share common random numbers: on goal e at step h they all draw the same coin u and
    the same uniform action (and follow the expert iff u < p), so differences between p values are not
    drowned by episode noise.
    """
    ps, goals = np.asarray(p_expert, dtype=np.float64), np.asarray(goals, dtype=np.float64)
    n_p, n_goals = len(ps), len(goals)
    env_seq, action_seq = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(action_seq)
    total = np.zeros(n_p * n_goals)
    success = np.zeros(n_p * n_goals, dtype=bool)
    with family.make_env(np.tile(goals, (n_p, 1)), num_workers=num_workers) as env:
        env.reset(seed=int(env_seq.generate_state(1)[0]))
        for _ in range(env.horizon):
            follow = np.tile(rng.random(n_goals), n_p) < np.repeat(ps, n_goals)
            uniform = np.tile(rng.uniform(-1.0, 1.0, size=(n_goals, ACTION_DIM)), (n_p, 1))
            actions = np.where(follow[:, None], expert_actions(env.oracle_state()), uniform)
            _, reward, _, _, info = env.step(actions)
            total += reward
            success |= info["success"]
    return total.reshape(n_p, n_goals), success.reshape(n_p, n_goals)


def calibrate_mixing(family: Simulator, targets: Mapping[str, float] = QUALITY_TARGETS,
                     episodes: int = 16, seed: int = 0, grid: tuple[float, ...] = CALIBRATION_GRID,
                     num_workers: int = 2) -> dict[str, dict[str, float]]:
    """p per quality so the mixed policy earns ``target`` of the expert's normalized return.

    Simulates every p of ``grid`` (which must run from 0 to 1: the uniform and expert baselines) on
    the same ``episodes`` training goals with common random numbers, makes the normalized-return curve
    monotone, inverts it by interpolation, then re-simulates the chosen p beside uniform and expert
    runs on freshly drawn goals and noise to report the achieved normalized return.
    Cost: (len(grid) + len(targets) + 2) × ``episodes`` episodes of ``family.horizon`` steps.
    """
    ps = np.asarray(grid, dtype=np.float64)
    if ps[0] != 0.0 or ps[-1] != 1.0 or np.any(np.diff(ps) <= 0):
        raise ValueError(f"grid must increase from 0 to 1, got {ps.tolist()}")
    for name, target in targets.items():
        if not 0.0 < target < 1.0:
            raise ValueError(f"quality {name!r}: target {target} must lie strictly between 0 and 1")
    fit_seq, check_seq = np.random.SeedSequence(seed).spawn(2)
    curve, _ = _normalized_curve(family, ps, episodes, fit_seq, num_workers)
    chosen = invert_quality_curve(ps, curve, targets)
    achieved, (uniform, expert) = _normalized_curve(family, np.array([0.0, *chosen.values(), 1.0]),
                                                    episodes, check_seq, num_workers)
    return {name: {"target": float(targets[name]), "mixing": p, "achieved": float(q),
                   "uniform_return": uniform, "expert_return": expert}
            for (name, p), q in zip(chosen.items(), achieved[1:-1], strict=True)}


def _normalized_curve(family: Simulator, ps: np.ndarray, episodes: int, seq: np.random.SeedSequence,
                      num_workers: int) -> tuple[np.ndarray, tuple[float, float]]:
    """Normalized return of each p (ps[0] = 0 and ps[-1] = 1 are the baselines) on shared goals."""
    goal_seq, roll_seq = seq.spawn(2)
    goals = family.train_goals
    goals = goals[np.random.default_rng(goal_seq).permutation(np.resize(np.arange(len(goals)), episodes))]
    returns, _ = rollout_returns(family, goals, ps, int(roll_seq.generate_state(1)[0]), num_workers)
    mean = returns.mean(axis=1)
    return normalized_return(mean, mean[0], mean[-1]), (float(mean[0]), float(mean[-1]))


def step_label_agreement(family: Simulator, p_first: float, p_second: float, bt_temperature: float,
                         episodes: int = 10, seed: int = 0, num_workers: int = 2) -> dict[str, float]:
    """Label agreement of I-PRL step labels y ~ BT(A(s, a) − A(s, a')) for a ~ π_p_first, a' ~ π_p_second.

    Runs the paper's I-PRL generation on ``episodes`` training goals (the state follows the preferred
    action) and reports the share of labels agreeing with the sign of the A difference (ties, e.g. two
    expert actions, left out), the share of ties and the median |ΔA| of the rest.
    """
    env_seq, goal_seq, act_seq = np.random.SeedSequence(seed).spawn(3)
    rng = np.random.default_rng(act_seq)
    goals = family.train_goals
    goals = goals[np.random.default_rng(goal_seq).permutation(np.resize(np.arange(len(goals)), episodes))]
    diffs, labels = [], []
    with family.make_env(goals, num_workers=num_workers) as env:
        env.reset(seed=int(env_seq.generate_state(1)[0]))
        for _ in range(env.horizon):
            state = env.oracle_state()
            first, second = (family.oracle.behavior_actions(state, p, rng) for p in (p_first, p_second))
            diff = advantage(state, first, env.horizon) - advantage(state, second, env.horizon)
            y = sample_preferences(diff, np.zeros_like(diff), bt_temperature, rng)
            env.step(np.where(y[:, None] == 1, first, second))
            diffs.append(diff)
            labels.append(y)
    diff, y = np.concatenate(diffs), np.concatenate(labels)
    return {"agreement": label_agreement(diff, np.zeros_like(diff), y), "tie_share": float(np.mean(diff == 0)),
            "median_abs_diff": float(np.median(np.abs(diff[diff != 0])))}
