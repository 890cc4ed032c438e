"""Input standardization of the networks: (s − μ_s) / σ_s per state dimension, (r − μ_r) / σ_r for per-step rewards.

Not in the paper, which feeds raw inputs. On Meta-World Reach the state holds positions in metres on top of large
constant offsets (over the data a dimension's std is 0.03–0.2 while its mean reaches 1) and the reward
−‖tcp − goal‖ has a std of 0.06, so the differences that locate the goal are a small part of each token after a
default-initialised linear embedding and LayerNorm. Standardizing makes every input dimension O(1).

The statistics come from the training split once, when a fit starts (``MethodModule.on_fit_start``), and are
buffers: checkpoints carry them and a deployed agent standardizes its raw context and query states the same way.
Dimensions that are constant over the data keep σ = 1. Actions are not touched (one-hot, or already in [−1, 1]).
Only fields with "states" or "rewards" in their name are read, so no method sees more of the data than it did.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import Tensor, nn

from icprl_lightning.contexts import Context

# at most this many rows (steps) per field enter the statistics, evenly strided
MAX_ROWS = 1_000_000


def _stats(arrays: list[np.ndarray], width: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    rows = [a.reshape(-1, width) if width else a.reshape(-1, 1) for a in arrays]
    rows = [r[:: max(1, len(r) // MAX_ROWS)] for r in rows]
    if not rows:
        return None
    x = np.concatenate(rows).astype(np.float64)
    std = x.std(0)
    return x.mean(0), np.where(std > 1e-6, std, 1.0)


class InputNormalizer(nn.Module):
    """Standardizes states and rewards with statistics fitted on the training split (identity until fitted)."""

    def __init__(self, state_dim: int) -> None:
        super().__init__()
        self.state_dim = state_dim
        self.register_buffer("state_mean", torch.zeros(state_dim))
        self.register_buffer("state_std", torch.ones(state_dim))
        self.register_buffer("reward_mean", torch.zeros(()))
        self.register_buffer("reward_std", torch.ones(()))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))

    def fit(self, split: dict[str, np.ndarray]) -> None:
        """Statistics of every field of ``split`` named *states* (shape [..., S]) or *rewards*; sets ``fitted``."""
        states = [np.asarray(v) for k, v in split.items() if "states" in k and np.asarray(v).shape[-1:] ==
                  (self.state_dim,)]
        rewards = [np.asarray(v) for k, v in split.items() if "rewards" in k]
        if not states:
            raise ValueError(f"normalize_inputs: the training split has no field of states of width {self.state_dim} "
                             f"to fit the statistics on (fields: {sorted(split)})")
        for (mean, std), names in ((_stats(states, self.state_dim), ("state_mean", "state_std")),
                                   (_stats(rewards, None) or (np.zeros(1), np.ones(1)), ("reward_mean", "reward_std"))):
            for name, value in zip(names, (mean, std), strict=True):
                buffer = getattr(self, name)
                buffer.copy_(torch.as_tensor(value, dtype=buffer.dtype).reshape(buffer.shape))
        self.fitted.fill_(True)

    def states(self, x: Tensor) -> Tensor:
        return (x - self.state_mean) / self.state_std

    def rewards(self, x: Tensor) -> Tensor:
        return (x - self.reward_mean) / self.reward_std

    def context(self, context: Context) -> Context:
        """The same context with its state and reward fields standardized (absent optional fields stay None)."""
        changes = {}
        for f in dataclasses.fields(context):
            value = getattr(context, f.name)
            if value is not None and "states" in f.name:
                changes[f.name] = self.states(value)
            elif value is not None and "rewards" in f.name:
                changes[f.name] = self.rewards(value)
        return dataclasses.replace(context, **changes)

    def extra_repr(self) -> str:
        return f"state_dim={self.state_dim}, fitted={bool(self.fitted)}"
