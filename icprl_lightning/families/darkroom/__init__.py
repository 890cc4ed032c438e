"""DarkRoom: the env (``env.py``), its closed-form oracle (``oracle.py``), the family (``family.py``) and a
single-goal Gymnasium env for Stable-Baselines3 (``gym_env.py``)."""

from icprl_lightning.families.darkroom.family import DarkRoomFamily

__all__ = ["DarkRoomFamily"]
