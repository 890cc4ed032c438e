"""The from-scratch protocol shared by the SB3 baselines (``sac_from_scratch``, ``dqn_from_scratch``).

One agent per (held-out task, seed) trains with periodic evaluation on fixed-seed episodes
(``sb3.EvalCheckpointCallback``); the best checkpoint by that return is restored and reported on fresh test
episodes, so the reported return is not the maximum of noisy estimates. Each baseline's JSON shares the
protocol's description, the mean ± sem over tasks, its cost and the machine (``from_scratch_record``).
"""

from __future__ import annotations

import platform
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


def summarize_over_goals(per_goal: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> dict[str, dict[str, float]]:
    """Mean ± standard error over goals of each key (each goal's value already averaged over seeds)."""
    out = {}
    for key in keys:
        mean, sem = mean_sem(np.array([g[key] for g in per_goal], dtype=np.float64))
        out[key] = {"mean": mean, "sem": sem}
    return out


def from_scratch_record(per_goal: Sequence[Mapping[str, Any]], keys: Sequence[str], wall_start: float,
                        cpu_start: float) -> dict[str, Any]:
    """The part of a from-scratch baseline's JSON every algorithm shares: protocol, summary, cost, machine."""
    return {"selection": "best checkpoint by mean evaluation return (fixed-seed episodes), reported on fresh episodes",
            **summarize_over_goals(per_goal, keys), "n_goals": len(per_goal), "per_goal": list(per_goal),
            "wall_seconds": time.perf_counter() - wall_start, "cpu_seconds": time.process_time() - cpu_start,
            "platform": platform.platform(), "torch_threads": torch.get_num_threads()}
