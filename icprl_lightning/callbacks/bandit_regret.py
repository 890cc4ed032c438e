"""Weak regret on held-out dueling-bandit problems at validation time: the held-out callback
(``callbacks/held_out.py``) of the ``duels`` evaluation (``evaluation/weak_regret.py``), logged under
``val/bandit/<source>/<method>/`` beside DTS on the same comparisons, per context source."""

from icprl_lightning.callbacks.held_out import HeldOutCallback


class BanditRegretCallback(HeldOutCallback):
    evaluation = "duels"
