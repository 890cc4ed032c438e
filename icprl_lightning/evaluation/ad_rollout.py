"""The in-context learning curve of Algorithm Distillation: the return of each of N consecutive episodes on
held-out goals, the context growing across them (``methods/ad.py``), beside the source learner's own curve and
the optimal return of the very same episodes.

AD is deployed online (Laskin et al. 2022, section 5): from an empty history on an unseen goal it acts from
T_θ(· | s, history) and appends each step (s, a, r), so episode e conditions episode e + 1; no parameter is
updated. All goals step at once through the family's vector env, reset from ``seed`` at the first episode only,
so the starts are fixed by ``seed``.
"""

from __future__ import annotations

import numpy as np
import torch

from icprl_lightning.families.base import TaskFamily
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.learning_histories import QLearningHistories
from icprl_lightning.families.darkroom.oracle import optimal_value
from icprl_lightning.methods.ad import HistoryAgent
from icprl_lightning.validation import check_int


def ad_learning_curve(agent: HistoryAgent, family: TaskFamily, tasks: np.ndarray, episodes: int,
                      seed: int = 0) -> np.ndarray:
    """Return per episode [n_tasks, episodes] of ``agent`` on ``tasks``, its history kept across the episodes.

    The agent is reset to empty histories first; afterwards it holds the history of the last episodes (its
    ``window``). Its ``slide`` sets how often a full window is re-encoded (``HistoryAgent``).
    """
    if not isinstance(agent, HistoryAgent):
        raise ValueError(f"ad_learning_curve deploys a HistoryAgent (ADModule.make_agent, or load_agent of an AD "
                         f"checkpoint), got {type(agent).__name__}")
    check_int("ad_learning_curve", "episodes", episodes, 1)
    tasks = np.asarray(tasks)
    env = family.make_env(tasks)
    try:
        agent.reset(len(tasks))
        returns = np.zeros((len(tasks), episodes))
        for episode in range(episodes):
            obs, _ = env.reset(seed=seed if episode == 0 else None)
            for _ in range(family.horizon):
                actions = agent.act(torch.as_tensor(obs, dtype=torch.float32))
                nxt, rewards, _, _, _ = env.step(actions.cpu().numpy())
                agent.observe(obs, actions, np.asarray(rewards, dtype=np.float32))
                returns[:, episode] += rewards
                obs = nxt
    finally:
        env.close()
    return returns


def source_learning_curve(learner: QLearningHistories, family: DarkRoomFamily, tasks: np.ndarray,
                          seed: int = 0) -> np.ndarray:
    """Return per episode [n_tasks, learner.episodes] of the source learner run from scratch on ``tasks``."""
    return learner.run(family, np.asarray(tasks), np.random.default_rng(seed))["episode_returns"].astype(np.float64)


def optimal_curve(family: DarkRoomFamily, tasks: np.ndarray, episodes: int, seed: int = 0) -> np.ndarray:
    """The optimal return [n_tasks, episodes] of the episodes ``ad_learning_curve(..., episodes, seed)`` plays.

    DarkRoom's env draws only at ``reset`` (its steps are deterministic), so resetting a fresh env the same way
    gives the same start cells, whatever the agent did; V*_H of each start is exact (``oracle.optimal_value``).
    """
    check_int("optimal_curve", "episodes", episodes, 1)
    tasks = np.asarray(tasks)
    env = family.make_env(tasks)
    try:
        optimal = np.zeros((len(tasks), episodes))
        for episode in range(episodes):
            env.reset(seed=seed if episode == 0 else None)
            optimal[:, episode] = optimal_value(env.states, env.goals, family.horizon, family.terminate_on_goal)
    finally:
        env.close()
    return optimal
