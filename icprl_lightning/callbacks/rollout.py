"""In-context rollouts on held-out tasks at validation time (DESIGN.md, "Evaluation and logging").

For every context quality the DataModule offers (``evaluation_suites``), the module is deployed through
the public ``Agent`` API on the held-out tasks' contexts and the callback logs, under
``val/<env>/<quality>/``: ``return`` and ``return_sem`` (mean ± standard error over held-out tasks),
``normalized_return``, ``success`` (where the env reports it), and the behavior policy's and optimal
policy's returns beside them. The sanity check is skipped. The same numbers are printed as a table
(``print_table``), so a run shows its held-out results in the terminal, not only in the logger.
"""

from __future__ import annotations

import lightning as L
from rich.console import Console
from rich.table import Table

from icprl_lightning.evaluation import rollout_in_context, summarize


class InContextRolloutCallback(L.Callback):
    def __init__(self, every_n_epochs: int = 1, greedy: bool | None = None, seed: int = 0,
                 print_table: bool = True) -> None:
        self.every_n_epochs = every_n_epochs
        self.print_table = print_table
        self.greedy = greedy
        self.seed = seed
        self.last_results: dict[str, dict[str, float]] = {}

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        epoch = trainer.current_epoch + 1
        last = trainer.max_epochs is not None and epoch >= trainer.max_epochs
        if trainer.state.fn == "fit" and epoch % self.every_n_epochs != 0 and not last:
            return
        # None: the method's own default (argmax for DPT/DP2T/ICPO, sampling for DIT/ICRG, whose
        # advantage-weighted policies are degenerate at their mode)
        options = {} if self.greedy is None else {"greedy": self.greedy}
        agent = pl_module.make_agent(seed=self.seed, **options)
        self.last_results = {}
        for suite in trainer.datamodule.evaluation_suites():
            result = summarize(suite, rollout_in_context(agent, suite, seed=self.seed))
            prefix = f"val/{suite.env_name}/{suite.quality}"
            self.last_results[prefix] = result
            pl_module.log_dict({f"{prefix}/{k}": float(v) for k, v in result.items()}, on_epoch=True)
        if self.print_table and trainer.is_global_zero:
            console = Console(stderr=True)
            if not console.is_terminal:
                console.width = 140  # a log file: do not wrap at 80 columns
            when = f", epoch {epoch}" if trainer.state.fn == "fit" else ""
            console.print(results_table(self.last_results, f"In-context rollouts on held-out tasks{when}"))


COLUMNS = (("return", "return"), ("normalized", "normalized_return"), ("success", "success"),
           ("behavior return", "behavior_return"), ("behavior normalized", "behavior_normalized_return"),
           ("behavior success", "behavior_success"),
           ("optimal return", "optimal_return"), ("expert return", "expert_return"))


def results_table(results: dict[str, dict[str, float]], title: str) -> Table:
    """One row per ``val/<env>/<quality>`` prefix; the columns any of them reports (± sem where known)."""
    shown = [(head, key) for head, key in COLUMNS if any(key in r for r in results.values())]
    table = Table(title=title)
    table.add_column("")
    for head, _ in shown:
        table.add_column(head, justify="right")
    for prefix, r in results.items():
        cells = []
        for _, key in shown:
            value, sem = r.get(key), r.get(f"{key}_sem")
            cells.append("" if value is None else f"{value:.3g}" + ("" if sem is None else f" ± {sem:.2g}"))
        table.add_row(prefix.removeprefix("val/"), *cells)
    return table
