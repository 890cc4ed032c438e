"""Supervised in-context pretraining: DPT and DP²T (paper eq. (1) and section 5).

Both maximize log T_θ(a* | s_query, D) over optimal-action labels of query states. They differ only in
the context D: DPT sees reward-annotated transitions (s, a, r, s') — the oracle baseline with full
reward supervision — while DP²T sees the preference context (I-PRL step comparisons). Each training
sequence scores its H query states against context prefixes of every size 1..H at once.
"""

from __future__ import annotations

from torch import Tensor

from icprl_lightning.methods.base import InContextModule
from icprl_lightning.methods.losses import supervised_action_loss
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError

PREFERENCE_KINDS = ("step_preference", "trajectory_preference")


class SupervisedPretrainingModule(InContextModule):
    needs_query_labels = True  # trains on the optimal actions of query states

    def loss(self, batch: ContextSamples) -> tuple[Tensor, dict[str, Tensor]]:
        positions = self.query_positions(batch.query_states.shape[1], batch.query_states.device)
        queries, labels = batch.query_states[:, positions], batch.optimal_actions[:, positions]
        outputs = self.policy(batch.context, queries, positions + 1)
        loss = supervised_action_loss(outputs, labels, self.action_spec.discrete)
        metrics = {}
        if self.action_spec.discrete:
            metrics["action_accuracy"] = (outputs.argmax(-1) == labels).float().mean()
        return loss, metrics


class DPTModule(SupervisedPretrainingModule):
    """DPT: reward context + optimal-action labels (the oracle baseline)."""

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 backbone: TransformerConfig = DEFAULT_BACKBONE, optimizer: OptimizerConfig = DEFAULT_OPTIMIZER,
                 queries_per_context: int | None = None, normalize_inputs: bool = False) -> None:
        super().__init__("reward", state_dim, action_dim, discrete, max_context, backbone=backbone,
                         optimizer=optimizer, queries_per_context=queries_per_context,
                         normalize_inputs=normalize_inputs)


class DP2TModule(SupervisedPretrainingModule):
    """DP²T: preference context + optimal-action labels (the paper's supervised diagnostic)."""

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 context_kind: str = "step_preference", backbone: TransformerConfig = DEFAULT_BACKBONE,
                 optimizer: OptimizerConfig = DEFAULT_OPTIMIZER, queries_per_context: int | None = None,
                 normalize_inputs: bool = False) -> None:
        if context_kind not in PREFERENCE_KINDS:
            raise HyperparameterError(f"DP2TModule: context_kind must be one of {list(PREFERENCE_KINDS)}, got "
                                      f"{context_kind!r} (DP2T conditions on preferences; a reward context makes "
                                      "it DPT, DPTModule)")
        super().__init__(context_kind, state_dim, action_dim, discrete, max_context, backbone=backbone,
                         optimizer=optimizer, queries_per_context=queries_per_context,
                         normalize_inputs=normalize_inputs)
