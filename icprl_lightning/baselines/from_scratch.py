"""The from-scratch protocol shared by the SB3 baselines (``sac_from_scratch``, ``dqn_from_scratch``).

One agent per (held-out task, seed) trains with periodic evaluation on fixed-seed episodes
(``sb3.EvalCheckpointCallback``); the best checkpoint by that return is restored and reported on fresh test
episodes, so the reported return is not the maximum of noisy estimates. Each baseline's JSON shares the
protocol's description, the mean ± sem over tasks, its cost and the machine (``over_goals``).
"""

from __future__ import annotations

import platform
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm

from icprl_lightning.metrics import mean_sem
from icprl_lightning.sb3 import Act, EvalCheckpointCallback, deterministic_act, run_episodes


def train_from_scratch(model: BaseAlgorithm, eval_env: gym.Env, total_timesteps: int, eval_every_steps: int,
                       eval_episodes: int, eval_seed: int, test_episodes: int, test_seed: int,
                       references: Mapping[str, Act] | None = None,
                       make_act: Callable[[BaseAlgorithm], Act] = deterministic_act) -> dict[str, Any]:
    """Train ``model`` with periodic evaluation, restore the best checkpoint, test it on fresh episodes.

    The checkpoint is chosen on the evaluation episodes (seed ``eval_seed``) and reported on
    ``test_episodes`` others (seed ``test_seed``), so the reported return is not the maximum of noisy
    estimates. ``references`` (e.g. uniform, expert) are run on the same test episodes. ``make_act`` turns
    the model into the evaluated action function (default: SB3's deterministic ``predict``).
    """
    callback = EvalCheckpointCallback(eval_env, eval_every_steps, eval_episodes, eval_seed, make_act,
                                      eval_at_start=False)
    start = time.perf_counter()
    model.learn(total_timesteps=total_timesteps, callback=callback)
    seconds = time.perf_counter() - start
    best = callback.restore_best()
    test = run_episodes(make_act(model), eval_env, test_episodes, test_seed)
    refs = {name: float(run_episodes(act, eval_env, test_episodes, test_seed).returns.mean())
            for name, act in (references or {}).items()}
    return {"return": float(test.returns.mean()), "success": float(test.success.mean()),
            "best_step": best.step, "best_eval_return": best.mean_return,
            "final_eval_return": callback.history[-1].mean_return,
            "eval_curve": [[r.step, r.mean_return, r.success] for r in callback.history],
            "reference_returns": refs, "train_seconds": seconds}


def over_goals(goals: np.ndarray, seeds: Sequence[int], run_goal: Callable[[np.ndarray, int], dict[str, Any]],
               progress: bool = False) -> dict[str, Any]:
    """``run_goal(goal, seed)`` for every goal and seed (the seed derived from both), per goal the mean over seeds;
    the part of a baseline's JSON every algorithm shares: protocol, mean ± sem over goals, cost, machine."""
    start, cpu_start = time.perf_counter(), time.process_time()
    keys = ("return", "success", "normalized_return")
    per_goal = []
    for g, goal in enumerate(goals):
        runs = []
        for seed in seeds:
            runs.append(run_goal(goal, int(np.random.SeedSequence([seed, g]).generate_state(1)[0])))
            if progress:
                print(f"goal {g} seed {seed}: return {runs[-1]['return']:.2f} success {runs[-1]['success']:.2f} "
                      f"({runs[-1]['train_seconds']:.0f} s)", file=sys.stderr, flush=True)
        per_goal.append({"goal": np.asarray(goal).tolist(),
                         **{k: float(np.mean([r[k] for r in runs])) for k in keys}, "runs": runs})
    summary = {}
    for key in keys:
        mean, sem = mean_sem(np.array([g[key] for g in per_goal], dtype=np.float64))
        summary[key] = {"mean": mean, "sem": sem}
    return {"selection": "best checkpoint by mean evaluation return (fixed-seed episodes), reported on fresh episodes",
            **summary, "n_goals": len(per_goal), "per_goal": per_goal,
            "wall_seconds": time.perf_counter() - start, "cpu_seconds": time.process_time() - cpu_start,
            "platform": platform.platform(), "torch_threads": torch.get_num_threads()}
