"""In-context scalar estimators: RewardGen's R_ψ(s, a | D^T) and DIT's Q̂(s, a | D^R) and V̂(s | D^R).

Paper, section 5.3 ("In-context reward representation") and appendix "Decision Importance Transformer".
The backbone is the policy's (context tokenizer + causal transformer); the query token embeds (s, a),
or s alone for V̂, and a linear head reads one scalar. By default every query sees the whole context and
itself: by the query mask this equals appending the query after the context and reading the last
position, which is how the paper reads R_ψ ("we read out its prediction at the last time step"), for all
queries of a trajectory in one pass.

R_ψ's outputs are unbounded by default; ``reward_range`` [low, high] bounds them, r̂ = low + (high − low) σ(f),
the prior that the latent per-step rewards lie in a known interval (DarkRoom's are in {0, 1}).

R_ψ has a second reading rule, ``causal`` (RewardGen's ``pair_source="context_causal"``): the query for
step h of a trajectory sees only the pair context's tokens of steps < h (step 0 sees none, only itself),
in training and in ``label`` alike. See ``InContextRewardModel``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from icprl_lightning.contexts import ActionSpec, Context, TrajectoryPreferenceContext
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.normalization import InputNormalizer
from icprl_lightning.models.tokenizers import TOKENIZERS
from icprl_lightning.models.transformer import CausalTransformer
from icprl_lightning.validation import check_range


class InContextEstimator(nn.Module):
    """f(s[, a] | D) -> a scalar per query; ``with_action`` says whether the query holds an action."""

    def __init__(self, context_kind: str, state_dim: int, action_spec: ActionSpec, with_action: bool,
                 backbone: TransformerConfig, max_context: int, normalize_inputs: bool = False) -> None:
        super().__init__()
        if context_kind not in TOKENIZERS:
            raise ValueError(f"no tokenizer for context kind {context_kind!r}; known: {sorted(TOKENIZERS)}")
        self.context_kind = context_kind
        self.action_spec = action_spec
        self.with_action = with_action
        self.tokenizer = TOKENIZERS[context_kind](state_dim, action_spec, backbone.n_embd)
        self.query_embed = nn.Linear(state_dim + (action_spec.size if with_action else 0), backbone.n_embd)
        self.transformer = CausalTransformer(backbone, max_context)
        self.head = nn.Linear(backbone.n_embd, 1)
        self.normalizer = InputNormalizer(state_dim) if normalize_inputs else None  # see models/normalization.py

    def forward(self, context: Context, states: Tensor, actions: Tensor | None = None, visible: Tensor | None = None
                ) -> Tensor:
        """states (B, Q, S) [, actions (B, Q) | (B, Q, A)] -> (B, Q).

        ``visible`` (Q,): how many context tokens each query sees, from the first (default: all of them).
        """
        if self.with_action != (actions is not None):
            raise ValueError(f"this estimator {'needs' if self.with_action else 'takes no'} query actions")
        if self.normalizer is not None:
            context, states = self.normalizer.context(context), self.normalizer.states(states)
        tokens = self.tokenizer(context)  # (B, T, D)
        query = states if actions is None else torch.cat([states, self.action_spec.encode(actions)], dim=-1)
        if visible is None:
            visible = torch.full((states.shape[1],), tokens.shape[1], device=states.device)
        return self.head(self.transformer(tokens, self.query_embed(query), visible)).squeeze(-1)


class InContextRewardModel(InContextEstimator):
    """R_ψ(s, a | ξ⁺, ξ⁻) on a T-PRL pair, plus the standardization ICRG applies to its labels.

    The Bradley–Terry likelihood fixes rewards only up to a constant per step, so the raw outputs carry an
    arbitrary offset. ``reward_mean`` / ``reward_std`` (buffers, saved with the weights) are RewardGen's
    output statistics on the training tasks' validation pairs; ``label`` returns standardized rewards, the
    r̂ that ICRG's DIT stage sees in pretraining and at deployment alike.

    ``causal`` is the reading rule. False: every query sees the whole pair context. True: the query for
    step h sees the context's tokens of steps < h only (token h holds both trajectories' step h), so when
    R_ψ scores the context's own pair (the paper's eq. (L_R^T)) neither the scored transition nor anything
    later is in view. Queries are one or more trajectories of the context's horizon H laid end to end
    (ξ_a then ξ_b in training, a pair in ICRG's relabeling, the behavior trajectory at deployment): query i
    is step i mod H. What still leaks under the causal reading: s_h continues one of the two trajectories
    whose steps < h are in view (in DarkRoom s_h is a deterministic move from s_{h-1}; in Meta-World the
    states are continuous in time), and the context holds them in winner/loser slots, so whether a scored
    transition belongs to the winner can be read off its state for every h ≥ 1. The causal form is the
    paper's model read fairly in time, not a leak-free test: scoring another pair of the task is.
    """

    def __init__(self, state_dim: int, action_spec: ActionSpec, backbone: TransformerConfig, max_context: int,
                 causal: bool = False, reward_range: tuple[float, float] | None = None,
                 normalize_inputs: bool = False) -> None:
        super().__init__("trajectory_preference", state_dim, action_spec, True, backbone, max_context,
                         normalize_inputs)
        if not isinstance(causal, bool):
            raise ValueError(f"InContextRewardModel: causal must be a bool, got {causal!r}")
        self.causal = causal
        self.reward_range = check_range("InContextRewardModel", "reward_range", reward_range)
        self.register_buffer("reward_mean", torch.zeros(()))
        self.register_buffer("reward_std", torch.ones(()))

    def extra_repr(self) -> str:
        return f"causal={self.causal}, reward_range={self.reward_range}"

    def visible(self, horizon: int, n_queries: int, device: torch.device) -> Tensor | None:
        """Context tokens each query sees: None (all) or, causally, step i mod H of query i -> (Q,)."""
        if not self.causal:
            return None
        if n_queries > horizon and n_queries % horizon:
            raise ValueError(f"states: a causal R_ψ reads query i as step i mod H of trajectories of the context's "
                             f"horizon H={horizon} laid end to end, so it takes at most H queries or a multiple of "
                             f"H; got {n_queries}")
        return torch.arange(n_queries, device=device) % horizon

    def forward(self, context: TrajectoryPreferenceContext, states: Tensor, actions: Tensor) -> Tensor:
        """Raw rewards R_ψ(s, a | context) for states (B, Q, S), actions (B, Q) -> (B, Q), read per ``causal``,
        inside ``reward_range`` when it is set."""
        r = super().forward(context, states, actions, self.visible(context.states_a.shape[1], states.shape[1],
                                                                    states.device))
        if self.reward_range is None:
            return r
        low, high = self.reward_range
        return low + (high - low) * torch.sigmoid(r)

    def label(self, context: TrajectoryPreferenceContext, states: Tensor, actions: Tensor) -> Tensor:
        """Standardized r̂(s_h, a_h | D^T) for states (B, T, S), actions (B, T) -> (B, T)."""
        return (self(context, states, actions) - self.reward_mean) / self.reward_std
