"""Meta-World Reach: the vector env on metaworld's reach-v3 (``env.py``), the scripted-expert oracle
(``oracle.py``), the family (``family.py``), a single-goal Gymnasium env for Stable-Baselines3
(``gym_env.py``) and the SB3 SAC oracle (``sac.py``)."""

from icprl_lightning.families.metaworld_reach.family import ReachTaskFamily

__all__ = ["ReachTaskFamily"]
