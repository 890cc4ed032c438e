"""Every log of a fit inside its run directory: the metrics as CSV, and W&B's own (offline) files.

* ``CSVMetrics`` adds a ``CSVLogger`` writing ``<run>/csv/metrics.csv`` (and ``hparams.yaml``) beside any
  other logger, so a run's curves can be read with no server (``icprl report RUN_DIR``). A fit that already
  has a CSV logger, or none at all (``--trainer.logger false``), is left as it is.
* ``wandb_in_run_directory(trainer)``, called before ``trainer.fit``, makes W&B write its files into the run
  directory (``<run>/wandb/offline-run-...``, for ``wandb sync``) instead of ``<save_dir>/wandb``. W&B's
  files go where ``wandb.init(dir=...)`` says, and Lightning starts the W&B run before any callback's
  ``setup``, so no callback can move them: the run id is drawn here, the run directory it implies
  computed as ``run_directory`` will compute it, and that directory handed to ``wandb.init``.
"""

from __future__ import annotations

import os
import secrets

import lightning as L
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.loggers import CSVLogger, Logger, TensorBoardLogger, WandbLogger
from lightning.pytorch.loggers.logger import DummyLogger

from icprl_lightning.callbacks.run_directory import run_directory

CSV_SUBDIR = "csv"  # <run>/csv/metrics.csv: a directory of its own (CSVLogger wants an empty one)
FLUSH_EVERY = 1  # write metrics.csv at every log call, so a running or killed run can be read


def _logger_directory(logger: Logger, default_root_dir: str) -> str:
    """The version directory ``run_directory`` takes from a fit's first logger (the same rule)."""
    if isinstance(logger, (CSVLogger, TensorBoardLogger)):
        return logger.log_dir
    version = logger.version
    version = version if isinstance(version, str) else f"version_{version}"
    return os.path.join(logger.save_dir or default_root_dir, str(logger.name), version)


def wandb_in_run_directory(trainer: L.Trainer) -> str | None:
    """Point every W&B logger that has not started at the fit's run directory; returns it (None: no W&B).

    A W&B logger without an id gets one now (W&B's own would come only with its run), so the run
    directory, ``<save_dir>/<project>/<id>`` when W&B is the first logger, is known before the run starts.
    Call before ``trainer.fit``, after anything that sets the other loggers' versions.
    """
    loggers = [lg for lg in trainer.loggers if not isinstance(lg, DummyLogger)]
    # _experiment, _id and _wandb_init: WandbLogger's only handles on its run id and on wandb.init's ``dir``
    pending = [lg for lg in loggers if isinstance(lg, WandbLogger) and lg._experiment is None]
    if not pending:
        return None
    for logger in pending:
        if logger._id is None:
            logger._id = logger._wandb_init["id"] = secrets.token_hex(4)  # W&B's ids: 8 characters [0-9a-z]
    run_dir = os.path.abspath(_logger_directory(loggers[0], trainer.default_root_dir))
    os.makedirs(run_dir, exist_ok=True)  # W&B looks for a git root there first, and warns when it is missing
    for logger in pending:
        logger._wandb_init["dir"] = run_dir  # wandb.init writes <dir>/wandb/...
    return run_dir


class CSVMetrics(Callback):
    """Adds a ``CSVLogger`` into ``<run>/csv`` (see the module docstring)."""

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage != "fit":
            return
        loggers = [lg for lg in trainer.loggers if not isinstance(lg, DummyLogger)]
        if not loggers or any(isinstance(lg, CSVLogger) for lg in loggers):
            return
        # Lightning logs the hyperparameters after every ``setup``, so the added logger records them too
        csv = CSVLogger(run_directory(trainer, pl_module), name="", version=CSV_SUBDIR,
                        flush_logs_every_n_steps=FLUSH_EVERY)
        trainer.loggers = [*trainer.loggers, csv]
