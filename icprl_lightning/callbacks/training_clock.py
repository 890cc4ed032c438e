"""Wall-clock seconds spent training, without validation: what "learning per second" is measured against.

Logs ``time/train_seconds`` at every validation (the seconds since fit start, minus every validation so
far, so rollouts and validation batches do not count), ``time/validation_seconds`` and
``time/optimizer_steps`` (the optimizer steps taken so far). With a CSV logger
the value sits in the same ``metrics.csv`` row as the rollout callback's held-out returns of that step
(``benchmarks/learning_speed.py`` reads them).
"""

from __future__ import annotations

import time

import lightning as L


class TrainingClock(L.Callback):
    def __init__(self) -> None:
        self._fit_start: float | None = None
        self._validating_since: float | None = None
        self._validation_seconds = 0.0

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._fit_start, self._validation_seconds = time.perf_counter(), 0.0

    def on_validation_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._validating_since = time.perf_counter()

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._fit_start is None or self._validating_since is None or trainer.sanity_checking:
            return
        train = self._validating_since - self._fit_start - self._validation_seconds
        clock = {"time/train_seconds": float(train), "time/validation_seconds": float(self._validation_seconds),
                 "time/optimizer_steps": float(trainer.global_step)}
        pl_module.log_dict(clock, on_epoch=True, rank_zero_only=True)  # rank 0's clock under several processes

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._validating_since is not None:
            self._validation_seconds += time.perf_counter() - self._validating_since
            self._validating_since = None
