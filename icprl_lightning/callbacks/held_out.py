"""The one held-out callback (DESIGN.md, "Evaluation and logging"): at the end of a validation epoch (every
``every_n_epochs`` and the last; the sanity check skipped) it asks a registered evaluation (``evaluation/base.py``)
for the module's numbers on the data's held-out tasks (``during_fit``), logs them and prints them (``show_fit``),
so a run shows its held-out results in the terminal, not only in the logger. Under several processes the
evaluation runs on rank 0 and every rank logs its results (``callbacks/distributed.py``).

The evaluation names what it reads (``requires_data``), which the pairing check compares with what the data
``offers`` before any data is generated. The built-in presets fix the evaluation: ``InContextRolloutCallback``
(``rollouts``: the paper's latent return on unseen tasks per context quality, with ``diagnostics``),
``BanditRegretCallback`` (``duels``: weak regret beside DTS per context source) and
``HeldOutPairAccuracyCallback`` (``pair_accuracy``: RewardGen's held-out pairs).
"""

from __future__ import annotations

from typing import Any

import lightning as L

from icprl_lightning.callbacks.distributed import log_broadcast, on_rank_zero
from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS


class HeldOutCallback(L.Callback):
    """See the module docstring. ``greedy`` None: the method's own default (argmax for DPT/DP²T/ICPO, sampling for
    DIT/ICRG, whose advantage-weighted policies are degenerate at their mode); ``diagnostics`` (rollouts):
    ``flipped_labels``, ``random_labels``, ``other_task`` beside the own context; ``method`` and ``chunk_size``
    (duels): the module's row name and the problems per forward pass."""

    evaluation: str = "rollouts"

    def __init__(self, every_n_epochs: int = 1, greedy: bool | None = None, seed: int = 0, print_table: bool = True,
                 diagnostics: list[str] | tuple[str, ...] = (), method: str | None = None,
                 chunk_size: int = 32) -> None:
        for diagnostic in diagnostics:
            if diagnostic not in DIAGNOSTICS or diagnostic == "own":
                raise ValueError(f"{type(self).__name__}: diagnostics must be among "
                                 f"{[d for d in DIAGNOSTICS if d != 'own']}, got {diagnostic!r}")
        self.every_n_epochs, self.greedy, self.seed, self.print_table = every_n_epochs, greedy, seed, print_table
        self.diagnostics, self.method, self.chunk_size = tuple(diagnostics), method, chunk_size
        self.last_results: dict[str, Any] = {}

    @property
    def requires_data(self) -> tuple[str, ...]:
        return (self.evaluation,)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        epoch = trainer.current_epoch + 1
        last = trainer.max_epochs is not None and epoch >= trainer.max_epochs
        if trainer.state.fn == "fit" and epoch % self.every_n_epochs != 0 and not last:
            return
        from icprl_lightning.registry import EVALUATIONS

        kind = EVALUATIONS.get(self.evaluation)
        self.last_results, logged = on_rank_zero(trainer, lambda: kind.during_fit(
            self._subject(pl_module), trainer.datamodule, seed=self.seed, diagnostics=self.diagnostics,
            chunk_size=self.chunk_size, method=self.method or _row_name(pl_module)))
        log_broadcast(pl_module, logged)
        if self.print_table and trainer.is_global_zero:
            kind.show_fit(self.last_results, f", epoch {epoch}" if trainer.state.fn == "fit" else "")

    def _subject(self, pl_module: L.LightningModule) -> Any:
        """What the evaluation judges: the module deployed as an ``Agent`` (its action choice as ``greedy`` says)."""
        return pl_module.make_agent(seed=self.seed, **({} if self.greedy is None else {"greedy": self.greedy}))


def _row_name(pl_module: L.LightningModule) -> str:
    from icprl_lightning.evaluation.duels import method_name

    return method_name(type(pl_module))
