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

# key -> (the class it must be, its default, whether a callback is of its kind). A config names only what differs,
# by key, e.g. ``evaluation: {every_n_epochs: 2}``, ``evaluation: null`` or ``best_checkpoint: {filename: best}``.
#   evaluation       the held-out evaluation during training: in-context rollouts every epoch;
#   best_checkpoint  "best" = lowest val/loss (validation contexts of the training tasks), printed as
#                    "best checkpoint (val/loss = ..., epoch E): PATH". Not the held-out return: the evaluation's
#                    held-out contexts are those `icprl evaluate` reports on, so choosing by them would select on
#                    the test set. last.ckpt (the final state) is LastCheckpoint's.
NAMED_CALLBACKS: dict[str, tuple[type[Callback], dict[str, Any], Callable[[Callback], bool]]] = {
    "evaluation": (Callback, {"class_path": "icprl_lightning.callbacks.rollout.InContextRolloutCallback"},
                   lambda c: hasattr(c, "requires_data")),  # a held-out evaluation (data_contract.ReadsData)
    "best_checkpoint": (ModelCheckpoint, {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                                          "init_args": {"monitor": "val/loss"}},
                        lambda c: isinstance(c, ModelCheckpoint)),
}


def named_callbacks(named: list[Callback | None], own: list[Callback]) -> list[Callback]:
    """The named callbacks a fit runs (``named`` in ``NAMED_CALLBACKS``' order): not those set to null, nor one of a
    kind the config's own ``trainer.callbacks`` hold, so a config that lists its evaluation or ``ModelCheckpoint``
    itself (as configs did before these defaults) runs with it once."""
    return [c for c, (_, _, kind) in zip(named, NAMED_CALLBACKS.values(), strict=True)
            if c is not None and not any(kind(o) for o in own)]


def default_callbacks() -> list[Callback]:
    """Fresh instances (one set per fit: they hold per-run state)."""
    return [RunDirectory(), FiniteCheck(), LastCheckpoint(), CSVMetrics(), TrainingClock(), TrainingProgress()]
