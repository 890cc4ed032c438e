"""Weak regret on held-out dueling-bandit problems at validation time (paper, appendix "Dueling Bandit Experiments").

For every context source the DataModule offers (``bandit_suites``: uniform, dirichlet, dts), the module's
policy and Double Thompson Sampling both play one duel after each context size h = 1..H of the held-out
contexts (``bandit_evaluation.evaluate_duels``), scored with the ``WeakRegret`` metric. Logged under
``val/bandit/<source>/``, side by side:

* ``weak_regret`` / ``weak_regret_auc`` — ICPO at h = H / averaged over h = 1..H;
* ``dts_weak_regret`` / ``dts_weak_regret_auc`` — DTS on the same comparisons;
* ``behavior_weak_regret`` / ``behavior_weak_regret_auc`` — the contexts' own behaviour policy.

Runs every ``every_n_epochs`` epochs and at the last one; the sanity check is skipped. Evaluation is
seeded, so DTS and the behaviour give the same numbers at every validation.
"""

from __future__ import annotations

import lightning as L

from icprl_lightning.bandit_evaluation import evaluate_duels
from icprl_lightning.metrics import WeakRegret


class BanditRegretCallback(L.Callback):
    def __init__(self, every_n_epochs: int = 1, seed: int = 0, chunk_size: int = 32) -> None:
        self.every_n_epochs = every_n_epochs
        self.seed = seed
        self.chunk_size = chunk_size
        self.last_results: dict[str, float] = {}

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        epoch = trainer.current_epoch + 1
        if trainer.state.fn == "fit" and epoch % self.every_n_epochs != 0 and epoch != trainer.max_epochs:
            return
        results: dict[str, float] = {}
        for suite in trainer.datamodule.bandit_suites():
            rewards = suite.expected_rewards
            for method, (first, second) in evaluate_duels(pl_module.policy, suite, self.seed,
                                                          self.chunk_size).items():
                name = f"val/bandit/{suite.source}/" + ("weak_regret" if method == "icpo" else
                                                        f"{method}_weak_regret")
                final, over_h = WeakRegret(), WeakRegret()
                final.update(rewards, first[:, -1], second[:, -1])
                over_h.update(rewards.repeat_interleave(first.shape[1], dim=0), first.reshape(-1),
                              second.reshape(-1))
                results[name] = float(final.compute())
                results[f"{name}_auc"] = float(over_h.compute())
        self.last_results = results
        pl_module.log_dict(results, on_epoch=True)
