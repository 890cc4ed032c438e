"""In-context rollouts on held-out tasks at validation time: the held-out callback (``callbacks/held_out.py``) of the
``rollouts`` evaluation (``evaluation/heldout_rollouts.py``), logged under ``val/<env>/<quality>/``: ``return`` and
``return_sem`` (over held-out tasks), ``normalized_return``, ``success`` (where the env reports it), the behavior
and optimal policies' returns beside them, and with ``diagnostics`` the same episodes with the context changed as
each states, under ``val/<env>/<quality>/<diagnostic>/`` (label diagnostics only for contexts with labels)."""

from icprl_lightning.callbacks.held_out import HeldOutCallback


class InContextRolloutCallback(HeldOutCallback):
    evaluation = "rollouts"
