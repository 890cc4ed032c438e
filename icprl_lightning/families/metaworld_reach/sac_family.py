"""Meta-World Reach on the paper's data recipe: a converged SAC as the oracle (appendix "Pretraining Data
Generation", "Meta-World (Reach-v2)").

``ReachSACTaskFamily`` is ``ReachTaskFamily`` (same goals, envs and split) whose oracle is an exported SAC
oracle (``sac_weights.py``) instead of the scripted TCP expert. A behavior policy's *level* (the generic
recipes' mixing level p) names an exported checkpoint at that share of π's return, acting by *sampling*
(level 0: uniform actions, 1: π); the optimal action is π's mean action tanh(μ(s)); the utility of an action
is Q̂(s, a), the minimum of the final twin critic, so a label reads A*(s, a) − A*(s, a') = Q̂(s, a) − Q̂(s, a')
(the baseline E_{a'~π} Q̂(s, a') of the paper's A* cancels). Held-out returns are normalized by the scripted
expert, so the two recipes' tables are on one scale. Privileged: it reads the goal-visible observation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.families.base import Oracle
from icprl_lightning.families.metaworld_reach.env import ACTION_DIM, HORIZON, ReachOracleState
from icprl_lightning.families.metaworld_reach.family import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.oracle import expert_actions
from icprl_lightning.families.metaworld_reach.sac_weights import CHECKSUMS, FINAL, ExportedSAC
from icprl_lightning.io import sha256
from icprl_lightning.metrics import mean_sem, per_task_mean

PACKAGED_ORACLES = Path(__file__).parent
DEFAULT_ORACLE_NAME = "sac_oracle_v1"
DEFAULT_ORACLE = PACKAGED_ORACLES / DEFAULT_ORACLE_NAME


def oracle_path(oracle_dir: str | Path) -> Path:
    """``oracle_dir`` as given; a bare name (no folder part) that is not a folder of the working directory names an
    oracle shipped in the package (``sac_oracle_v1``). The default is that bare name, so a saved run config, and a
    model exported from it, carries no machine's absolute path."""
    path = Path(oracle_dir)
    if not path.exists() and path.parent == Path(".") and (PACKAGED_ORACLES / path.name).is_dir():
        return PACKAGED_ORACLES / path.name
    return path

# (state, standard-normal noise [N, 4], uniform actions [N, 4]) -> actions [N, 4]
PolicyFn = Callable[[ReachOracleState, np.ndarray, np.ndarray], np.ndarray]


class ReachSACOracle(Oracle):
    """The ``Oracle`` of ``families/base.py`` backed by an exported SAC oracle; see the module docstring."""

    def __init__(self, weights: ExportedSAC) -> None:
        self.weights = weights

    @staticmethod
    def _obs(state: ReachOracleState) -> np.ndarray:
        if state.obs is None:
            raise ValueError("the SAC oracle needs the goal-visible observation (ReachOracleState.obs)")
        return state.obs

    def uniform_actions(self, state: ReachOracleState, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, size=(len(state.hand), ACTION_DIM)).astype(np.float32)

    def optimal_actions(self, state: ReachOracleState) -> np.ndarray:
        return self.weights.mean_actions(self._obs(state))

    def behavior_actions(self, state: ReachOracleState, mixing: np.ndarray | float,
                         rng: np.random.Generator) -> np.ndarray:
        """Per row, a sample of the checkpoint at that row's level (0: uniform).

        Draws, in order: standard-normal noise [N, 4], then uniform actions [N, 4] (the order is part of a
        dataset's bytes).
        """
        n = len(state.hand)
        levels = np.broadcast_to(np.asarray(mixing, dtype=np.float64), (n,))
        noise = rng.standard_normal((n, ACTION_DIM))
        out = self.uniform_actions(state, rng)
        for level in np.unique(levels):
            if level == 0.0:
                continue
            rows = levels == level
            out[rows] = self.weights.sample_actions(self._obs(state)[rows], float(level), noise[rows])
        return out

    def utility(self, state: ReachOracleState, actions: np.ndarray) -> np.ndarray:
        """Q̂(s, a) of K candidates [K, N, 4] -> [K, N]: at one state its differences are differences of A*."""
        return self.weights.q_values(self._obs(state), actions)


class ReachSACTaskFamily(ReachTaskFamily):
    """Reach with the SAC oracle at ``oracle_dir`` (default: the committed ``sac_oracle_v1``)."""

    name = "metaworld_reach_sac"

    def __init__(self, oracle_dir: str | Path = DEFAULT_ORACLE_NAME, seed: int = 0, n_train: int = 45, n_test: int = 5,
                 horizon: int = HORIZON, num_workers: int = 2, fresh_test_goals: int = 0) -> None:
        super().__init__(seed=seed, n_train=n_train, n_test=n_test, horizon=horizon, num_workers=num_workers,
                         fresh_test_goals=fresh_test_goals)
        self.oracle_dir = oracle_path(oracle_dir)
        self.weights = ExportedSAC(self.oracle_dir)  # verifies the checksums now, not mid-generation

    @cached_property
    def oracle(self) -> ReachSACOracle:  # type: ignore[override]
        return ReachSACOracle(self.weights)

    def _simulate(self, goals: np.ndarray, policies: Mapping[str, PolicyFn], seed: int
                  ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Return [E] and success [E] of each policy on episodes of ``goals`` [E, 3], all in one vector env.

        Common random numbers: every policy meets the same starts, the same noise and the same uniform draws.
        """
        env_seed, action_seed = np.random.SeedSequence(seed).generate_state(2)
        rng = np.random.default_rng(action_seed)
        e, k = len(goals), len(policies)
        total, success = np.zeros(k * e), np.zeros(k * e, dtype=bool)
        with self.make_env(np.tile(goals, (k, 1))) as env:
            env.reset(seed=int(env_seed))
            for _ in range(env.horizon):
                state = env.oracle_state()
                noise, uniform = rng.standard_normal((e, ACTION_DIM)), rng.uniform(-1, 1, (e, ACTION_DIM))
                actions = np.concatenate([
                    fn(ReachOracleState(*(f[i * e:(i + 1) * e] if isinstance(f, np.ndarray) else f for f in state)),
                       noise, uniform) for i, fn in enumerate(policies.values())])
                _, reward, _, _, info = env.step(actions)
                total += reward
                success |= info["success"]
        return {name: (total[i * e:(i + 1) * e], success[i * e:(i + 1) * e]) for i, name in enumerate(policies)}

    def _policies(self, levels: Mapping[str, float]) -> dict[str, PolicyFn]:
        w = self.weights
        out: dict[str, PolicyFn] = {"uniform": lambda s, noise, u: u.astype(np.float32)}
        for name, level in levels.items():
            out[name] = lambda s, noise, u, level=level: w.sample_actions(s.obs, level, noise)
        out["sac"] = lambda s, noise, u: w.mean_actions(s.obs)
        out["expert"] = lambda s, noise, u: expert_actions(s)
        return out

    def calibrate(self, targets: Mapping[str, float], episodes: int, seed: int) -> dict[str, dict[str, float]]:
        """Each target's exported checkpoint (level = target), its share measured on ``episodes`` training episodes.

        An exception to the shared calibration (``families/calibration.py``), which cannot apply here: the
        behavior policies are SAC checkpoints, not mixtures of optimal and uniform actions, so there is no
        mixing level to search. A level names the checkpoint whose share of π's return was measured when the
        oracle was exported; this re-measures it, beside the uniform and π returns that the shared simulation
        measures at p = 0 and p = 1 (they agree within its noise: tested).
        """
        levels = {name: self.weights.resolve_level(t) for name, t in targets.items()}  # KeyError names a missing one
        train = self.train_goals
        goals = train[np.random.default_rng(seed).permutation(np.resize(np.arange(len(train)), episodes))]
        sim = {k: r.mean() for k, (r, _) in self._simulate(goals, self._policies(levels), seed).items()}
        uniform, final, expert = sim["uniform"], sim["sac"], sim["expert"]
        return {name: {"target": float(targets[name]), "mixing": level,
                       "achieved": float((sim[name] - uniform) / (final - uniform)),
                       "achieved_vs_expert": float((sim[name] - uniform) / (expert - uniform)),
                       "checkpoint_step": int(self.weights.policy_info(level)["step"]),
                       "uniform_return": float(uniform), "sac_return": float(final), "expert_return": float(expert)}
                for name, level in levels.items()}

    def references(self, tasks: np.ndarray, mixing: Mapping[str, float], episodes: int,
                   rng: np.random.Generator) -> dict[str, Any]:
        """Return and success of uniform, each behavior checkpoint, π (mean action) and the scripted expert.

        An exception to the shared ``references_by_simulation``, which would simulate mixtures, not checkpoints,
        and normalize by π: here the reference is the scripted expert, so the scripted and SAC recipes' tables
        share one scale, and π's own return and success are reported beside it. Its uniform and π returns agree
        with the shared simulation's at p = 0 and p = 1 within their noise (tested).
        """
        goals = np.repeat(tasks, episodes, axis=0)
        task_of = np.repeat(np.arange(len(tasks)), episodes)
        sim = self._simulate(goals, self._policies(dict(mixing)), int(rng.integers(2**31)))
        per_task = {k: per_task_mean(r, task_of) for k, (r, _) in sim.items()}
        rate = {k: mean_sem(per_task_mean(s.astype(float), task_of))[0] for k, (_, s) in sim.items()}
        uniform, expert = per_task["uniform"], per_task["expert"]
        reference = {}
        for q in mixing:
            b_mean, b_sem = mean_sem(per_task[q])
            reference[q] = {"behavior_return": b_mean, "behavior_return_sem": b_sem, "behavior_success": rate[q],
                            "behavior_normalized_return": mean_sem((per_task[q] - uniform) / (expert - uniform))[0],
                            "expert_return": mean_sem(expert)[0], "expert_success": rate["expert"],
                            "sac_return": mean_sem(per_task["sac"])[0], "sac_success": rate["sac"],
                            "sac_normalized_return": mean_sem((per_task["sac"] - uniform) / (expert - uniform))[0],
                            "uniform_return": mean_sem(uniform)[0]}
        return {"test_reference": reference,
                "test_reference_per_task": {"uniform_return": uniform.tolist(), "expert_return": expert.tolist()}}

    def config(self) -> dict[str, Any]:
        return {**super().config(), "expert": "sac",
                "sac_oracle": {"dir": self.oracle_dir.name, "sha256": sha256(self.oracle_dir / CHECKSUMS)}}


__all__ = ["DEFAULT_ORACLE", "DEFAULT_ORACLE_NAME", "FINAL", "ReachSACOracle", "ReachSACTaskFamily"]
