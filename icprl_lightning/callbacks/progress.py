"""Training progress in any output: plain lines within an epoch when no progress bar shows, and one summary
line per epoch.

Lightning's bar redraws one line with carriage returns, which a CI log, ``tee``, ``nohup`` or a notebook
shows as nothing or as garbage; the CLI turns it off when stdout is not a terminal. Without a bar,
``TrainingProgress`` prints a plain line (``progress.Progress``) at each 10% of an epoch's batches or every
30 s. Every epoch it prints one line, through the bar when there is one::

    epoch 3/20: train loss 0.412, val loss 0.437, 18.5 steps/s, elapsed 4m12s

``train loss`` is the mean of the epoch's training-step losses (this process's batches); ``val loss`` is
the epoch's logged ``val/loss``, shown only when validation ran in that epoch; steps/s counts optimizer
steps over the epoch's training time, validation excluded. Only rank 0 prints.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import IO, Any

import lightning as L
import torch

from icprl_lightning.progress import Progress, format_duration, format_rate


class TrainingProgress(L.Callback):
    """See the module docstring.

    Args:
        every_percent: a line each time this share of an epoch's batches more is done (without a bar;
            None: ``progress.EVERY_PERCENT``).
        every_seconds: a line at least this often while training advances (without a bar; None:
            ``progress.EVERY_SECONDS``).
        min_seconds: no two in-epoch lines closer than this (None: ``progress.MIN_SECONDS``).
        stream: where lines go without a bar (default stdout at the time of printing).
        clock: seconds, monotonic (tests pass a fake one).
    """

    def __init__(self, every_percent: float | None = None, every_seconds: float | None = None,
                 min_seconds: float | None = None, stream: IO[str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.every_percent, self.every_seconds, self.min_seconds = every_percent, every_seconds, min_seconds
        self.stream, self.clock = stream, clock
        self._fit_start = clock()
        self._reset_epoch(0)

    def _reset_epoch(self, global_step: int) -> None:
        self._epoch_start = self.clock()
        self._train_seconds: float | None = None  # set when the epoch's validation starts
        self._first_step = global_step
        self._loss_sum, self._loss_count = 0.0, 0
        self._validated = False
        self._batches: Progress | None = None

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._fit_start = self.clock()

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._reset_epoch(trainer.global_step)
        if trainer.is_global_zero and trainer.progress_bar_callback is None:
            total = trainer.num_training_batches
            total = int(total) if math.isfinite(total) else None
            self._batches = Progress(total, self._epoch_name(trainer), unit="batch", interactive=False,
                                     every_percent=self.every_percent, every_seconds=self.every_seconds,
                                     min_seconds=self.min_seconds, stream=self.stream, clock=self.clock)

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        loss = outputs.get("loss") if isinstance(outputs, dict) else outputs
        if isinstance(loss, torch.Tensor) and loss.numel() == 1:
            self._loss_sum += float(loss.detach())
            self._loss_count += 1
        if self._batches is not None:
            self._batches.advance()

    def on_validation_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking and self._train_seconds is None:
            self._train_seconds = self.clock() - self._epoch_start

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self._validated = True

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._batches = None  # the summary replaces the epoch's last progress line
        if not trainer.is_global_zero:
            return
        line = self.summary(trainer)
        bar = trainer.progress_bar_callback
        if bar is not None:
            bar.print(line)  # above the bar, not through it
        else:
            print(line, file=self.stream or sys.stdout, flush=True)

    def summary(self, trainer: L.Trainer) -> str:
        """The epoch's summary line (see the module docstring)."""
        now = self.clock()
        parts = []
        if self._loss_count:
            parts.append(f"train loss {self._loss_sum / self._loss_count:.4g}")
        val = trainer.callback_metrics.get("val/loss")
        if self._validated and val is not None:
            parts.append(f"val loss {float(val):.4g}")
        train_seconds = self._train_seconds if self._train_seconds is not None else now - self._epoch_start
        parts.append(format_rate(trainer.global_step - self._first_step, train_seconds, "step"))
        parts.append(f"elapsed {format_duration(now - self._fit_start)}")
        return f"{self._epoch_name(trainer)}: " + ", ".join(parts)

    @staticmethod
    def _epoch_name(trainer: L.Trainer) -> str:
        epochs = trainer.max_epochs
        return f"epoch {trainer.current_epoch + 1}" + (f"/{epochs}" if epochs is not None and epochs > 0 else "")
