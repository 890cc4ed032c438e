"""RewardGen on held-out tasks at validation time: the held-out callback (``callbacks/held_out.py``) of the
``pair_accuracy`` evaluation (``evaluation/pair_accuracy.py``): how often R_ψ's summed rewards order an unseen
task's pair as its label does, logged as ``val/<env>/<quality>/pair_accuracy`` and ``val/<env>/heldout_pair_accuracy``.
Chance is 0.5; tied returns carry coin-flip labels, so the ceiling is below 1 (the manifest's ``eval_statistics``
give the label agreement and tie fraction per quality)."""

from typing import Any

from icprl_lightning.callbacks.held_out import HeldOutCallback


class HeldOutPairAccuracyCallback(HeldOutCallback):
    evaluation = "pair_accuracy"

    def _subject(self, pl_module: Any) -> Any:
        return pl_module  # a reward model, not a policy: it scores the pairs itself
