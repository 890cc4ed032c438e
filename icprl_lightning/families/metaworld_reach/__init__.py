"""Meta-World Reach: the vector env on metaworld's reach-v3 (``env.py``), the scripted-expert oracle
(``oracle.py``), the family (``family.py``), a single-goal Gymnasium env for Stable-Baselines3
(``gym_env.py``), the SB3 SAC oracle's training (``sac.py``), its weights-only export (``sac_weights.py``,
the committed ``sac_oracle_v1/``) and the family on the paper's recipe that uses it (``sac_family.py``)."""

from icprl_lightning.families.metaworld_reach.family import ReachTaskFamily

__all__ = ["ReachTaskFamily"]
