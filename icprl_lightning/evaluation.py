"""In-context evaluation on held-out tasks, as a plain function the rollout callback and scripts call.

The paper's performance metric (section 6): the latent cumulative reward of an episode in an unseen
task, with the agent conditioned on a fixed offline context from that task (no parameter updates, no
reward observed). Returns are averaged per task, then summarized as mean ± standard error over tasks.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
import yaml

from icprl_lightning.data.suites import EvalSuite
from icprl_lightning.metrics import mean_sem, per_task_mean


class AgentLike(Protocol):
    def reset(self, context: Any) -> None: ...

    def act(self, obs: torch.Tensor) -> torch.Tensor: ...


@torch.no_grad()
def rollout_in_context(agent: AgentLike, suite: EvalSuite, seed: int = 0) -> dict[str, np.ndarray]:
    """Run one episode per context; returns per-episode ``return`` (and ``success`` when the env reports it).

    ``success`` is 1 for an episode whose ``info["success"]`` was true at any step (metaworld's criterion).
    The env is closed afterwards.
    """
    env = suite.make_env()
    try:
        obs, _ = env.reset(seed=seed)
        agent.reset(suite.context)
        total = np.zeros(env.num_envs)
        success = np.zeros(env.num_envs, dtype=bool)
        reports_success = False
        for _ in range(suite.horizon):
            actions = agent.act(torch.as_tensor(obs, dtype=torch.float32))
            obs, reward, terminated, truncated, info = env.step(actions.cpu().numpy())
            total += reward
            if "success" in info:
                reports_success = True
                success |= np.asarray(info["success"], dtype=bool)
            if np.all(terminated | truncated):
                break
    finally:
        # Vector envs may hold worker processes (Meta-World); release them now, not at garbage collection.
        if hasattr(env, "close"):
            env.close()
    out = {"return": total}
    if reports_success:
        out["success"] = success.astype(np.float64)
    return out


def summarize(suite: EvalSuite, episodes: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean ± sem over held-out tasks of return (normalized too) and success, plus the references."""
    out: dict[str, float] = {}
    for name, values in episodes.items():
        out[name], out[f"{name}_sem"] = mean_sem(per_task_mean(values, suite.task_index))
    if suite.normalize is not None:
        normalized = suite.normalize(episodes["return"])
        out["normalized_return"], out["normalized_return_sem"] = mean_sem(per_task_mean(normalized, suite.task_index))
    out.update(suite.reference)
    return out


def datamodule_from_config(path: str | Path, **overrides: Any):
    """The DataModule a config's ``data`` section names (class_path + init_args), built without the CLI."""
    data = yaml.safe_load(Path(path).read_text())["data"]
    module, _, name = data["class_path"].rpartition(".")
    return getattr(importlib.import_module(module), name)(**{**data.get("init_args", {}), **overrides})
