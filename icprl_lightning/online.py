"""Online deployment with preference queries (DESIGN.md: "an online agent appends each answered comparison
as one token"; docs/deployment.md walks through it).

At each step h the agent proposes a pair (a_h, a'_h) from T_θ(· | s_h, D_{<h}) by its pair rule
(``propose``), an annotator ``label(states [B, S], first, second) -> labels [B]`` answers y_h (1 = first
won), and ``observe`` appends (s_h, a_h, a'_h, y_h) as one new token into the KV cache
(``CausalTransformer.extend``), never re-encoding earlier comparisons. Outputs then equal ``policy.forward``
on the grown context (tests/deploy/test_online_agent.py). Every ``StepPreferenceContext`` model deploys
online, the dueling-bandit ICPO too (``obs = torch.zeros(B, 0)``); other context kinds are refused. With an
empty context the query takes position 0, which training never scores, so the first proposal of an
empty-start agent is the model's uninformed prior.

Pair rules (``PAIR_RULES``, or any callable ``rule(agent, outputs [B, A]) -> (first, second)``):
``ActionAndUniform`` (default, as ``evaluation/duels.py``), ``TopTwo`` and ``SampledPair`` (active,
discrete only), ``UniformPair`` (the passive reference). A name or a discrete-only rule on continuous actions
is checked when the rule is set: one ``ValueError`` before the first ``propose``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import torch
from torch import Tensor

from icprl_lightning.contexts import ActionSpec, StepPreferenceContext, as_tensor
from icprl_lightning.deploy import Agent, load_agent
from icprl_lightning.models.policy import InContextPolicy

Pair = tuple[Tensor, Tensor]
Labeler = Callable[[Tensor, Tensor, Tensor], Tensor]  # label(states, first, second) -> labels in {0, 1}


def _column(name: str, x) -> Tensor:
    """A per-task value [B, ...] (tensor or numpy array) as one context step [B, 1, ...]."""
    x = as_tensor(name, x, "[B] or [B, A]")
    if x.dim() == 0:
        raise ValueError(f"{name} must hold one value per task, shape [B] or [B, A], got a scalar")
    return x[:, None]


class PairRule(Protocol):
    """``discrete_only`` (optional attribute, default False): the rule needs discrete actions."""

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> Pair:
        """``outputs`` [B, A]: T_θ's logits (discrete) or means (continuous) at the current states."""
        ...


def _other_action(agent: OnlineAgent, first: Tensor) -> Tensor:
    """An action uniform over the n − 1 discrete actions other than ``first`` (a uniform non-zero offset)."""
    n = agent.policy.action_spec.size
    return (first + torch.randint(1, n, first.shape, generator=agent.generator, device=first.device)) % n


def _uniform_box(agent: OnlineAgent, shape: torch.Size, device: torch.device) -> Tensor:
    """Points uniform on the continuous action box [-1, 1]^A."""
    return torch.rand(shape, generator=agent.generator, device=device) * 2 - 1


def _discrete_outputs(rule: str, agent: OnlineAgent, outputs: Tensor) -> Tensor:
    """``outputs`` of a model with discrete actions, checked finite as ``act`` checks them; else a clear error."""
    if not agent.policy.action_spec.discrete:
        raise ValueError(f"{rule} needs discrete actions; this model's actions are continuous "
                         "(use ActionAndUniform or another pair rule)")
    agent.choose(outputs)
    return outputs


class ActionAndUniform:
    """The agent's own action first; the second uniform over the other arms (discrete) or on [-1, 1]^A."""

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> Pair:
        first = agent.choose(outputs)
        if agent.policy.action_spec.discrete:
            return first, _other_action(agent, first)
        return first, _uniform_box(agent, first.shape, first.device)


class TopTwo:
    """The two actions of highest probability under T_θ, the most likely first (discrete actions only)."""

    discrete_only = True

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> Pair:
        top = _discrete_outputs("TopTwo", agent, outputs).topk(2, dim=-1).indices
        return top[:, 0], top[:, 1]


class SampledPair:
    """Two distinct actions sampled from T_θ (discrete only): the first ~ T_θ, the second ~ T_θ without the first."""

    discrete_only = True

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> Pair:
        probs = torch.softmax(_discrete_outputs("SampledPair", agent, outputs).float(), dim=-1)
        first = torch.multinomial(probs, 1, generator=agent.generator).squeeze(-1)
        rest = probs.scatter(-1, first[:, None], 0.0)
        # all mass on the first action (a saturated softmax) leaves the rest at 0: fall back to uniform over them
        rest = torch.where(rest.sum(-1, keepdim=True) > 0, rest, torch.ones_like(rest).scatter(-1, first[:, None], 0.0))
        return first, torch.multinomial(rest, 1, generator=agent.generator).squeeze(-1)


class UniformPair:
    """Two distinct uniform actions (discrete), or two uniform points of [-1, 1]^A: the passive reference rule."""

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> Pair:
        if agent.policy.action_spec.discrete:
            first = torch.randint(0, agent.policy.action_spec.size, outputs.shape[:1], generator=agent.generator,
                                  device=outputs.device)
            return first, _other_action(agent, first)
        return _uniform_box(agent, outputs.shape, outputs.device), _uniform_box(agent, outputs.shape, outputs.device)


PAIR_RULES: dict[str, type] = {"action_uniform": ActionAndUniform, "top_two": TopTwo, "sampled": SampledPair,
                               "uniform": UniformPair}


def resolve_pair_rule(rule: PairRule | str | None, action_spec: ActionSpec) -> PairRule:
    """``rule`` as a callable fit for ``action_spec``: a name of ``PAIR_RULES``, a rule object, or None (the default
    ``ActionAndUniform``); an unknown name, a class instead of an instance, anything not callable or a
    discrete-only rule on continuous actions is a ``ValueError`` naming the valid choices."""
    names = ", ".join(sorted(PAIR_RULES))
    if rule is None:
        return ActionAndUniform()
    if isinstance(rule, str):
        if rule not in PAIR_RULES:
            raise ValueError(f"pair_rule {rule!r} is not a pair rule; the names are {names} (or pass any callable "
                             "rule(agent, outputs) -> (first, second))")
        rule = PAIR_RULES[rule]()
    elif isinstance(rule, type):
        raise ValueError(f"pair_rule {rule.__name__} is a class; pass an instance ({rule.__name__}()) or a name: "
                         f"{names}")
    elif not callable(rule):
        raise ValueError(f"pair_rule must be a name ({names}) or a callable rule(agent, outputs) -> (first, second), "
                         f"got {type(rule).__name__}")
    if getattr(rule, "discrete_only", False) and not action_spec.discrete:
        raise ValueError(f"pair_rule {type(rule).__name__} needs discrete actions; this model's actions are "
                         "continuous (use action_uniform or uniform)")
    return rule


class OnlineAgent(Agent):
    """An ``Agent`` whose context (T ≥ 0 steps so far) grows by one answered comparison per ``observe``, its KV
    ``cache`` extended in place (``use_cache=False``: ``policy.forward`` each time, the slow reference). ``seed``
    also drives the pair rule."""

    context: StepPreferenceContext | None

    def __init__(self, policy: InContextPolicy, greedy: bool = True, use_cache: bool = True, seed: int | None = None,
                 pair_rule: PairRule | str | None = None) -> None:
        if policy.context_kind != "step_preference":
            raise ValueError(f"online deployment appends step-preference comparisons; this model takes "
                             f"{policy.context_kind!r} contexts")
        super().__init__(policy, greedy=greedy, use_cache=use_cache, seed=seed)
        self.pair_rule = pair_rule

    @property
    def pair_rule(self) -> PairRule:
        """The rule ``propose`` asks by; set it to a name of ``PAIR_RULES`` or a rule (checked as it is set)."""
        return self._pair_rule

    @pair_rule.setter
    def pair_rule(self, rule: PairRule | str | None) -> None:
        self._pair_rule = resolve_pair_rule(rule, self.policy.action_spec)

    @classmethod
    def from_agent(cls, agent: Agent, pair_rule: PairRule | str | None = None) -> OnlineAgent:
        """The same policy, greedy/cache options and random stream as ``agent`` (e.g. from ``load_agent``)."""
        online = cls(agent.policy, greedy=agent.greedy, use_cache=agent.use_cache, pair_rule=pair_rule)
        if agent.generator is not None:
            online.generator = agent.generator
        return online

    @classmethod
    def load(cls, checkpoint: str | Path, greedy: bool | None = None, seed: int | None = None,
             pair_rule: PairRule | str | None = None, map_location: str | torch.device = "cpu") -> OnlineAgent:
        """Read a checkpoint as ``load_agent`` does (untrusted, allow-listed, checksummed), then go online."""
        return cls.from_agent(load_agent(checkpoint, greedy=greedy, seed=seed, map_location=map_location),
                              pair_rule=pair_rule)

    @property
    def length(self) -> int:
        """Comparisons in the context so far."""
        if self.context is None:
            raise RuntimeError("call reset(batch_size) or reset(context) first")
        return self.context.states.shape[1]

    @torch.no_grad()
    def reset(self, context: StepPreferenceContext | int) -> None:
        """Start B tasks from an empty context (``context`` = B, an int) or from a given one (validated as by
        ``Agent.reset`` and encoded at once, so that ``observe`` can extend its cache)."""
        if isinstance(context, bool) or not isinstance(context, int | StepPreferenceContext):
            raise ValueError(f"reset takes a batch size (int >= 1) or a StepPreferenceContext, got {context!r}")
        if isinstance(context, StepPreferenceContext):
            super().reset(context)
            if self.use_cache:
                self.cache = self.policy.encode(self.context)
            return
        if context < 1:
            raise ValueError(f"batch_size must be >= 1, got {context}")
        self.context = self._empty_context(context)
        self.cache = self.policy.empty_cache(context, self.device) if self.use_cache else None

    @torch.no_grad()
    def outputs(self, obs: Tensor) -> Tensor:
        """T_θ at obs [B, S] given the context so far: logits [B, n] (discrete) or means [B, A] (continuous)."""
        query = self._check_obs(obs)[:, None, :]  # (B, 1, S)
        if self.use_cache:
            return self.policy.query(self.cache, query)[:, 0]
        visible = torch.tensor([self.length], device=self.device)
        return self.policy(self.context, query, visible)[:, 0]

    @torch.no_grad()
    def act(self, obs: Tensor) -> Tensor:
        """obs [B, S] -> actions [B] (discrete) or [B, A] (continuous), as ``Agent.act`` on the context so far."""
        return self.choose(self.outputs(obs))

    def choose(self, outputs: Tensor) -> Tensor:
        """Outputs [B, A] -> actions, as ``act`` does: argmax or a sample (discrete), the mean (continuous)."""
        return self._choose(outputs)

    @torch.no_grad()
    def propose(self, obs: Tensor) -> Pair:
        """The pair (first, second) to ask about at obs [B, S], by ``pair_rule``; each [B] or [B, A]."""
        return self.pair_rule(self, self.outputs(obs))

    @torch.no_grad()
    def observe(self, obs: Tensor, first: Tensor, second: Tensor, labels: Tensor) -> None:
        """Append the answered comparisons (obs [B, S], first, second, labels [B], 1 = first won): one token each,
        validated as one ``StepPreferenceContext`` step; past ``max_context`` a ``ValueError`` and nothing changes."""
        obs = self._check_obs(obs)
        limit = self.policy.transformer.max_context
        if self.length + 1 > limit:
            raise ValueError(f"the context already holds {self.length} comparisons, this model's max_context; "
                             "reset() to start again")
        step = StepPreferenceContext(obs[:, None], _column("first", first), _column("second", second),
                                     _column("labels", labels))
        try:
            step = step.validate(self.policy.state_dim, self.policy.action_spec)
        except ValueError as e:
            raise ValueError(f"observe: {e} (one step: T = 1; first/second are `actions`/`alt_actions`, labels "
                             "are `preferred`)") from None
        if step.batch_size != self.context.batch_size:
            raise ValueError(f"observe: {step.batch_size} comparisons for {self.context.batch_size} tasks")
        step = step.to(self.device)
        if self.use_cache:
            self.policy.extend(self.cache, step)
        self.context = StepPreferenceContext(*(torch.cat([old, new], dim=1) for old, new in zip(
            (self.context.states, self.context.actions, self.context.alt_actions, self.context.preferred),
            (step.states, step.actions, step.alt_actions, step.preferred), strict=True)))

    @torch.no_grad()
    def step(self, obs: Tensor, labeler: Labeler) -> tuple[Tensor, Tensor, Tensor]:
        """Propose a pair at obs, label it by ``labeler(obs, first, second)``, observe it; returns all three."""
        first, second = self.propose(obs)
        labels = labeler(obs, first, second)
        self.observe(obs, first, second, labels)
        return first, second, labels

    def _empty_context(self, batch_size: int) -> StepPreferenceContext:
        spec, d = self.policy.action_spec, self.device
        actions = (torch.zeros(batch_size, 0, dtype=torch.int64, device=d) if spec.discrete
                   else torch.zeros(batch_size, 0, spec.size, device=d))
        return StepPreferenceContext(torch.zeros(batch_size, 0, self.policy.state_dim, device=d), actions,
                                     actions.clone(), torch.zeros(batch_size, 0, device=d))

    def _check_obs(self, obs: Tensor) -> Tensor:
        if self.context is None:
            raise RuntimeError("call reset(batch_size) or reset(context) before act/propose/observe")
        return super()._check_obs(obs)
