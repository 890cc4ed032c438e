"""Each built-in family's own ``calibrate`` / ``references`` is a justified exception to the shared ones
(``families/calibration.py``): measured by the shared simulation, it agrees within its noise.

The shared default is the path for a new family; the built-in overrides exist for the reasons their docstrings
give (DarkRoom: the exact closed-form optimum and its R / R* scale; Meta-World Reach: a cheaper grid and success
rates; the SAC recipe: checkpoints, not mixtures). These tests check that none of them measures something else:

* a calibration's mixing levels, simulated by ``calibration.simulate_returns`` (common random numbers), reach
  their targets within the noise of both measurements (bootstrap over episodes);
* a family's references agree with ``calibration.references_by_simulation`` on the same held-out tasks.

The Meta-World ones run MuJoCo episodes (about a minute each on 2 cores): slow.
"""

from __future__ import annotations

import numpy as np
import pytest

from icprl_lightning.families.calibration import calibrate_by_simulation, references_by_simulation, simulate_returns
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_value

TARGETS = {"low": 0.2, "medium": 0.4, "high": 0.8}
Z = 4.0  # how many standard deviations of noise a difference may span


def shares(returns: np.ndarray, baseline: bool) -> np.ndarray:
    """Share of the last row's mean return reached by each middle row of ``returns`` [P, E]: (R − R_0) / (R_last −
    R_0) with the first row as the uniform baseline, or R / R_last without one (row 0 then unused)."""
    mean = returns.mean(axis=1)
    base = mean[0] if baseline else 0.0
    return (mean[1:-1] - base) / (mean[-1] - base)


def shares_with_noise(returns: np.ndarray, baseline: bool, draws: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """``shares`` and their bootstrap standard deviation over episodes, resampled jointly (common random numbers)."""
    idx = np.random.default_rng(0).integers(0, returns.shape[1], (draws, returns.shape[1]))
    return shares(returns, baseline), np.std([shares(returns[:, i], baseline) for i in idx], axis=0)


def reached_targets(family, calibration: dict, calibration_episodes: int, episodes: int, baseline: bool) -> None:
    """The calibrated levels, simulated by the shared simulation on ``episodes`` training episodes, reach their
    targets within the noise of this measurement and of the calibration's own (``calibration_episodes``)."""
    train = family.tasks("train")
    tasks = train[np.resize(np.arange(len(train)), episodes)]
    levels = np.array([0.0, *(calibration[q]["mixing"] for q in TARGETS), 1.0])
    measured, noise = shares_with_noise(simulate_returns(family, tasks, levels, seed=12345), baseline)
    tolerance = Z * noise * np.sqrt(1 + episodes / calibration_episodes)
    targets = np.array(list(TARGETS.values()))
    assert np.all(np.abs(measured - targets) < tolerance), (measured, targets, tolerance)


def agree(a: float, b: float, sem_a: float, sem_b: float) -> None:
    assert abs(a - b) <= Z * np.hypot(sem_a, sem_b) + 1e-9, (a, b, sem_a, sem_b)


def agree_per_task(a: list[float], b: list[float]) -> None:
    """Per-task means of the same tasks: their mean difference is within the noise of the differences."""
    d = np.asarray(a) - np.asarray(b)
    assert abs(d.mean()) <= Z * d.std(ddof=1) / np.sqrt(len(d)) + 1e-9, d


# ---- DarkRoom: closed-form optimum, R / R* ----------------------------------------------------------------

def test_darkroom_calibration_reaches_its_targets_in_the_shared_simulation():
    family = DarkRoomFamily()
    calibration = family.calibrate(TARGETS, episodes=10, seed=0)  # 10 per goal: 800 episodes per level
    reached_targets(family, calibration, 10 * len(family.tasks("train")), 800, baseline=False)


def test_darkroom_calibration_finds_the_shared_calibrations_levels():
    """The shared calibration, asked for the same shares on its own scale ((R − U) / (R* − U) for R / R* = t), finds
    the same mixing levels as DarkRoom's, within the seed-to-seed spread of DarkRoom's."""
    family = DarkRoomFamily()
    n_train = len(family.tasks("train"))
    own = np.array([[family.calibrate(TARGETS, 10, seed=s)[q]["mixing"] for q in TARGETS] for s in range(6)])
    first = calibrate_by_simulation(family, TARGETS, 10 * n_train, seed=0)["low"]
    uniform, optimal = first["uniform_return"], first["optimal_return"]
    converted = {q: (t * optimal - uniform) / (optimal - uniform) for q, t in TARGETS.items()}
    shared = calibrate_by_simulation(family, converted, 10 * n_train, seed=1)
    spread = own.std(axis=0, ddof=1)
    for i, q in enumerate(TARGETS):
        assert abs(shared[q]["mixing"] - own[:, i].mean()) < Z * spread[i] * np.sqrt(1 + 1 / len(own)), (
            q, shared[q]["mixing"], own[:, i], spread[i])


def test_darkroom_references_agree_with_the_shared_simulation():
    family = DarkRoomFamily()
    test, mixing, episodes = family.tasks("test"), {"low": 0.28, "medium": 0.44, "high": 0.78}, 25
    own = family.references(test, mixing, episodes, np.random.default_rng(0))["test_reference"]
    shared = references_by_simulation(family, test, mixing, episodes, np.random.default_rng(1))["test_reference"]
    # the optimal return of an episode is V* of its uniform start: its spread over starts bounds the noise
    rng = np.random.default_rng(2)
    goals = np.repeat(test, 1000, axis=0)
    v = optimal_value(rng.integers(0, family.size, goals.shape), goals, family.horizon, family.terminate_on_goal)
    optimal_sem = v.std() / np.sqrt(len(test) * episodes)
    for q in mixing:
        agree(own[q]["behavior_return"], shared[q]["behavior_return"], own[q]["behavior_return_sem"],
              shared[q]["behavior_return_sem"])
        agree(own[q]["optimal_return"], shared[q]["optimal_return"], optimal_sem, optimal_sem)


# ---- Meta-World Reach: the scripted expert, a cheaper grid ------------------------------------------------

@pytest.mark.slow
def test_reach_calibration_reaches_its_targets_and_its_references_agree_with_the_shared_simulation():
    from icprl_lightning.families.metaworld_reach import ReachTaskFamily

    family = ReachTaskFamily(num_workers=2)
    calibration = family.calibrate(TARGETS, episodes=16, seed=0)
    reached_targets(family, calibration, 16, 24, baseline=True)

    test, mixing = family.tasks("test"), {q: calibration[q]["mixing"] for q in TARGETS}
    own = family.references(test, mixing, 4, np.random.default_rng(0))
    shared = references_by_simulation(family, test, mixing, 4, np.random.default_rng(1))
    for q in TARGETS:
        a, b = own["test_reference"][q], shared["test_reference"][q]
        agree(a["behavior_return"], b["behavior_return"], a["behavior_return_sem"], b["behavior_return_sem"])
        assert 0.0 <= a["behavior_success"] <= 1.0  # what the shared references do not measure
    agree_per_task(own["test_reference_per_task"]["uniform_return"],
                   shared["test_reference_per_task"]["uniform_return"])
    agree_per_task(own["test_reference_per_task"]["expert_return"],  # the oracle's optimal action is the expert's
                   shared["test_reference_per_task"]["optimal_return"])


# ---- the SAC recipe: checkpoints, not mixtures ------------------------------------------------------------

@pytest.mark.slow
def test_sac_calibration_and_references_measure_what_the_shared_simulation_does_at_its_ends():
    """The shared simulation at p = 0 and p = 1 is uniform actions and π's mean action: the SAC calibration's and
    references' uniform and π returns agree with it; each exported checkpoint still holds its level."""
    from icprl_lightning.families.metaworld_reach.sac_family import ReachSACTaskFamily

    family = ReachSACTaskFamily(num_workers=2)
    calibration = family.calibrate(TARGETS, episodes=16, seed=0)
    train = family.tasks("train")
    ends = simulate_returns(family, train[np.resize(np.arange(len(train)), 24)], np.array([0.0, 1.0]), seed=7)
    for i, key in enumerate(("uniform_return", "sac_return")):
        spread = ends[i].std(ddof=1)
        agree(calibration["low"][key], ends[i].mean(), spread / np.sqrt(16), spread / np.sqrt(24))
    for q, target in TARGETS.items():
        # export picked the 10k-step checkpoint nearest each share (0.19 / 0.43 / 0.75 when exported)
        assert abs(calibration[q]["achieved"] - target) < 0.1, calibration[q]

    test = family.tasks("test")
    own = family.references(test, {q: calibration[q]["mixing"] for q in TARGETS}, 4, np.random.default_rng(0))
    shared = references_by_simulation(family, test, {}, 4, np.random.default_rng(1))
    agree_per_task(own["test_reference_per_task"]["uniform_return"],
                   shared["test_reference_per_task"]["uniform_return"])
    pi = np.asarray(shared["test_reference_per_task"]["optimal_return"])
    agree(own["test_reference"]["low"]["sac_return"], pi.mean(), pi.std(ddof=1) / np.sqrt(len(pi)),
          pi.std(ddof=1) / np.sqrt(len(pi)))
