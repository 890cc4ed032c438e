"""Context tokenizers: one token per transition of a context dataset (paper, "Implementation Details").

* I-PRL (s_h, a_h, a'_h, y_h): the label is encoded by order — the token is (s, a⁺, a⁻), winner
  first. This is the same information as (a, a', y) and makes the token invariant to which slot each
  action was proposed in.
* Reward contexts (s, a, r, s') for DPT.

Discrete actions enter as one-hot vectors, continuous ones as they are (``ActionSpec.encode``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from icprl_lightning.data.contexts import ActionSpec, RewardContext, StepPreferenceContext


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
        plus, minus = preferred_first(context)
        enc = self.action_spec.encode
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


TOKENIZERS: dict[str, type[nn.Module]] = {
    "step_preference": StepPreferenceTokenizer,
    "reward": RewardTokenizer,
}
