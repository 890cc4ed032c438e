"""Gymnasium ids for the task families' envs: ``icprl/DarkRoom-v0`` and ``icprl/MetaWorldReach-v0``.

Importing this module registers them (``import icprl_lightning.families.registration``, or let Gymnasium
import it: ``gymnasium.make("icprl_lightning.families.registration:icprl/DarkRoom-v0", goal=[3, 4])``).
Gymnasium 1.x has no plugin discovery (0.26's ``gymnasium.envs`` entry points were removed in 1.0), so
registration happens on import only. The entry points are strings: registering imports neither torch nor
MuJoCo, which load when an env is first made.

Each id has a single-env ``entry_point`` (``gymnasium.make``) and the project's batched env as its
``vector_entry_point`` (``gymnasium.make_vec``: N episodes step in one call, not a loop over N envs). Both
take the same kwargs; their meaning, the spaces and the seeding are in ``docs/environments.md``. No
``max_episode_steps``: the envs truncate at their own ``horizon`` kwarg, which a fixed ``TimeLimit`` would
contradict.

The dueling bandit is not registered: its action is a pair of arms and its feedback a comparison, not a
reward, so a Gymnasium reward would mislead every tool that maximizes it (``docs/environments.md``).
"""

from __future__ import annotations

import gymnasium as gym

# id -> (single-env entry point, vector entry point)
ENV_IDS = {
    "icprl/DarkRoom-v0": ("icprl_lightning.families.darkroom.gym_env:darkroom_env",
                          "icprl_lightning.families.darkroom.gym_env:darkroom_vector_env"),
    "icprl/MetaWorldReach-v0": ("icprl_lightning.families.metaworld_reach.gym_env:reach_env",
                                "icprl_lightning.families.metaworld_reach.gym_env:reach_vector_env"),
}


def register_envs() -> None:
    """Register every id of ``ENV_IDS`` that is not registered yet (idempotent: no override warnings)."""
    for env_id, (entry_point, vector_entry_point) in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, vector_entry_point=vector_entry_point)


register_envs()
