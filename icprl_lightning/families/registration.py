"""Gymnasium ids for the task families' envs: ``icprl/DarkRoom-v0`` and ``icprl/MetaWorldReach-v0``
(kwargs, spaces and seeding: docs/environments.md).

``import icprl_lightning`` registers them: Gymnasium 1.x has no plugin discovery, so registration happens on
import only. The entry points are strings, so registering imports neither torch nor MuJoCo. Each id has a
single-env ``entry_point`` and the project's batched env as its ``vector_entry_point``, taking the same kwargs.
No ``max_episode_steps``: the envs truncate at their own ``horizon`` kwarg, which a fixed ``TimeLimit`` would
contradict. The dueling bandit is not registered: its feedback is a comparison, and a Gymnasium reward would
mislead every tool that maximizes it.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

# id -> (single-env entry point, vector entry point)
ENV_IDS = {
    "icprl/DarkRoom-v0": ("icprl_lightning.families.darkroom.gym_env:darkroom_env",
                          "icprl_lightning.families.darkroom.gym_env:darkroom_vector_env"),
    "icprl/MetaWorldReach-v0": ("icprl_lightning.families.metaworld_reach.gym_env:reach_env",
                                "icprl_lightning.families.metaworld_reach.gym_env:reach_vector_env"),
}


def check_num_envs(env_id: str, num_envs: object, goals: object) -> None:
    """``num_envs`` is an integer >= 1 and, with ``goals``, their number: a mismatch names ``num_envs``."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
        raise ValueError(f"{env_id}: num_envs must be an integer >= 1, got {num_envs!r}")
    rows = np.shape(goals)[0] if goals is not None and np.ndim(goals) >= 1 else None
    if rows is not None and np.ndim(goals) == 2 and rows != num_envs:
        raise ValueError(f"{env_id}: num_envs is {num_envs} but goals has {rows} rows (one per env): pass "
                         f"num_envs={rows}")


def register_envs() -> None:
    """Register every id of ``ENV_IDS`` that is not registered yet (idempotent: no override warnings)."""
    for env_id, (entry_point, vector_entry_point) in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, vector_entry_point=vector_entry_point)


register_envs()
