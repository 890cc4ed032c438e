"""The in-context policy T_θ(a | s, D): context tokenizer + causal transformer + action head.

Discrete actions: a categorical head (logits). Continuous actions: the Gaussian mean of
N(a; T_θ(s, D), γI) (paper, appendix "ICPO for Continuous Control Tasks"), squashed by tanh into the
action box [-1, 1].
"""

from __future__ import annotations

from torch import Tensor, nn

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.models.normalization import InputNormalizer
from icprl_lightning.models.tokenizers import TOKENIZERS
from icprl_lightning.models.transformer import CausalTransformer, KVCache


class GaussianMeanHead(nn.Module):
    def __init__(self, n_embd: int, action_dim: int) -> None:
        super().__init__()
        self.linear = nn.Linear(n_embd, action_dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.linear(x).tanh()


class InContextPolicy(nn.Module):
    """Maps (context, query states) to action logits (discrete) or action means (continuous)."""

    def __init__(self, context_kind: str, state_dim: int, action_spec: ActionSpec, n_layer: int, n_embd: int,
                 n_head: int, max_context: int, dropout: float = 0.0, normalize_inputs: bool = False) -> None:
        super().__init__()
        if context_kind not in TOKENIZERS:
            raise ValueError(f"no tokenizer for context kind {context_kind!r}; known: {sorted(TOKENIZERS)}")
        self.context_kind = context_kind
        self.state_dim = state_dim
        self.action_spec = action_spec
        self.tokenizer = TOKENIZERS[context_kind](state_dim, action_spec, n_embd)
        self.query_embed = nn.Linear(state_dim, n_embd)
        self.transformer = CausalTransformer(n_layer, n_embd, n_head, max_context, dropout)
        self.head = (nn.Linear(n_embd, action_spec.size) if action_spec.discrete
                     else GaussianMeanHead(n_embd, action_spec.size))
        # standardized states and rewards (models/normalization.py); None: the raw inputs, as the paper
        self.normalizer = InputNormalizer(state_dim) if normalize_inputs else None

    def _tokens(self, context) -> Tensor:
        return self.tokenizer(context if self.normalizer is None else self.normalizer.context(context))

    def _query(self, query_states: Tensor) -> Tensor:
        return self.query_embed(query_states if self.normalizer is None else self.normalizer.states(query_states))

    def features(self, context, query_states: Tensor, visible: Tensor) -> Tensor:
        """The transformer's outputs at the query tokens, before the action head -> (B, Q, n_embd)."""
        return self.transformer(self._tokens(context), self._query(query_states), visible)

    def forward(self, context, query_states: Tensor, visible: Tensor) -> Tensor:
        """query_states (B, Q, S), visible (Q,) -> (B, Q, A): logits or action means."""
        return self.head(self.features(context, query_states, visible))

    def encode(self, context) -> KVCache:
        return self.transformer.encode(self._tokens(context))

    def query(self, cache: KVCache, query_states: Tensor) -> Tensor:
        """query_states (B, Q, S) against the whole cached context -> (B, Q, A)."""
        return self.head(self.transformer.query(cache, self._query(query_states)))
