"""Each ``fit`` in its own run directory, and a resume that continues exactly where the run stopped.

``run_directory`` picks the directory once per fit; ``RunDirectory`` points checkpoints at it, prints where
the run and its checkpoints are, and stores/restores the RNG states that make a resume exact.
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
            run_dir = os.path.join(trainer.default_root_dir,
                                   f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-{secrets.token_hex(2)}")
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
    of ``fit`` prints where the best and the last checkpoint are (the path a pipeline's next stage takes, e.g.
    ICRG's ``--model.init_args.reward_gen_checkpoint``). A checkpoint also stores the Python, NumPy and
    torch RNG states, restored on ``--ckpt_path``, and validation runs RNG-isolated, so a run resumed from a
    checkpoint saved at the end of an epoch draws the same shuffles as one that was never interrupted.
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
            if not isinstance(callback, ModelCheckpoint):
                continue
            best, last = callback.best_model_path, callback.last_model_path
            if best and os.path.exists(best):
                print(f"best checkpoint: {os.path.abspath(best)}", flush=True)
            if last and os.path.exists(last):
                print(f"last checkpoint: {os.path.abspath(last)}", flush=True)

    # Validation during fit draws from the global RNGs too (e.g. ICPO's pair draws); it runs isolated, as
    # Lightning's sanity check does, so the training stream is the same whether or not a run validated, and
    # a checkpoint saved at an epoch's last step resumes into exactly the draws the uninterrupted run makes.
    def on_validation_start(self, trainer, pl_module) -> None:
        self._val_rng = None if trainer.sanity_checking else _rng_state()

    def on_validation_end(self, trainer, pl_module) -> None:
        rng, self._val_rng = getattr(self, "_val_rng", None), None
        if rng is not None:
            _set_rng_state(rng)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint["icprl_rng"] = _rng_state()

    def on_load_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        # callbacks are restored before the fit loop makes its first iterator (which draws the shuffle)
        if "icprl_rng" in checkpoint:
            _set_rng_state(checkpoint["icprl_rng"])


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
