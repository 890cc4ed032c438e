"""In-context episodes on held-out MDP tasks through the public ``Agent``, and their summary.

The paper's performance metric (section 6): the latent cumulative reward of an episode in an unseen task, the
agent conditioned on a fixed offline context from that task (no parameter updates, no reward observed),
averaged per task, then mean ± standard error over tasks. ``success`` (Meta-World Reach) is the share of
episodes whose success flag was raised at some step, metaworld's criterion. ``suite_env`` builds one vector env
of a suite's tasks to pass as ``env=``: ``reset(seed=s)`` fixes every episode, so reusing it gives the episodes
a fresh one gives without starting Meta-World's worker processes again (seconds, more than an episode). The
context diagnostics are ``evaluation.diagnostics``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Protocol

import numpy as np
import torch

from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.metrics import mean_sem, per_task_mean
from icprl_lightning.progress import Progress


class AgentLike(Protocol):
    def reset(self, context: Any) -> None: ...

    def act(self, obs: torch.Tensor) -> torch.Tensor: ...


@contextmanager
def suite_env(suite: EvalSuite) -> Iterator[Any]:
    """``suite.make_env()``, closed on exit (vector envs may hold worker processes: Meta-World's do)."""
    env = suite.make_env()
    try:
        yield env
    finally:
        if hasattr(env, "close"):
            env.close()


@torch.no_grad()
def rollout_in_context(agent: AgentLike, suite: EvalSuite, seed: int = 0, env: Any = None,
                       progress: bool = True) -> dict[str, np.ndarray]:
    """One episode per context: per-episode ``return`` [B] (and ``success``, 1 when ``info["success"]`` was true at
    any step). ``env``: a ``suite_env`` to reuse, left open (default: a fresh one, closed after). ``progress``:
    steps counted (``progress.Progress``: a bar in a terminal, plain lines in a log)."""
    if env is None:
        with suite_env(suite) as fresh:
            return rollout_in_context(agent, suite, seed, fresh, progress)
    if env.num_envs != len(suite.task_index):
        raise ValueError(f"env: {env.num_envs} envs for a suite of {len(suite.task_index)} episodes")
    obs, _ = env.reset(seed=seed)
    agent.reset(suite.context)
    total = np.zeros(env.num_envs)
    success = np.zeros(env.num_envs, dtype=bool)
    reports_success = False
    with Progress(suite.horizon, f"rollouts {suite.env_name}/{suite.quality}", enabled=progress) as steps:
        for _ in range(suite.horizon):
            actions = agent.act(torch.as_tensor(obs, dtype=torch.float32))
            obs, reward, terminated, truncated, info = env.step(actions.cpu().numpy())
            total += reward
            steps.advance()
            if "success" in info:
                reports_success = True
                success |= np.asarray(info["success"], dtype=bool)
            if np.all(terminated | truncated):
                break
    out = {"return": total}
    if reports_success:
        out["success"] = success.astype(np.float64)
    return out


def rollout_seeds(make_agent: Callable[[int], AgentLike], suite: EvalSuite, seeds: Sequence[int],
                  suite_for_seed: Callable[[int], EvalSuite] | None = None, env: Any = None) -> dict[str, np.ndarray]:
    """Episodes for every seed (a fresh ``make_agent(seed)`` each), concatenated seed-major: [len(seeds) · B].

    Every seed is one more episode per context (new start state, new action samples). ``normalized_return``
    is added per seed, because a suite's ``normalize`` maps its own B episodes (per-task references).
    ``suite_for_seed(seed)``, when given, is the suite deployed at that seed (a context diagnostic drawn
    from the seed, ``evaluation.diagnostics``); it must keep ``suite``'s tasks. ``env``: as ``rollout_in_context``'s,
    one env for every seed.
    """
    if env is None:
        with suite_env(suite) as fresh:
            return rollout_seeds(make_agent, suite, seeds, suite_for_seed, fresh)
    episodes: dict[str, list[np.ndarray]] = {}
    for seed in seeds:
        deployed = suite if suite_for_seed is None else suite_for_seed(seed)
        result = rollout_in_context(make_agent(seed), deployed, seed=seed, env=env)
        if suite.normalize is not None:
            result["normalized_return"] = suite.normalize(result["return"])
        for name, values in result.items():
            episodes.setdefault(name, []).append(values)
    return {name: np.concatenate(values) for name, values in episodes.items()}


def episode_stats(suite: EvalSuite, episodes: dict[str, np.ndarray], with_tasks: bool = False) -> dict[str, Any]:
    """Mean ± sem over held-out tasks of each per-episode metric (``<name>``, ``<name>_sem``) of B or n · B episodes
    (seed-major, as ``rollout_seeds``), each task's episodes averaged first; ``normalized_return`` computed when
    missing. ``with_tasks``: also ``per_task``, the per-task means (sorted ids) the bootstrap resamples."""
    n_seeds, rest = divmod(len(episodes["return"]), len(suite.task_index))
    if rest or n_seeds == 0:
        raise ValueError(f"{len(episodes['return'])} episodes are not a multiple of the suite's "
                         f"{len(suite.task_index)} contexts")
    episodes = dict(episodes)
    if suite.normalize is not None and "normalized_return" not in episodes:
        episodes["normalized_return"] = np.concatenate([suite.normalize(r)
                                                        for r in np.split(episodes["return"], n_seeds)])
    tasks = np.tile(suite.task_index, n_seeds)
    out: dict[str, Any] = {}
    per_task: dict[str, list[float]] = {}
    for name, values in episodes.items():
        task_means = per_task_mean(values, tasks)
        out[name], out[f"{name}_sem"] = mean_sem(task_means)
        per_task[name] = task_means.tolist()
    if with_tasks:
        out["per_task"] = per_task
    return out


def summarize(suite: EvalSuite, episodes: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean ± sem over held-out tasks of return (normalized too) and success, plus the references."""
    return {**episode_stats(suite, episodes), **suite.reference}
