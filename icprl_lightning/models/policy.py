"""The in-context policy T_θ(a | s, D): context tokenizer + causal transformer + action head.

Discrete actions: a categorical head (logits). Continuous actions: the Gaussian mean of
N(a; T_θ(s, D), γI) (paper, appendix "ICPO for Continuous Control Tasks"), squashed by tanh into the
action box [-1, 1].

Where a query state enters the sequence (``layout``); both compute a function of (s, D_{1:v}) only, for a
query that sees the first v context steps:

* ``"appended"`` (default): [E(c_1) … E(c_T); E_q(s)]: the query is its own token after the context at
  position v, attending to context tokens 1..v and itself (``CausalTransformer.forward``). Training scores
  Q query states in one pass of T + Q tokens under a custom mask.
* ``"merged"``: the query is summed into the token after the last comparison it sees. Token j (0-based)
  is E(c_j) + E_q(s_{j+1}) — comparison j (nothing for j = 0, the sequence's start) plus the *next*
  context step's state — and a query s that sees v steps is the token E(c_v) + E_q(s) at position v.
  Token j carries only D_{1:j} and s_{j+1}; so the output at token j is T_θ(· | s_{j+1}, D_{1:j}), the
  policy at context step j + 1's own state before its comparison is seen, and one plain causal pass of
  T tokens (``CausalTransformer.causal``, the fused ``is_causal`` kernel) scores all T of them
  (``next_step_outputs``): half the tokens of the appended layout's T + T and no mask. Deployment
  encodes tokens 0..T−1 once (they depend on D only) and runs E(c_T) + E_q(s) against the cache
  (``KVCache.carry`` holds E(c_T)). ``benchmarks/training_throughput.py`` measures it.
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor, nn

from icprl_lightning.contexts import ActionSpec, Context
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.normalization import InputNormalizer
from icprl_lightning.models.tokenizers import TOKENIZERS
from icprl_lightning.models.transformer import CausalTransformer, KVCache

LAYOUTS = ("appended", "merged")


class GaussianMeanHead(nn.Module):
    def __init__(self, n_embd: int, action_dim: int) -> None:
        super().__init__()
        self.linear = nn.Linear(n_embd, action_dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.linear(x).tanh()


class InContextPolicy(nn.Module):
    """Maps (context, query states) to action logits (discrete) or action means (continuous)."""

    def __init__(self, context_kind: str, state_dim: int, action_spec: ActionSpec, backbone: TransformerConfig,
                 max_context: int, normalize_inputs: bool = False, layout: str = "appended") -> None:
        super().__init__()
        if context_kind not in TOKENIZERS:
            raise ValueError(f"no tokenizer for context kind {context_kind!r}; known: {sorted(TOKENIZERS)}")
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {list(LAYOUTS)}, got {layout!r}")
        self.context_kind = context_kind
        self.state_dim = state_dim
        self.action_spec = action_spec
        self.layout = layout
        n_embd = backbone.n_embd
        self.tokenizer = TOKENIZERS[context_kind](state_dim, action_spec, n_embd)
        with warnings.catch_warnings():  # a bandit has no state (state_dim 0): its query token is the bias alone,
            warnings.filterwarnings("ignore", "Initializing zero-element tensors", UserWarning)  # nothing to init
            self.query_embed = nn.Linear(state_dim, n_embd)
        self.transformer = CausalTransformer(backbone, max_context)
        self.head = (nn.Linear(n_embd, action_spec.size) if action_spec.discrete
                     else GaussianMeanHead(n_embd, action_spec.size))
        # standardized states and rewards (models/normalization.py); None: the raw inputs, as the paper
        self.normalizer = InputNormalizer(state_dim) if normalize_inputs else None

    @property
    def merged(self) -> bool:
        return self.layout == "merged"

    def _tokens(self, context: Context) -> Tensor:
        return self.tokenizer(context if self.normalizer is None else self.normalizer.context(context))

    def _query(self, query_states: Tensor) -> Tensor:
        return self.query_embed(query_states if self.normalizer is None else self.normalizer.states(query_states))

    def _merged(self, context: Context, start: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """(tokens E(c_j) + E_q(s_{j+1}) for j = 0..T−1, E(c_1..c_T)); ``start`` is E(c_j) before the first step
        (zeros: the sequence's start; online deployment passes the cache's carry)."""
        tokens = self._tokens(context)  # (B, T, D)
        if start is None:
            start = tokens.new_zeros(tokens.shape[0], 1, tokens.shape[2])
        previous = torch.cat([start, tokens[:, :-1]], dim=1)
        return previous + self._query(context.states), tokens

    def features(self, context: Context, query_states: Tensor, visible: Tensor) -> Tensor:
        """The transformer's outputs at the query tokens, before the action head -> (B, Q, n_embd)."""
        if not self.merged:
            return self.transformer(self._tokens(context), self._query(query_states), visible)
        steps, tokens = self._merged(context)
        start = tokens.new_zeros(tokens.shape[0], 1, tokens.shape[2])
        seen = torch.cat([start, tokens], dim=1)[:, visible.to(tokens.device)]  # E(c_v), zeros for v = 0
        return self.transformer(steps, seen + self._query(query_states), visible)

    def forward(self, context: Context, query_states: Tensor, visible: Tensor) -> Tensor:
        """query_states (B, Q, S), visible (Q,) -> (B, Q, A): logits or action means."""
        return self.head(self.features(context, query_states, visible))

    def next_step_outputs(self, context: Context) -> Tensor:
        """Merged layout: T_θ(· | s_{j+1}, D_{1:j}) for j = 0..T−1 in one causal pass -> (B, T, A).

        Equals ``forward(context, context.states, arange(T))`` (tested), in T tokens instead of 2T.
        """
        if not self.merged:
            raise ValueError("next_step_outputs is the merged layout's training pass; this policy's layout is "
                             f"{self.layout!r} (use forward)")
        return self.head(self.transformer.causal(self._merged(context)[0]))

    def encode(self, context: Context) -> KVCache:
        if not self.merged:
            return self.transformer.encode(self._tokens(context))
        steps, tokens = self._merged(context)
        cache = self.transformer.encode(steps)
        cache.carry = tokens[:, -1:]
        return cache

    def query(self, cache: KVCache, query_states: Tensor) -> Tensor:
        """query_states (B, Q, S) against the whole cached context -> (B, Q, A)."""
        x = self._query(query_states)
        if self.merged:
            x = x + cache.carry
        return self.head(self.transformer.query(cache, x))

    def empty_cache(self, batch_size: int, device: torch.device | str | None = None) -> KVCache:
        """A cache of B empty contexts for ``extend`` to grow (online deployment)."""
        cache = self.transformer.empty_cache(batch_size, device)
        if self.merged:
            cache.carry = cache.keys[0].new_zeros(batch_size, 1, self.transformer.pos.embedding_dim)
        return cache

    def extend(self, cache: KVCache, steps: Context) -> KVCache:
        """Append the context steps ``steps`` (B, n) to the cached context, in place (``CausalTransformer.extend``)."""
        if not self.merged:
            return self.transformer.extend(cache, self._tokens(steps))
        new, tokens = self._merged(steps, start=cache.carry)
        self.transformer.extend(cache, new)
        cache.carry = tokens[:, -1:]
        return cache
