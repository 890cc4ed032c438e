"""Stop a fit the moment its loss or weights stop being finite, and never save a checkpoint of such weights.

Without it a run whose loss overflows (e.g. inputs of 1e30) trains on to NaN weights, exits 0 and prints
its best checkpoint as if nothing happened. The check is cheap, unlike ``torch.autograd.detect_anomaly``:
one ``isfinite`` of the scalar loss per training batch, one pass over the weights at each epoch's end,
and one over the state being saved in every checkpoint (``on_save_checkpoint`` runs before the file is
written, so raising there writes nothing). The first failure raises ``NonFiniteError``, one line naming
the epoch, batch and global step and what went non-finite (the loss, or the first weight by name); the fit
ends there, so no checkpoint is saved after it and the end-of-fit lines (best/last checkpoint) are not
printed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback
from torch import Tensor


class NonFiniteError(RuntimeError):
    """A fit stopped because its loss or a weight became NaN or infinite."""


class FiniteCheck(Callback):
    """Raises ``NonFiniteError`` when the training loss or any weight is NaN or infinite (module docstring)."""

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        loss = outputs.get("loss") if isinstance(outputs, Mapping) else outputs
        if not isinstance(loss, Tensor):  # a skipped batch (training_step returned None)
            return
        finite = bool(torch.isfinite(loss.detach()).all())
        # every rank decides together: one rank raising alone would leave the others waiting in a collective
        if not trainer.strategy.reduce_boolean_decision(finite, all=True):
            value = "non-finite on another rank" if finite else f"{loss.detach().float().sum().item()}"
            raise NonFiniteError(f"the training loss is {value} at {_where(trainer, batch_idx)}; the fit is stopped "
                                 "and nothing more is saved (lower the learning rate, or check the data's scale)")

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        bad = _first_non_finite(pl_module.named_parameters())
        if not trainer.strategy.reduce_boolean_decision(bad is None, all=True):
            what = f"weight {bad}" if bad is not None else "a weight on another rank"
            raise NonFiniteError(f"{what} at the end of {_where(trainer)}; the fit is stopped and nothing more is "
                                 "saved")

    def on_save_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict) -> None:
        # local only (no collective): a save may run on one rank's exception path; the weights are the same
        # on every rank, so every rank decides alike
        bad = _first_non_finite(checkpoint.get("state_dict", {}).items())
        if bad is not None:
            raise NonFiniteError(f"checkpoint not saved: weight {bad} at {_where(trainer)}; the fit is stopped")


def _first_non_finite(named: Iterable[tuple[str, Tensor]]) -> str | None:
    """``"<name> has N NaN/inf values of M"`` for the first floating tensor that is not all finite, else None."""
    for name, tensor in named:
        if not isinstance(tensor, Tensor) or not tensor.is_floating_point():
            continue
        finite = torch.isfinite(tensor.detach())
        if not bool(finite.all()):
            return f"{name} has {int((~finite).sum())} NaN/inf values of {finite.numel()}"
    return None


def _where(trainer: L.Trainer, batch_idx: int | None = None) -> str:
    batch = f", batch {batch_idx}" if batch_idx is not None else ""
    return f"epoch {trainer.current_epoch}{batch} (global step {trainer.global_step})"
