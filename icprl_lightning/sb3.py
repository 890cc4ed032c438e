"""Stable-Baselines3 agents evaluated while they train: episode rollouts and the checkpoint callback (for the
SAC oracle and the from-scratch baselines).

``EvalCheckpointCallback`` evaluates on a separate env reset with the same seed each time, so all checkpoints
face the same start states and the curve is not drowned by episode noise. Success of an episode is "the
success flag was raised at some step", as in ``evaluation/rollout.py``.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

Act = Callable[[np.ndarray], np.ndarray]


class EpisodeStats(NamedTuple):
    returns: np.ndarray  # [episodes] latent return of each episode
    success: np.ndarray  # [episodes] 1.0 when info["success"] was raised at some step


class EvalRecord(NamedTuple):
    step: int           # environment steps of training so far
    mean_return: float  # over the evaluation episodes
    success: float      # share of evaluation episodes that succeeded
    path: str | None    # the saved SB3 zip, relative to the save directory's parent (or None)


def run_episodes(act: Act, env: gym.Env, episodes: int, seed: int,
                 reset_options: Sequence[dict[str, Any]] | None = None) -> EpisodeStats:
    """Roll ``act`` (obs → action) for ``episodes`` episodes; the first reset gets ``seed``, the rest continue it."""
    if reset_options is not None and len(reset_options) != episodes:
        raise ValueError(f"reset_options must hold one dict per episode ({episodes}), got {len(reset_options)}")
    returns, success = np.zeros(episodes), np.zeros(episodes)
    for ep in range(episodes):
        obs, _ = env.reset(seed=seed if ep == 0 else None, options=None if reset_options is None else reset_options[ep])
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            returns[ep] += reward
            success[ep] = max(success[ep], float(info.get("success", False)))
            done = terminated or truncated
    return EpisodeStats(returns, success)


def deterministic_act(model: BaseAlgorithm) -> Act:
    """The policy's greedy / mean action (SB3 ``predict(deterministic=True)``)."""
    return lambda obs: model.predict(obs, deterministic=True)[0]


class EvalCheckpointCallback(BaseCallback):
    """Evaluate every ``eval_every_steps`` steps, at the end of training (and at step 0 with
    ``eval_at_start``, i.e. the untrained policy); keep the best weights; optionally save each checkpoint.

    ``make_act(model)`` gives the action function to evaluate (default: the deterministic policy).
    ``verbose`` > 0 prints each evaluation to stderr. After training, ``history`` lists every evaluation,
    ``best_index`` the first one with the highest mean return, and ``restore_best()`` loads its weights
    into the model.
    """

    def __init__(self, eval_env: gym.Env, eval_every_steps: int, eval_episodes: int, eval_seed: int,
                 make_act: Callable[[BaseAlgorithm], Act] = deterministic_act, save_dir: str | Path | None = None,
                 reset_options: Sequence[dict[str, Any]] | None = None, eval_at_start: bool = True,
                 verbose: int = 0) -> None:
        super().__init__(verbose)
        if eval_every_steps < 1 or eval_episodes < 1:
            raise ValueError(f"eval_every_steps and eval_episodes must be ≥ 1, got {eval_every_steps}, "
                             f"{eval_episodes}")
        self.eval_env = eval_env
        self.eval_every_steps = eval_every_steps
        self.eval_episodes = eval_episodes
        self.eval_seed = eval_seed
        self.make_act = make_act
        self.save_dir = None if save_dir is None else Path(save_dir)
        self.reset_options = reset_options
        self.eval_at_start = eval_at_start
        self.history: list[EvalRecord] = []
        self._evaluated_multiple = 0  # the last multiple of eval_every_steps evaluated
        self.best_index = -1
        self._best_state: dict[str, Any] | None = None

    def _on_training_start(self) -> None:
        if self.eval_at_start and not self.history:  # a second learn() call continues the history
            self._evaluate()

    def _on_step(self) -> bool:
        # With n vectorized envs num_timesteps grows by n per call: evaluate once per multiple crossed.
        if self.num_timesteps // self.eval_every_steps > self._evaluated_multiple:
            self._evaluated_multiple = self.num_timesteps // self.eval_every_steps
            self._evaluate()
        return True

    def _on_training_end(self) -> None:
        # The final policy is always a candidate (the oracle's "converged" checkpoint), even off the grid.
        if not self.history or self.history[-1].step != self.num_timesteps:
            self._evaluate()

    def _evaluate(self) -> None:
        stats = run_episodes(self.make_act(self.model), self.eval_env, self.eval_episodes, self.eval_seed,
                             self.reset_options)
        path = None
        if self.save_dir is not None:
            self.save_dir.mkdir(parents=True, exist_ok=True)
            name = f"step_{self.num_timesteps:08d}.zip"
            self.model.save(self.save_dir / name)
            path = f"{self.save_dir.name}/{name}"
        self.history.append(EvalRecord(int(self.num_timesteps), float(stats.returns.mean()),
                                       float(stats.success.mean()), path))
        if self.verbose:
            print(f"step {self.num_timesteps}: return {stats.returns.mean():.2f}, success {stats.success.mean():.2f}",
                  file=sys.stderr, flush=True)
        if self.best_index < 0 or self.history[-1].mean_return > self.history[self.best_index].mean_return:
            self.best_index = len(self.history) - 1
            self._best_state = copy.deepcopy(self.model.policy.state_dict())

    def restore_best(self) -> EvalRecord:
        """Load the best evaluated weights into the model's policy and return that evaluation."""
        if self._best_state is None:
            raise RuntimeError("no evaluation yet: train with this callback first")
        self.model.policy.load_state_dict(self._best_state)
        return self.history[self.best_index]
