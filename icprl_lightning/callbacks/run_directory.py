"""Each ``fit`` in its own run directory, and a resume that continues exactly where the run stopped.

``run_directory`` picks the directory once per fit; ``RunDirectory`` points checkpoints at it, prints where
the run and its best checkpoint are, and stores/restores the RNG states that make a resume exact.
``unique_logger_versions`` gives a CSV or TensorBoard logger a version of its own before the fit starts:
they would otherwise pick ``version_N`` by listing their directory, and two fits started together list it
at the same moment and share one run directory.
"""

from __future__ import annotations

import os
import random
import secrets
import time

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from lightning.pytorch.loggers.logger import DummyLogger

RUN_DIR_ATTR = "_icprl_run_dir"


def fresh_name() -> str:
    """``<date>-<time>-<hex>``: sorts by start time, and two runs started in the same second differ."""
    return f"{time.strftime('%Y%m%d-%H%M%S')}-{secrets.token_hex(3)}"


def unique_logger_versions(trainer: L.Trainer) -> None:
    """Give each CSV/TensorBoard logger without a version a fresh one (``fresh_name``), before anything reads it.

    Call before ``trainer.fit``: Lightning creates the loggers' directories before any callback's ``setup``.
    A version set in the config is kept. W&B needs nothing: its version is its random run id.
    """
    for logger in trainer.loggers:
        # _version: the loggers' only handle on it (their ``version`` property fills it by listing the directory)
        if isinstance(logger, (CSVLogger, TensorBoardLogger)) and logger._version is None:
            logger._version = fresh_name()


def run_directory(trainer: L.Trainer, pl_module: L.LightningModule | None = None) -> str:
    """The run's own directory, chosen once per ``fit`` (cached on the trainer) and created.

    With a logger it is the logger's version directory, ``<save_dir>/<name>/<version>`` (for W&B
    ``<save_dir>/<project>/<run id>``, for CSV/TensorBoard their ``log_dir``), which is where Lightning's
    ``ModelCheckpoint`` without a ``dirpath`` writes too. Without one (``--trainer.logger false``, or
    ``fast_dev_run``, which swaps loggers for a dummy) it is a fresh ``<default_root_dir>/<model>-<time>-<hex>``,
    so two runs of one config never share a directory.
    """
    cached = getattr(trainer, RUN_DIR_ATTR, None)
    if cached is not None:
        return cached
    loggers = [lg for lg in trainer.loggers if not isinstance(lg, DummyLogger)]
    run_dir = None
    if loggers:
        logger = loggers[0]
        if isinstance(logger, (CSVLogger, TensorBoardLogger)):
            run_dir = logger.log_dir
        else:
            version = logger.version
            version = version if isinstance(version, str) else f"version_{version}"
            run_dir = os.path.join(logger.save_dir or trainer.default_root_dir, str(logger.name), version)
    elif trainer.is_global_zero:
        name = type(pl_module).__name__.removesuffix("Module").lower() if pl_module is not None else "run"
        while True:  # a fresh directory, even for two runs started in the same second
            run_dir = os.path.join(trainer.default_root_dir, f"{name}-{fresh_name()}")
            try:
                os.makedirs(run_dir)
                break
            except FileExistsError:
                continue
    run_dir = os.path.abspath(trainer.strategy.broadcast(run_dir))  # rank 0's choice on every rank
    os.makedirs(run_dir, exist_ok=True)
    setattr(trainer, RUN_DIR_ATTR, run_dir)
    return run_dir


class RunDirectory(Callback):
    """Puts every ``fit`` in its own run directory (``run_directory``) and makes its resume exact.

    ``setup`` points each ``ModelCheckpoint`` without a ``dirpath`` at ``<run>/checkpoints`` (without a logger
    Lightning would use the shared ``<default_root_dir>/checkpoints``) and prints the run directory; the end
    of ``fit`` prints each monitored best checkpoint with the metric it was chosen by, ``best checkpoint
    (val/loss = 0.1234, epoch 7): PATH`` (the path a pipeline's next stage takes, e.g. ICRG's
    ``--model.init_args.reward_gen_checkpoint``); ``LastCheckpoint`` prints the last one. An unmonitored
    ``ModelCheckpoint`` has no "best" (its best is merely its latest) and prints nothing. A checkpoint also
    stores the Python, NumPy and torch RNG states, restored on ``--ckpt_path``, and validation runs
    RNG-isolated, so a run resumed from a checkpoint saved at the end of an epoch draws the same shuffles as
    one that was never interrupted.
    """

    def setup(self, trainer, pl_module, stage: str) -> None:
        if stage != "fit":
            return
        run_dir = run_directory(trainer, pl_module)
        for callback in trainer.checkpoint_callbacks:
            if isinstance(callback, ModelCheckpoint) and callback.dirpath is None:
                callback.dirpath = os.path.join(run_dir, "checkpoints")
        if trainer.is_global_zero:
            print(f"run directory: {run_dir}", flush=True)

    def on_fit_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        for callback in trainer.checkpoint_callbacks:
            if not isinstance(callback, ModelCheckpoint) or not callback.monitor:
                continue
            best, score = callback.best_model_path, callback.best_model_score
            if best and score is not None and os.path.exists(best):
                print(f"best checkpoint ({callback.monitor} = {float(score):.6g}{_epoch_of(best)}): "
                      f"{os.path.abspath(best)}", flush=True)

    # Validation during fit draws from the global RNGs too (e.g. ICPO's pair draws); it runs isolated, as
    # Lightning's sanity check does, so the training stream is the same whether or not a run validated, and
    # a checkpoint saved at an epoch's last step resumes into exactly the draws the uninterrupted run makes.
    def on_validation_start(self, trainer, pl_module) -> None:
        self._val_rng = None if trainer.sanity_checking else _rng_state()

    def on_validation_end(self, trainer, pl_module) -> None:
        rng, self._val_rng = getattr(self, "_val_rng", None), None
        if rng is not None:
            _set_rng_state(rng)

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        # a fit stopped inside validation (SIGTERM) is saved next (LastCheckpoint): with the training stream
        self.on_validation_end(trainer, pl_module)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint["icprl_rng"] = _rng_state()

    def on_load_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        # callbacks are restored before the fit loop makes its first iterator (which draws the shuffle)
        if "icprl_rng" in checkpoint:
            try:
                _set_rng_state(checkpoint["icprl_rng"])
            except (KeyError, TypeError, ValueError, IndexError, RuntimeError, AttributeError, OverflowError) as e:
                # only a forged (resealed) file: the seal covers a damaged one
                raise ValueError(f"the checkpoint's icprl_rng entry is not the RNG states a fit saves "
                                 f"({type(e).__name__}: {str(e)[:200]}); resume from another checkpoint") from None


def _epoch_of(path: str) -> str:
    """``", epoch E"`` as stored in the checkpoint (memory-mapped: no weight is read), or "" if unreadable."""
    try:
        return f", epoch {torch.load(path, map_location='cpu', weights_only=True, mmap=True)['epoch']}"
    except Exception:  # the path is still worth printing
        return ""


def _rng_state() -> dict:
    """The Python, NumPy and torch (CPU) RNG states, as tensors and plain values only: checkpoints are read
    with ``weights_only`` loading, which refuses numpy objects."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    return {"python": random.getstate(), "torch": torch.get_rng_state(),
            "numpy": [kind, torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss), float(gauss)]}


def _set_rng_state(state: dict) -> None:
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    kind, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    torch.set_rng_state(state["torch"])
