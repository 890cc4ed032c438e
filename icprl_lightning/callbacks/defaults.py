"""The callbacks every ``icprl fit`` runs with, whatever its config (the CLI's ``trainer_defaults``), and the two
a config changes or drops by name (``NAMED_CALLBACKS``).

Named callbacks come first, then a config's own ``trainer.callbacks``, then the always-on ones (Lightning then
moves checkpoint callbacks last): ``RunDirectory`` (the run's own directory, exact resume), ``FiniteCheck`` (stop
on a NaN/inf loss or weight before anything is saved), ``LastCheckpoint`` (``last.ckpt`` is the final state, saved
atomically; SIGTERM exits 143), ``CSVMetrics`` (the metrics as CSV inside the run directory, beside any logger),
``TrainingClock`` (the training seconds without validation, at every validation: the wall-clock axis of a
learning curve) and ``TrainingProgress`` (plain progress lines and a one-line summary per epoch when output is a
log).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from lightning.pytorch.callbacks import Callback, ModelCheckpoint

from icprl_lightning.callbacks.finite_check import FiniteCheck
from icprl_lightning.callbacks.last_checkpoint import LastCheckpoint
from icprl_lightning.callbacks.progress import TrainingProgress
from icprl_lightning.callbacks.run_directory import RunDirectory
from icprl_lightning.callbacks.run_logs import CSVMetrics
from icprl_lightning.callbacks.training_clock import TrainingClock

# key -> (the class it must be, its default, whether a callback is of its kind); a config names what differs by key
# (``evaluation: {every_n_epochs: 2}``, ``evaluation: null``). The evaluation: held-out rollouts. The best checkpoint:
# lowest val/loss of the training tasks' validation contexts, never the held-out return `icprl evaluate` reports.
NAMED_CALLBACKS: dict[str, tuple[type[Callback], dict[str, Any], Callable[[Callback], bool]]] = {
    "evaluation": (Callback, {"class_path": "icprl_lightning.callbacks.rollout.InContextRolloutCallback"},
                   lambda c: hasattr(c, "requires_data")),  # a held-out evaluation (data_contract.ReadsData)
    "best_checkpoint": (ModelCheckpoint, {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                                          "init_args": {"monitor": "val/loss"}},
                        lambda c: isinstance(c, ModelCheckpoint)),
}


def default_callbacks() -> list[Callback]:
    """Fresh instances (one set per fit: they hold per-run state)."""
    return [RunDirectory(), FiniteCheck(), LastCheckpoint(), CSVMetrics(), TrainingClock(), TrainingProgress()]
