"""The callbacks every ``icprl fit`` runs with, whatever its config (the CLI's ``trainer_defaults``).

A config's own callbacks come first; these are appended (Lightning then moves checkpoint callbacks last):
``RunDirectory`` (the run's own directory, exact resume), ``FiniteCheck`` (stop on a NaN/inf loss or weight
before anything is saved), ``LastCheckpoint`` (``last.ckpt`` is the final state, saved atomically;
SIGTERM exits 143), ``CSVMetrics`` (the metrics as CSV inside the run directory, beside any logger),
``TrainingClock`` (the training seconds without validation, at every validation: the wall-clock axis of a
learning curve) and ``TrainingProgress`` (plain progress lines and a one-line summary per epoch when output is a
log).
"""

from __future__ import annotations

from lightning.pytorch.callbacks import Callback

from icprl_lightning.callbacks.finite_check import FiniteCheck
from icprl_lightning.callbacks.last_checkpoint import LastCheckpoint
from icprl_lightning.callbacks.progress import TrainingProgress
from icprl_lightning.callbacks.run_directory import RunDirectory
from icprl_lightning.callbacks.run_logs import CSVMetrics
from icprl_lightning.callbacks.training_clock import TrainingClock


def default_callbacks() -> list[Callback]:
    """Fresh instances (one set per fit: they hold per-run state)."""
    return [RunDirectory(), FiniteCheck(), LastCheckpoint(), CSVMetrics(), TrainingClock(), TrainingProgress()]
