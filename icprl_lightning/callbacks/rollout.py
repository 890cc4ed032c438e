"""In-context rollouts on held-out tasks at validation time (DESIGN.md, "Evaluation and logging").

For every context quality the DataModule offers (``evaluation_suites``), the module is deployed through
the public ``Agent`` API on the held-out tasks' contexts (``evaluation.rollout_in_context``: the paper's
latent return on unseen tasks) and the callback logs, under ``val/<env>/<quality>/``: ``return`` and
``return_sem`` (mean ± standard error over held-out tasks), ``normalized_return``, ``success`` (where the
env reports it), and the behavior policy's and optimal policy's returns beside them. The sanity check is
skipped. The same numbers are printed as a table (``print_table``; ``evaluation.report.results_table``), so a
run shows its held-out results in the terminal, not only in the logger. Under several processes the
rollouts run on rank 0 and every rank logs its results (``callbacks/distributed.py``).

``diagnostics`` (``flipped_labels``, ``random_labels``, ``other_task``; ``evaluation.diagnostics``) adds the
same episodes with the context changed as each states, logged under ``val/<env>/<quality>/<diagnostic>/``:
a run then shows as it trains whether its policy reads the labels of its context. Label diagnostics apply
only to contexts with labels.
"""

from __future__ import annotations

import lightning as L

from icprl_lightning.callbacks.distributed import log_broadcast, on_rank_zero
from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS, applicable, diagnose_suite
from icprl_lightning.evaluation.report import results_table, show_table
from icprl_lightning.evaluation.rollout import rollout_in_context, suite_env, summarize


class InContextRolloutCallback(L.Callback):
    requires_data = ("evaluation_suites",)  # the held-out evaluation it reads (checked against the data's ``offers``)

    def __init__(self, every_n_epochs: int = 1, greedy: bool | None = None, seed: int = 0,
                 print_table: bool = True, diagnostics: list[str] | tuple[str, ...] = ()) -> None:
        for diagnostic in diagnostics:
            if diagnostic not in DIAGNOSTICS or diagnostic == "own":
                raise ValueError(f"InContextRolloutCallback: diagnostics must be among "
                                 f"{[d for d in DIAGNOSTICS if d != 'own']}, got {diagnostic!r}")
        self.diagnostics = tuple(diagnostics)
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
        self.last_results, logged = on_rank_zero(trainer, lambda: self._evaluate(trainer, pl_module, options))
        log_broadcast(pl_module, logged)
        if self.print_table and trainer.is_global_zero:
            when = f", epoch {epoch}" if trainer.state.fn == "fit" else ""
            show_table(results_table(self.last_results, f"In-context rollouts on held-out tasks{when}"))

    def _evaluate(self, trainer: L.Trainer, pl_module: L.LightningModule,
                  options: dict) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
        """The results per suite (and diagnostic) and the values logged from them."""
        agent = pl_module.make_agent(seed=self.seed, **options)
        results: dict[str, dict[str, float]] = {}
        logged: dict[str, float] = {}
        for suite in trainer.datamodule.evaluation_suites():
            with suite_env(suite) as env:  # the own context and every diagnostic reset the same env
                result = summarize(suite, rollout_in_context(agent, suite, seed=self.seed, env=env))
                prefix = f"val/{suite.env_name}/{suite.quality}"
                results[prefix] = result
                logged.update({f"{prefix}/{k}": float(v) for k, v in result.items()})
                for diagnostic in applicable(suite.context, self.diagnostics):
                    changed = diagnose_suite(suite, diagnostic, seed=self.seed)
                    result = summarize(changed, rollout_in_context(agent, changed, seed=self.seed, env=env))
                    results[f"{prefix}/{diagnostic}"] = result
                    logged.update({f"{prefix}/{diagnostic}/{k}": float(v) for k, v in result.items()
                                   if not k.startswith(("behavior", "optimal", "expert"))})
        return results, logged
