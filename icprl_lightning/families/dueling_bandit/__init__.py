"""Linear dueling bandits: the family (``env.py``) and Double Thompson Sampling (``dts.py``), which is both
a behavior policy of its contexts and the paper's baseline."""

from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily

__all__ = ["LinearDuelingBanditFamily"]
