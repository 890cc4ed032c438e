"""``<run>/checkpoints/last.ckpt`` is always the run's final state, and a SIGTERM ends a fit with exit status 143.

Lightning's ``ModelCheckpoint(save_last=True)`` writes ``last.ckpt`` only when it saves a top-k checkpoint,
so with a monitored metric it holds the last *improving* epoch (a 50-epoch run's "last" could be epoch 46).
``LastCheckpoint`` is unmonitored: it saves at the end of every training epoch (after validation, so the
file holds that epoch's callback states too) and at the end of training if a step was taken since. It
takes ``last.ckpt`` over from every ``ModelCheckpoint``: their ``save_last`` is turned off (it would write
a second, older ``last.ckpt``, or ``last-v1.ckpt`` beside ours) and their ``last_model_path`` names our
file. Every save is atomic (``atomic_io.use_atomic_saves``). At the end of ``fit`` it prints
``last checkpoint (epoch E, step S): PATH``; "best" is ``RunDirectory``'s line, by the metric it was chosen on.

SIGTERM: Lightning's signal connector turns it into a ``SIGTERMException`` between two batches (a
consistent state), a ``SystemExit`` without a code, so the process used to exit 0 and ``fit && next-stage``
carried on. Here the state at that point is saved as ``last.ckpt`` (unless that step is saved already) and
the exit status set to 128 + SIGTERM = 143, the shell's convention for a process ended by SIGTERM. A
Ctrl+C (KeyboardInterrupt, which Lightning turns into exit status 1) saves nothing: it can land in the
middle of an optimizer step, so the last epoch-end ``last.ckpt`` stands.
"""

from __future__ import annotations

import os
import signal
import sys

import lightning as L
from lightning.pytorch.callbacks import Checkpoint, ModelCheckpoint
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities.exceptions import SIGTERMException
from lightning.pytorch.utilities.rank_zero import rank_zero_info

from icprl_lightning.callbacks.atomic_io import use_atomic_saves
from icprl_lightning.callbacks.run_directory import run_directory

SIGTERM_EXIT_STATUS = 128 + signal.SIGTERM


class LastCheckpoint(Checkpoint):
    """Saves the run's final state to ``<run>/checkpoints/last.ckpt`` (module docstring)."""

    FILENAME = "last.ckpt"

    def __init__(self) -> None:
        self.dirpath: str | None = None
        self.last_model_path = ""
        self.saved_epoch: int | None = None  # the epoch and global step of the state in last_model_path
        self.saved_step: int | None = None

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage != "fit":
            return
        self.dirpath = os.path.join(run_directory(trainer, pl_module), "checkpoints")
        self.last_model_path, self.saved_epoch, self.saved_step = "", None, None
        use_atomic_saves(trainer)
        for callback in _model_checkpoints(trainer):
            if callback.save_last:
                rank_zero_info(f"ModelCheckpoint(save_last={callback.save_last!r}) is turned off: LastCheckpoint "
                               f"writes {self.FILENAME} at every epoch's end, whatever the monitor")
                callback.save_last = False

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._save(trainer)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._save(trainer)  # a fit that stopped between epoch ends (e.g. max_time); no-op otherwise

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        if not isinstance(exception, SIGTERMException):
            return
        exception.code = SIGTERM_EXIT_STATUS  # SystemExit's status: what the process exits with
        try:
            self._save(trainer)
        except Exception as err:  # the previous last.ckpt is intact (atomic saves); say so and exit anyway
            saved = f"saving its state failed ({type(err).__name__}: {err})"
        else:
            saved = "its state is saved" if self.last_model_path else "nothing is saved"
        if trainer.is_global_zero:
            where = (f"; last checkpoint (epoch {self.saved_epoch}, step {self.saved_step}): {self.last_model_path}"
                     if self.last_model_path else "")
            sys.stderr.write(f"fit stopped by SIGTERM at epoch {trainer.current_epoch}, global step "
                             f"{trainer.global_step} (exit status {SIGTERM_EXIT_STATUS}); {saved}{where}\n")
            sys.stderr.flush()

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.is_global_zero and self.last_model_path and os.path.exists(self.last_model_path):
            print(f"last checkpoint (epoch {self.saved_epoch}, step {self.saved_step}): {self.last_model_path}",
                  flush=True)

    def _save(self, trainer: L.Trainer) -> None:
        if (self.dirpath is None or trainer.fast_dev_run or trainer.sanity_checking
                or trainer.state.fn != TrainerFn.FITTING or self.saved_step == trainer.global_step):
            return
        path = os.path.join(self.dirpath, self.FILENAME)
        # the whole training state (saying so also silences Lightning's "weights_only was not set" note); the
        # epoch Lightning writes into the file is trainer.current_epoch
        trainer.save_checkpoint(path, weights_only=False)
        self.last_model_path, self.saved_epoch, self.saved_step = path, trainer.current_epoch, trainer.global_step
        for callback in _model_checkpoints(trainer):  # Lightning's public "last checkpoint" attribute, truthful
            callback.last_model_path = path


def _model_checkpoints(trainer: L.Trainer) -> list[ModelCheckpoint]:
    return [c for c in trainer.checkpoint_callbacks if isinstance(c, ModelCheckpoint)]
