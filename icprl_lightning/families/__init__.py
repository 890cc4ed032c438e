"""Task families: the one extension point (``base.py``), and DarkRoom, Meta-World Reach and the linear
dueling bandits, each in its own folder (its env, its oracle, its family class)."""

from icprl_lightning.families import registration as _registration  # noqa: F401, E402  (the icprl/ Gymnasium ids)
