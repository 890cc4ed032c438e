"""Weak regret on held-out dueling-bandit problems at validation time (paper, appendix "Dueling Bandit Experiments").

For every context source the DataModule offers (``bandit_suites``: uniform, dirichlet, dts), the module
is deployed through the public ``Agent`` and plays one duel after each context size h = 1..H of the
held-out contexts (``evaluation.evaluate_duels``), beside Double Thompson Sampling on the same comparisons
and the contexts' own behaviour policy. Each duel is scored by the weak regret
min(R* − R(a), R* − R(a')). Logged under ``val/bandit/<source>/<method>/``, with ``<method>`` the
module's own name (``ICPOModule`` -> ``icpo``, or ``method`` if given), ``dts`` and ``behavior``:

* ``weak_regret`` / ``weak_regret_sem`` — at h = H, mean ± standard error over held-out problems;
* ``weak_regret_auc`` / ``weak_regret_auc_sem`` — averaged over h = 1..H.

The same numbers are printed as a table (one row per source; ``print_table``). Runs every
``every_n_epochs`` epochs and at the last one; the sanity check is skipped. Evaluation is seeded, so DTS
and the behaviour give the same numbers at every validation. Under several processes the duels run on
rank 0 and every rank logs their results (``callbacks/distributed.py``).
"""

from __future__ import annotations

import lightning as L

from icprl_lightning.callbacks.distributed import log_broadcast, on_rank_zero
from icprl_lightning.evaluation.duels import evaluate_duels, method_name, regret_curve, summarize_regret
from icprl_lightning.evaluation.report import regret_table, show_table


class BanditRegretCallback(L.Callback):
    requires_data = ("bandit_suites",)  # the held-out evaluation it reads (checked against the data's ``offers``)

    def __init__(self, every_n_epochs: int = 1, seed: int = 0, chunk_size: int = 32, method: str | None = None,
                 greedy: bool | None = None, print_table: bool = True) -> None:
        self.every_n_epochs = every_n_epochs
        self.seed = seed
        self.chunk_size = chunk_size  # problems per forward pass (bounds memory)
        self.method = method
        self.greedy = greedy  # None: the method's own default (argmax for ICPO, as in the paper)
        self.print_table = print_table
        self.last_results: dict[str, dict[str, float]] = {}  # val/bandit/<source>/<method> -> summary

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        epoch = trainer.current_epoch + 1
        if trainer.state.fn == "fit" and epoch % self.every_n_epochs != 0 and epoch != trainer.max_epochs:
            return
        options = {} if self.greedy is None else {"greedy": self.greedy}
        by_source = on_rank_zero(trainer, lambda: self._evaluate(trainer, pl_module, options))
        self.last_results = {f"val/bandit/{source}/{name}": summary
                             for source, per_method in by_source.items() for name, summary in per_method.items()}
        log_broadcast(pl_module, {f"{prefix}/{k}": float(v) for prefix, summary in self.last_results.items()
                                  for k, v in summary.items()})
        if self.print_table and trainer.is_global_zero:
            when = f", epoch {epoch}" if trainer.state.fn == "fit" else ""
            show_table(regret_table(by_source, f"Weak regret on held-out bandit problems{when}"))

    def _evaluate(self, trainer: L.Trainer, pl_module: L.LightningModule,
                  options: dict) -> dict[str, dict[str, dict[str, float]]]:
        """The weak-regret summaries per context source and method."""
        agent = pl_module.make_agent(seed=self.seed, **options)
        method = self.method or method_name(type(pl_module))
        by_source: dict[str, dict[str, dict[str, float]]] = {}
        for suite in trainer.datamodule.bandit_suites():
            duels = evaluate_duels(agent, suite, method, self.seed, self.chunk_size)
            by_source[suite.source] = {name: summarize_regret(regret_curve(suite.expected_rewards, pair))
                                       for name, pair in duels.items()}
        return by_source
