"""In-context scalar estimators: RewardGen's R_ψ(s, a | D^T) and DIT's Q̂(s, a | D^R) and V̂(s | D^R).

Paper, section 5.3 ("In-context reward representation") and appendix "Decision Importance Transformer".
The backbone is the policy's (context tokenizer + causal transformer); the query token embeds (s, a),
or s alone for V̂, and a linear head reads one scalar. Every query sees the whole context and itself:
by the query mask this equals appending the query after the context and reading the last position,
which is how the paper reads R_ψ ("we read out its prediction at the last time step"), for all queries
of a trajectory in one pass.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.models.tokenizers import TOKENIZERS
from icprl_lightning.models.transformer import CausalTransformer


class InContextEstimator(nn.Module):
    """f(s[, a] | D) -> a scalar per query; ``with_action`` says whether the query holds an action."""

    def __init__(self, context_kind: str, state_dim: int, action_spec: ActionSpec, with_action: bool, n_layer: int,
                 n_embd: int, n_head: int, max_context: int, dropout: float = 0.0) -> None:
        super().__init__()
        if context_kind not in TOKENIZERS:
            raise ValueError(f"no tokenizer for context kind {context_kind!r}; known: {sorted(TOKENIZERS)}")
        self.context_kind = context_kind
        self.action_spec = action_spec
        self.with_action = with_action
        self.tokenizer = TOKENIZERS[context_kind](state_dim, action_spec, n_embd)
        self.query_embed = nn.Linear(state_dim + (action_spec.size if with_action else 0), n_embd)
        self.transformer = CausalTransformer(n_layer, n_embd, n_head, max_context, dropout)
        self.head = nn.Linear(n_embd, 1)

    def forward(self, context, states: Tensor, actions: Tensor | None = None) -> Tensor:
        """states (B, Q, S) [, actions (B, Q) | (B, Q, A)] -> (B, Q), each query seeing the whole context."""
        if self.with_action != (actions is not None):
            raise ValueError(f"this estimator {'needs' if self.with_action else 'takes no'} query actions")
        tokens = self.tokenizer(context)  # (B, T, D)
        query = states if actions is None else torch.cat([states, self.action_spec.encode(actions)], dim=-1)
        visible = torch.full((states.shape[1],), tokens.shape[1], device=states.device)
        return self.head(self.transformer(tokens, self.query_embed(query), visible)).squeeze(-1)


class InContextRewardModel(InContextEstimator):
    """R_ψ(s, a | ξ⁺, ξ⁻) on a T-PRL pair, plus the standardization ICRG applies to its labels.

    The Bradley–Terry likelihood fixes rewards only up to a constant per step, so the raw outputs carry an
    arbitrary offset. ``reward_mean`` / ``reward_std`` (buffers, saved with the weights) are RewardGen's
    output statistics on the training tasks' validation pairs; ``label`` returns standardized rewards, the
    r̂ that ICRG's DIT stage sees in pretraining and at deployment alike.
    """

    def __init__(self, state_dim: int, action_spec: ActionSpec, n_layer: int, n_embd: int, n_head: int,
                 max_context: int, dropout: float = 0.0) -> None:
        super().__init__("trajectory_preference", state_dim, action_spec, True, n_layer, n_embd, n_head, max_context,
                         dropout)
        self.register_buffer("reward_mean", torch.zeros(()))
        self.register_buffer("reward_std", torch.ones(()))

    def label(self, context, states: Tensor, actions: Tensor) -> Tensor:
        """Standardized r̂(s_h, a_h | D^T) for states (B, T, S), actions (B, T) -> (B, T)."""
        return (self(context, states, actions) - self.reward_mean) / self.reward_std
