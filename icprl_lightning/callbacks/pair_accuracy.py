"""RewardGen on held-out tasks: how often R_ψ's summed rewards order an unseen task's pair as its label does.

At each validation epoch (the sanity check is skipped) the callback scores the held-out goals' pairs of
every context quality, each conditioned on another pair of its goal (``heldout_pairs()`` of the T-PRL
DataModule), and logs ``val/<env>/<quality>/pair_accuracy`` and ``val/<env>/heldout_pair_accuracy`` (all
qualities). Chance is 0.5; tied returns carry coin-flip labels, so the ceiling is below 1 (the manifest's
``eval_statistics`` give the label agreement and tie fraction per quality). The same numbers are printed
once per epoch, so a run shows them in the terminal, not only in the logger. Under several processes the
pairs are scored on rank 0 and every rank logs the accuracies (``callbacks/distributed.py``).
"""

from __future__ import annotations

import sys

import lightning as L
import torch
from lightning.fabric.utilities.apply_func import move_data_to_device

from icprl_lightning.callbacks.distributed import log_broadcast, on_rank_zero


class HeldOutPairAccuracyCallback(L.Callback):
    requires_data = ("heldout_pairs",)  # the held-out evaluation it reads (checked against the data's ``offers``)

    def __init__(self) -> None:
        self.last_results: dict[str, float] = {}

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        env = trainer.datamodule.metric_env
        correct = on_rank_zero(trainer, lambda: self._correct(trainer, pl_module))
        results = {f"val/{env}/{q}/pair_accuracy": float(c.mean()) for q, c in correct.items()}
        results[f"val/{env}/heldout_pair_accuracy"] = float(torch.cat(list(correct.values())).mean())
        self.last_results = results
        log_broadcast(pl_module, results)
        if trainer.is_global_zero:
            shown = ", ".join(f"{q} {float(c.mean()):.3f} (n={len(c)})" for q, c in correct.items())
            all_pairs = results[f"val/{env}/heldout_pair_accuracy"]
            print(f"Held-out pair accuracy (epoch {trainer.current_epoch + 1}): {shown}; "
                  f"all {all_pairs:.3f}", file=sys.stderr)

    @staticmethod
    def _correct(trainer: L.Trainer, pl_module: L.LightningModule) -> dict[str, torch.Tensor]:
        """Per quality, whether each held-out pair is ordered as its label (on the CPU)."""
        correct = {}
        for quality, batch in trainer.datamodule.heldout_pairs().items():
            batch = move_data_to_device(batch, pl_module.device)  # typed samples, moved field by field
            correct[quality] = pl_module.pair_correct(batch).float().cpu()
        return correct
