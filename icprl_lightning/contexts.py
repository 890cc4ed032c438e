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
shape ``[B, T, A]`` for continuous ones.

``validate(state_dim, action_spec)`` returns the context *normalized* (a new object), which ``Agent.reset``
uses; anything it cannot take as meant is a ``ValueError`` naming the field, the expected shape/dtype/range
and what was given: ``B ≥ 1`` contexts of ``T ≥ 1`` steps (an empty context would put the query at a position
the model never saw); states, rewards and continuous actions floating (float16/bfloat16/float64 converted to
float32; integer and bool refused) and finite (float64 beyond float32's range counts as inf); discrete
actions integer (converted to int64) in ``[0, n)`` (bool refused: ambiguous); ``preferred`` exactly 0 or 1
(int, float or bool; returned float32; 2, −1, 0.5 or NaN refused, never thresholded). A numeric
``numpy.ndarray`` is converted, anything else (lists, scalars, None) refused. ``data/schema.py`` applies
the same value rules to a dataset's memory-mapped arrays when a DataModule loads them.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields

import numpy as np
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


_UNSIGNED = (torch.uint16, torch.uint32, torch.uint64)  # "shell" dtypes: few ops; converted to int64 first


def as_tensor(name: str, x, expected: str) -> Tensor:
    """``x`` as a tensor: tensors as they are, numeric numpy arrays converted (copied); anything else refused
    (a nested list has no definite dtype or shape)."""
    if isinstance(x, Tensor):
        return x
    if isinstance(x, np.ndarray):
        if x.dtype.kind not in "biuf":
            raise ValueError(f"{name} must be a torch.Tensor of shape {expected}; got a numpy array of dtype "
                             f"{x.dtype}")
        return torch.from_numpy(np.array(x, dtype=x.dtype.newbyteorder("=")))
    raise ValueError(f"{name} must be a torch.Tensor (or numpy.ndarray) of shape {expected}, got {type(x).__name__}")


def _check(name: str, x, shape: tuple[int | None, ...], floating: bool | None, expected: str) -> Tensor:
    x = as_tensor(name, x, expected)
    if x.is_complex() or x.is_sparse or x.is_quantized:
        raise ValueError(f"{name} must be a real, dense tensor of shape {expected}, got {x.dtype} ({x.layout})")
    ok_shape = x.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, x.shape, strict=True))
    if not ok_shape:
        raise ValueError(f"{name} must have shape {expected}, got {list(x.shape)}")
    if floating is True and not x.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor of shape {expected}, got dtype {x.dtype}")
    if floating is False and x.is_floating_point():
        raise ValueError(f"{name} must be an integer tensor of shape {expected}, got dtype {x.dtype}")
    return x


def check_floats(name: str, x, shape: tuple[int | None, ...], expected: str) -> Tensor:
    """A floating tensor of ``shape``, every value finite, returned as float32 (float64/16 converted)."""
    x = _check(name, x, shape, True, expected)
    y = x.to(torch.float32)
    bad = ~torch.isfinite(y)
    if bad.any():
        n_nan = int(torch.isnan(y).sum())
        n_inf = int(bad.sum()) - n_nan
        note = ""
        if x.dtype == torch.float64 and int(torch.isinf(x).sum()) < n_inf:
            note = " (float64 values beyond float32's range, |x| > 3.4e38, count as inf)"
        raise ValueError(f"{name} must hold finite values, shape {expected}; got {n_nan} NaN and {n_inf} "
                         f"inf of {y.numel()} values{note}")
    return y


def _found(x: Tensor, bad: Tensor, original: torch.dtype) -> list:
    values = torch.unique(x[bad])[:5].tolist()
    return [v % 2**64 for v in values] if original == torch.uint64 else values


def _check_labels(name: str, x, shape: tuple[int, ...], expected: str) -> Tensor:
    """Preference labels exactly 0 or 1 (int, float or bool), returned as float32 (how batches serve them)."""
    x = _check(name, x, shape, None, expected)
    original = x.dtype
    y = x.to(torch.int64) if original in _UNSIGNED else x
    y = y.to(torch.float64) if y.is_floating_point() else y
    bad = (y != 0) & (y != 1)
    if bad.any():
        raise ValueError(f"{name} must hold only 0 or 1 (1 = the first of the pair won), shape {expected}; "
                         f"got {int(bad.sum())} other values, e.g. {_found(y, bad, original)}")
    return y.to(torch.float32)


def _check_actions(name: str, x, b: int, t: int, spec: ActionSpec) -> Tensor:
    """Discrete: integer indices in [0, n) as int64 (bool refused). Continuous: finite floats as float32."""
    if not spec.discrete:
        return check_floats(name, x, (b, t, spec.size), f"[B={b}, T={t}, A={spec.size}] float32")
    expected = f"[B={b}, T={t}] int64 indices in [0, {spec.size})"
    x = _check(name, x, (b, t), False, expected)
    if x.dtype == torch.bool:
        raise ValueError(f"{name} must be an integer tensor of shape {expected}, got dtype torch.bool "
                         "(bool actions are ambiguous: pass the action indices)")
    y = x.to(torch.int64)
    bad = (y < 0) | (y >= spec.size)
    if bad.any():
        raise ValueError(f"{name} holds action indices outside [0, {spec.size}), shape {expected}; got "
                         f"{int(bad.sum())} such values, e.g. {_found(y, bad, x.dtype)}")
    return y


def _check_states(name: str, x, state_dim: int, axis: str = "T") -> tuple[Tensor, int, int]:
    """A context's first field [B, T, S] as float32, with its batch size and number of steps: both at least 1."""
    x = check_floats(name, x, (None, None, state_dim), f"[B, {axis}, S={state_dim}] float32")
    b, t = x.shape[:2]
    if b == 0:
        raise ValueError(f"{name} holds no contexts (B = 0, shape {list(x.shape)}): a batch needs at least one")
    if t == 0:
        raise ValueError(f"{name} holds an empty context ({axis} = 0, shape {list(x.shape)}): a context needs at "
                         "least one step (the query would sit at a position the model never saw)")
    return x, b, t


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

    def validate(self, state_dim: int, action_spec: ActionSpec) -> StepPreferenceContext:
        states, b, t = _check_states("states", self.states, state_dim)
        return StepPreferenceContext(
            states, _check_actions("actions", self.actions, b, t, action_spec),
            _check_actions("alt_actions", self.alt_actions, b, t, action_spec),
            _check_labels("preferred", self.preferred, (b, t), f"[B={b}, T={t}] with values in {{0, 1}}"))


@dataclass
class RewardContext(_Context):
    """DPT's reward-annotated transitions (s, a, r, s'): the oracle baseline's context only."""

    states: Tensor       # [B, T, S]
    actions: Tensor      # [B, T] | [B, T, A]
    rewards: Tensor      # [B, T]
    next_states: Tensor  # [B, T, S]

    def validate(self, state_dim: int, action_spec: ActionSpec) -> RewardContext:
        states, b, t = _check_states("states", self.states, state_dim)
        return RewardContext(
            states, _check_actions("actions", self.actions, b, t, action_spec),
            check_floats("rewards", self.rewards, (b, t), f"[B={b}, T={t}] float32"),
            check_floats("next_states", self.next_states, (b, t, state_dim), f"[B={b}, T={t}, S={state_dim}] float32"))


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

    def validate(self, state_dim: int, action_spec: ActionSpec) -> TrajectoryPreferenceContext:
        states_a, b, h = _check_states("states_a", self.states_a, state_dim, "H")
        out = dict(
            states_a=states_a, actions_a=_check_actions("actions_a", self.actions_a, b, h, action_spec),
            states_b=check_floats("states_b", self.states_b, (b, h, state_dim),
                                  f"[B={b}, H={h}, S={state_dim}] float32"),
            actions_b=_check_actions("actions_b", self.actions_b, b, h, action_spec),
            preferred=_check_labels("preferred", self.preferred, (b,), f"[B={b}] with values in {{0, 1}}"))
        if (self.behavior_states is None) != (self.behavior_actions is None):
            raise ValueError("behavior_states and behavior_actions come together: set both or neither")
        if self.behavior_states is not None:
            states = check_floats("behavior_states", self.behavior_states, (b, None, state_dim),
                                  f"[B={b}, T, S={state_dim}] float32")
            states, _, t = _check_states("behavior_states", states, state_dim)
            out.update(behavior_states=states,
                       behavior_actions=_check_actions("behavior_actions", self.behavior_actions, b, t, action_spec))
        return TrajectoryPreferenceContext(**out)


@dataclass
class RewardTrajectoryContext(_Context):
    """DIT's context D^R = {s_h, a_h, r_h}: one trajectory with per-step rewards (true, or RewardGen's r̂)."""

    states: Tensor   # [B, T, S]
    actions: Tensor  # [B, T] | [B, T, A]
    rewards: Tensor  # [B, T]

    def validate(self, state_dim: int, action_spec: ActionSpec) -> RewardTrajectoryContext:
        states, b, t = _check_states("states", self.states, state_dim)
        return RewardTrajectoryContext(
            states, _check_actions("actions", self.actions, b, t, action_spec),
            check_floats("rewards", self.rewards, (b, t), f"[B={b}, T={t}] float32"))


# Any of the four typed contexts: the type of every ``context`` a model, a method or an agent takes.
Context = StepPreferenceContext | RewardContext | TrajectoryPreferenceContext | RewardTrajectoryContext

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


def context_from_fields(kind: str, values: dict[str, Tensor]) -> Context:
    """The typed context of ``kind`` from a dict of its fields (named as the dataclass's); optional fields (those
    with a default, e.g. ICRG's behavior trajectory) are taken when present."""
    cls = CONTEXT_TYPES[kind]
    return cls(**{f.name: values[f.name] for f in fields(cls) if f.default is MISSING or f.name in values})
