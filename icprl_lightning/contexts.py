"""Typed, batched in-context datasets: the public input of every method and of ``Agent.reset``.

The paper's context datasets (section 4.1 and the DPT preliminaries):

* ``StepPreferenceContext``  D^I = {s_h, (a_h, a'_h, y_h)}_{h ≤ T}          (I-PRL)
* ``TrajectoryPreferenceContext``  D^T = {ξ, ξ', y}                        (T-PRL)
* ``RewardContext``  D^R = {s_j, a_j, r_j, s'_j}_{j ≤ T}                     (DPT, the reward oracle)
* ``RewardTrajectoryContext``  D^R = {s_h, a_h, r_h}_{h ≤ H}                (DIT; r̂ from RewardGen in ICRG)

``preferred = 1`` always means the *first* element of the pair won. A context carries no reward (but
``RewardContext``, which only DPT receives, and ``RewardTrajectoryContext``, which carries true rewards
only for the DIT oracle baseline and RewardGen's estimates r̂ in ICRG), no goal, no A* and no Q*.

Actions are ``int64`` indices of shape ``[B, T]`` for discrete action spaces and ``float32`` vectors of
shape ``[B, T, A]`` for continuous ones. ``validate`` raises ``ValueError`` naming the expected shape.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields

import torch
from torch import Tensor


@dataclass(frozen=True)
class ActionSpec:
    """What an action is: ``n`` discrete choices, or a ``dim``-dimensional continuous vector."""

    discrete: bool
    size: int  # number of actions (discrete) or action dimension (continuous)

    def encode(self, actions: Tensor) -> Tensor:
        """Actions as network input: one-hot for discrete, the vector itself for continuous."""
        if self.discrete:
            return torch.nn.functional.one_hot(actions.long(), self.size).float()
        return actions.float()

    def describe(self, lead: str) -> str:
        return f"[{lead}] int64" if self.discrete else f"[{lead}, {self.size}] float32"


def _check(name: str, x: Tensor, shape: tuple[int | None, ...], floating: bool | None, expected: str) -> None:
    if not isinstance(x, Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape {expected}, got {type(x).__name__}")
    ok_shape = x.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, x.shape, strict=True))
    if not ok_shape:
        raise ValueError(f"{name} must have shape {expected}, got {list(x.shape)}")
    if floating is True and not x.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor of shape {expected}, got dtype {x.dtype}")
    if floating is False and (x.is_floating_point() or x.is_complex()):
        raise ValueError(f"{name} must be an integer tensor of shape {expected}, got dtype {x.dtype}")


def _check_actions(name: str, x: Tensor, b: int, t: int, spec: ActionSpec) -> None:
    if spec.discrete:
        _check(name, x, (b, t), False, f"[B={b}, T={t}] int64")
        if x.numel() and (x.min() < 0 or x.max() >= spec.size):
            raise ValueError(f"{name} holds action indices outside [0, {spec.size})")
    else:
        _check(name, x, (b, t, spec.size), True, f"[B={b}, T={t}, A={spec.size}] float32")


class _Context:
    def map(self, fn):
        """The same context with ``fn`` applied to every tensor field (absent optional fields stay None)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}  # type: ignore[arg-type]
        return type(self)(**{k: None if v is None else fn(v) for k, v in values.items()})

    def to(self, device: torch.device | str):
        return self.map(lambda x: x.to(device))

    @property
    def batch_size(self) -> int:
        return getattr(self, fields(self)[0].name).shape[0]  # type: ignore[arg-type]


@dataclass
class StepPreferenceContext(_Context):
    """I-PRL context: at state s_h the pair (a_h, a'_h) was compared; ``preferred`` = 1 if a_h won."""

    states: Tensor       # [B, T, S] float
    actions: Tensor      # [B, T] int64 | [B, T, A] float
    alt_actions: Tensor  # [B, T] int64 | [B, T, A] float
    preferred: Tensor    # [B, T] in {0, 1}

    def validate(self, state_dim: int, action_spec: ActionSpec) -> None:
        _check("states", self.states, (None, None, state_dim), True, f"[B, T, S={state_dim}] float32")
        b, t = self.states.shape[:2]
        _check_actions("actions", self.actions, b, t, action_spec)
        _check_actions("alt_actions", self.alt_actions, b, t, action_spec)
        _check("preferred", self.preferred, (b, t), None, f"[B={b}, T={t}] with values in {{0, 1}}")


@dataclass
class RewardContext(_Context):
    """DPT's reward-annotated transitions (s, a, r, s'): the oracle baseline's context only."""

    states: Tensor       # [B, T, S]
    actions: Tensor      # [B, T] | [B, T, A]
    rewards: Tensor      # [B, T]
    next_states: Tensor  # [B, T, S]

    def validate(self, state_dim: int, action_spec: ActionSpec) -> None:
        _check("states", self.states, (None, None, state_dim), True, f"[B, T, S={state_dim}] float32")
        b, t = self.states.shape[:2]
        _check_actions("actions", self.actions, b, t, action_spec)
        _check("rewards", self.rewards, (b, t), True, f"[B={b}, T={t}] float32")
        _check("next_states", self.next_states, (b, t, state_dim), True, f"[B={b}, T={t}, S={state_dim}] float32")


@dataclass
class TrajectoryPreferenceContext(_Context):
    """T-PRL context D^T = {ξ_a, ξ_b, y}: two state-action trajectories of one task, ``preferred`` = 1 if ξ_a won.

    ICRG deployment (paper, "ICRG Deployment") also needs an unlabeled behavior trajectory of the same
    task, {s_h, a_h}, which RewardGen labels: ``behavior_states`` / ``behavior_actions`` (both or neither;
    other methods ignore them).
    """

    states_a: Tensor   # [B, H, S] float
    actions_a: Tensor  # [B, H] int64 | [B, H, A] float
    states_b: Tensor   # [B, H, S] float
    actions_b: Tensor  # [B, H] int64 | [B, H, A] float
    preferred: Tensor  # [B] in {0, 1}
    behavior_states: Tensor | None = None   # [B, T, S] float
    behavior_actions: Tensor | None = None  # [B, T] int64 | [B, T, A] float

    @property
    def states(self) -> Tensor:
        """ξ_a's states [B, H, S]: the step axis of the context (one token per step of the pair)."""
        return self.states_a

    def validate(self, state_dim: int, action_spec: ActionSpec) -> None:
        _check("states_a", self.states_a, (None, None, state_dim), True, f"[B, H, S={state_dim}] float32")
        b, h = self.states_a.shape[:2]
        _check_actions("actions_a", self.actions_a, b, h, action_spec)
        _check("states_b", self.states_b, (b, h, state_dim), True, f"[B={b}, H={h}, S={state_dim}] float32")
        _check_actions("actions_b", self.actions_b, b, h, action_spec)
        _check("preferred", self.preferred, (b,), None, f"[B={b}] with values in {{0, 1}}")
        if (self.behavior_states is None) != (self.behavior_actions is None):
            raise ValueError("behavior_states and behavior_actions come together: set both or neither")
        if self.behavior_states is not None:
            _check("behavior_states", self.behavior_states, (b, None, state_dim), True,
                   f"[B={b}, T, S={state_dim}] float32")
            _check_actions("behavior_actions", self.behavior_actions, b, self.behavior_states.shape[1], action_spec)


@dataclass
class RewardTrajectoryContext(_Context):
    """DIT's context D^R = {s_h, a_h, r_h}: one trajectory with per-step rewards (true, or RewardGen's r̂)."""

    states: Tensor   # [B, T, S]
    actions: Tensor  # [B, T] | [B, T, A]
    rewards: Tensor  # [B, T]

    def validate(self, state_dim: int, action_spec: ActionSpec) -> None:
        _check("states", self.states, (None, None, state_dim), True, f"[B, T, S={state_dim}] float32")
        b, t = self.states.shape[:2]
        _check_actions("actions", self.actions, b, t, action_spec)
        _check("rewards", self.rewards, (b, t), True, f"[B={b}, T={t}] float32")


CONTEXT_TYPES: dict[str, type[_Context]] = {
    "step_preference": StepPreferenceContext,
    "reward": RewardContext,
    "trajectory_preference": TrajectoryPreferenceContext,
    "reward_trajectory": RewardTrajectoryContext,
}


def context_fields(kind: str) -> tuple[str, ...]:
    if kind not in CONTEXT_TYPES:
        raise ValueError(f"unknown context kind {kind!r}; known: {sorted(CONTEXT_TYPES)}")
    return tuple(f.name for f in fields(CONTEXT_TYPES[kind]))


def context_from_batch(kind: str, batch: dict[str, Tensor], prefix: str = ""):
    """Build the typed context of ``kind`` from a batch dict (fields named as the dataclass, + ``prefix``).

    Optional fields (those with a default, e.g. ICRG's behavior trajectory) are taken when present.
    """
    cls = CONTEXT_TYPES[kind]
    return cls(**{f.name: batch[prefix + f.name] for f in fields(cls)
                  if f.default is MISSING or prefix + f.name in batch})
