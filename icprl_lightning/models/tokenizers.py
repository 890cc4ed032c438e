"""Context tokenizers: one token per transition of a context dataset (paper, "Implementation Details").

* I-PRL (s_h, a_h, a'_h, y_h): the label is encoded by order — the token is (s, a⁺, a⁻), winner
  first. This is the same information as (a, a', y) and makes the token invariant to which slot each
  action was proposed in.
* Reward contexts (s, a, r, s') for DPT.
* T-PRL pairs (ξ_a, ξ_b, y): one token per step h holding *both* trajectories' transitions, winner first,
  each embedded by its own module, E⁺(s⁺_h, a⁺_h) + E⁻(s⁻_h, a⁻_h) (the paper's reward model embeds ξ⁺ and
  ξ⁻ with two separate modules). Step-aligning the pair keeps the context H tokens long, so a query that
  sees the first t tokens sees both trajectories up to step t, exactly like an I-PRL context prefix.
* Reward trajectories (s, a, r) for DIT, with true rewards or RewardGen's estimates.

A soft label y ∈ (0, 1) (a person's tie, 1/2) has no winner to put first: its token is y E(a first) + (1 − y)
E(a' first), the label's expectation of the two orders' tokens (the embeddings are linear), so a tie's token is
symmetric in the pair. Contexts of labels 0 and 1 take the winner-first path unchanged.

Discrete actions enter as one-hot vectors, continuous ones as they are (``ActionSpec.encode``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from icprl_lightning.contexts import (
    ActionSpec,
    RewardContext,
    RewardTrajectoryContext,
    StepPreferenceContext,
    TrajectoryPreferenceContext,
)
from icprl_lightning.preferences import has_soft_labels


def preferred_first(context: StepPreferenceContext) -> tuple[Tensor, Tensor]:
    """(a⁺, a⁻) from (a, a', y) with y = 1 when ``actions`` won."""
    won = context.preferred > 0.5
    if context.actions.dim() == 3:
        won = won[..., None]
    return torch.where(won, context.actions, context.alt_actions), torch.where(won, context.alt_actions,
                                                                               context.actions)


class StepPreferenceTokenizer(nn.Module):
    def __init__(self, state_dim: int, action_spec: ActionSpec, n_embd: int) -> None:
        super().__init__()
        self.action_spec = action_spec
        self.embed = nn.Linear(state_dim + 2 * action_spec.size, n_embd)

    def forward(self, context: StepPreferenceContext) -> Tensor:
        enc = self.action_spec.encode
        if has_soft_labels(context.preferred):  # y E(a ≻ a') + (1 − y) E(a' ≻ a): a tie's token is both orders' mean
            a, b, y = enc(context.actions), enc(context.alt_actions), context.preferred[..., None]
            return (y * self.embed(torch.cat([context.states, a, b], dim=-1))
                    + (1 - y) * self.embed(torch.cat([context.states, b, a], dim=-1)))
        plus, minus = preferred_first(context)
        return self.embed(torch.cat([context.states, enc(plus), enc(minus)], dim=-1))  # (B, T, D)


class RewardTokenizer(nn.Module):
    def __init__(self, state_dim: int, action_spec: ActionSpec, n_embd: int) -> None:
        super().__init__()
        self.action_spec = action_spec
        self.embed = nn.Linear(2 * state_dim + action_spec.size + 1, n_embd)

    def forward(self, context: RewardContext) -> Tensor:
        parts = [context.states, self.action_spec.encode(context.actions), context.rewards[..., None],
                 context.next_states]
        return self.embed(torch.cat(parts, dim=-1))  # (B, T, D)


def preferred_trajectory_first(context: TrajectoryPreferenceContext) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(s⁺, a⁺, s⁻, a⁻) from (ξ_a, ξ_b, y) with y = 1 when ξ_a won."""
    won = context.preferred.reshape(-1, 1, 1) > 0.5  # (B, 1, 1)
    won_a = won[..., 0] if context.actions_a.dim() == 2 else won
    c = context
    return (torch.where(won, c.states_a, c.states_b), torch.where(won_a, c.actions_a, c.actions_b),
            torch.where(won, c.states_b, c.states_a), torch.where(won_a, c.actions_b, c.actions_a))


class TrajectoryPreferenceTokenizer(nn.Module):
    def __init__(self, state_dim: int, action_spec: ActionSpec, n_embd: int) -> None:
        super().__init__()
        self.action_spec = action_spec
        self.embed_preferred = nn.Linear(state_dim + action_spec.size, n_embd)
        self.embed_rejected = nn.Linear(state_dim + action_spec.size, n_embd)

    def forward(self, context: TrajectoryPreferenceContext) -> Tensor:
        enc = self.action_spec.encode
        if has_soft_labels(context.preferred):  # a tie's tokens are the mean of both orders' (as for steps)
            a = torch.cat([context.states_a, enc(context.actions_a)], dim=-1)
            b = torch.cat([context.states_b, enc(context.actions_b)], dim=-1)
            y = context.preferred.reshape(-1, 1, 1)
            return (y * (self.embed_preferred(a) + self.embed_rejected(b))
                    + (1 - y) * (self.embed_preferred(b) + self.embed_rejected(a)))
        s_plus, a_plus, s_minus, a_minus = preferred_trajectory_first(context)
        return (self.embed_preferred(torch.cat([s_plus, enc(a_plus)], dim=-1))
                + self.embed_rejected(torch.cat([s_minus, enc(a_minus)], dim=-1)))  # (B, H, D)


class RewardTrajectoryTokenizer(nn.Module):
    def __init__(self, state_dim: int, action_spec: ActionSpec, n_embd: int) -> None:
        super().__init__()
        self.action_spec = action_spec
        self.embed = nn.Linear(state_dim + action_spec.size + 1, n_embd)

    def forward(self, context: RewardTrajectoryContext) -> Tensor:
        parts = [context.states, self.action_spec.encode(context.actions), context.rewards[..., None]]
        return self.embed(torch.cat(parts, dim=-1))  # (B, T, D)


TOKENIZERS: dict[str, type[nn.Module]] = {
    "step_preference": StepPreferenceTokenizer,
    "reward": RewardTokenizer,
    "trajectory_preference": TrajectoryPreferenceTokenizer,
    "reward_trajectory": RewardTrajectoryTokenizer,
}
