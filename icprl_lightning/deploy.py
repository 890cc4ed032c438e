"""The public deployment API (DESIGN.md, "Deployment: the public contract").

    from icprl_lightning import load_agent
    agent = load_agent("run/checkpoints/last.ckpt")   # any method's checkpoint
    agent = load_agent("bandit-icpo")                 # or a model directory, or a shipped model's name
    agent.obs_dim, agent.action_spec, agent.max_context, agent.context_kind   # what it takes (below)
    agent.reset(context)                              # typed, batched context for B tasks
    action = agent.act(obs)                           # obs [B, S] -> [B] (discrete) | [B, A]
    actions = agent.act_each_prefix(obs)              # obs [B, S] -> [B, T] | [B, T, A]: after D_{1:h}, h = 1..T

``obs_dim`` (S), ``action_spec``, ``max_context`` and ``context_kind`` / ``context_type`` say what a
checkpoint expects. The first ``act`` encodes the context once into a KV cache; each ``act`` runs only the
query token (paper, "DP²T Deployment" / "ICPO Deployment", D fixed). ``act_each_prefix`` (the
dueling-bandit evaluation's question: weak regret vs context size) is one forward pass where query h sees
the first h context tokens (the training mask), without the cache.

DPT, DP²T and ICPO act greedily by default (DIT and ICRG sample; ``greedy=False`` samples a_h ~ T_θ as the
paper writes it): for λ = 1 ICPO's optimum is T ∝ exp(A*/(β τ)), about softmax(A*) at β = τ = 1, whose
samples are noisy where advantages differ by 1–2 (DarkRoom); a smaller β samples almost as well as the mode
(``icprl reproduce darkroom_lambda_beta``). Continuous actions are the policy mean. Invalid inputs raise
``ValueError`` naming the field (``contexts.py`` lists the rules); ``act`` before ``reset``, or a
non-finite policy output, is a ``RuntimeError``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from icprl_lightning.contexts import CONTEXT_TYPES, ActionSpec, Context, as_tensor, check_floats
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.models.transformer import KVCache

# The keys of ``contexts.CONTEXT_TYPES``, spelled out so a type checker knows the values ``Agent.context_kind``
# can take (a test checks that the two agree).
ContextKind = Literal["step_preference", "trajectory_preference", "reward", "reward_trajectory"]


class Agent:
    """A deployed in-context policy for B tasks at once (see the module docstring)."""

    def __init__(self, policy: InContextPolicy, greedy: bool = True, use_cache: bool = True,
                 seed: int | None = None, compile: bool = False) -> None:
        self.policy = policy
        self.greedy = greedy
        self.use_cache = use_cache
        # torch.compile of the per-step query (one token against the cache): its small ops fused into a few
        # kernels: 1.2-1.5x a model's eager env-steps/s at 100 tasks, after a one-time compile per context length
        # (benchmarks/deployment_throughput.py --compile; docs/results/speed/speed_deploy100.json)
        if compile and not use_cache:
            raise ValueError("compile=True compiles the cached query step: it needs use_cache=True")
        # Inductor's C++ wrapper calls the graph's kernels without a Python frame per kernel, which matters when an
        # act() is a few dozen tiny kernels (a one-time C++ build of a few seconds more)
        self._compiled_query = (torch.compile(policy.query, dynamic=False, options={"cpp_wrapper": True})
                                if compile else None)
        self.generator: torch.Generator | None = None
        if seed is not None:
            self.generator = torch.Generator(device=self.device).manual_seed(seed)
        self.context: Context | None = None
        self.cache: KVCache | None = None

    @property
    def device(self) -> torch.device:
        return next(self.policy.parameters()).device

    @property
    def obs_dim(self) -> int:
        """S: the size of one observation, for ``act(obs [B, S])`` and the context's states (0 for a bandit)."""
        return self.policy.state_dim

    @property
    def action_spec(self) -> ActionSpec:
        """What an action is: ``discrete`` with ``size`` choices (actions int64 in [0, size)), or a continuous
        vector of ``size`` floats."""
        return self.policy.action_spec

    @property
    def max_context(self) -> int:
        """The most context steps T that ``reset`` accepts: the context length the model was trained for."""
        return self.policy.transformer.max_context

    @property
    def context_kind(self) -> ContextKind:
        """The kind of context ``reset`` takes: ``step_preference``, ``trajectory_preference``, ``reward``
        or ``reward_trajectory`` (``context_type`` is its class)."""
        return self.policy.context_kind

    @property
    def context_type(self) -> type:
        """The context class ``reset`` takes (``StepPreferenceContext``, ...), from ``context_kind``."""
        return CONTEXT_TYPES[self.context_kind]

    @torch.no_grad()
    def reset(self, context: Context) -> None:
        """Condition on a new batch of contexts (validated by ``contexts.py``; encoded at the first ``act``).
        A failed reset leaves no context, so a later ``act`` cannot silently use the previous one."""
        self.context, self.cache = None, None
        if not isinstance(context, self.context_type):
            raise ValueError(f"this agent takes a {self.context_type.__name__}, got {type(context).__name__}")
        context = context.validate(self.obs_dim, self.action_spec)
        length, limit = context.states.shape[1], self.max_context
        if length > limit:
            raise ValueError(f"context holds {length} steps; this model was trained for at most {limit}")
        self.context = context.to(self.device)

    @torch.no_grad()
    def act(self, obs: Tensor) -> Tensor:
        """obs [B, S] float -> actions [B] int64 (discrete) or [B, A] float (continuous)."""
        query = self._check_obs(obs)[:, None, :]  # (B, 1, S)
        if self.use_cache:
            if self.cache is None:
                self.cache = self.policy.encode(self.context)
            out = (self._compiled_query or self.policy.query)(self.cache, query)
        else:
            visible = torch.tensor([self.context.states.shape[1]], device=self.device)
            out = self.policy(self.context, query, visible)
        return self._choose(out[:, 0])

    @torch.no_grad()
    def act_each_prefix(self, obs: Tensor, batch_chunk: int = 32) -> Tensor:
        """obs [B, S] -> actions [B, T] | [B, T, A]: column h − 1 conditioned on D_{1:h} only (column T − 1 is
        ``act(obs)``). One forward pass of 2T tokens per ``batch_chunk`` rows (bounds memory); no KV cache."""
        obs = self._check_obs(obs)
        if isinstance(batch_chunk, bool) or not isinstance(batch_chunk, int) or batch_chunk < 1:
            raise ValueError(f"batch_chunk must be an int >= 1, got {batch_chunk!r}")
        b, t = self.context.batch_size, self.context.states.shape[1]
        visible = torch.arange(1, t + 1, device=self.device)  # query h sees D_{1:h}
        out = []
        for start in range(0, b, batch_chunk):
            rows = slice(start, start + batch_chunk)
            queries = obs[rows, None, :].expand(-1, t, -1)  # (b, T, S): the same state after every prefix
            out.append(self.policy(self.context.map(lambda x, rows=rows: x[rows]), queries, visible))
        return self._choose(torch.cat(out))  # (B, T, A) -> (B, T) | (B, T, A)

    def _check_obs(self, obs: Tensor) -> Tensor:
        """obs [B, S] floating (float64/16 converted to float32; numpy arrays accepted), every value finite."""
        if self.context is None:
            raise RuntimeError("call reset(context) before act(obs)")
        b, s = self.context.batch_size, self.policy.state_dim
        expected = f"[B={b}, S={s}] float32"
        if isinstance(obs, np.ndarray) and obs.dtype.kind in "biuf":
            obs = as_tensor("obs", obs, expected)
        if (not isinstance(obs, Tensor) or obs.shape != (b, s) or not obs.is_floating_point()
                or obs.is_complex()):
            got = f"{list(obs.shape)} {obs.dtype}" if isinstance(obs, Tensor | np.ndarray) else type(obs).__name__
            raise ValueError(f"obs must be a float tensor of shape [B={b}, S={s}], got {got}")
        return check_floats("obs", obs, (b, s), expected).to(self.device)

    def _choose(self, out: Tensor) -> Tensor:
        """Logits or means (..., A) -> actions: the mean (continuous), argmax or a sample (discrete). A
        non-finite output (huge inputs overflow the network) is an error, never a NaN action or arbitrary argmax."""
        if not torch.isfinite(out).all():
            rows = int((~torch.isfinite(out)).flatten(1).any(1).sum()) if out.dim() > 1 else 1
            raise RuntimeError(f"the policy's output is not finite (NaN or inf) for {rows} of {out.shape[0]} rows: "
                               "finite inputs of very large magnitude overflow the network (or its weights are "
                               "not finite); rescale the states/rewards to the range the model was trained on")
        if not self.policy.action_spec.discrete:
            return out
        if self.greedy:
            return out.argmax(-1)
        flat = out.reshape(-1, out.shape[-1]).softmax(-1)
        return torch.multinomial(flat, 1, generator=self.generator).reshape(out.shape[:-1])


def load_agent(checkpoint: str | Path, greedy: bool | None = None, use_cache: bool = True, seed: int | None = None,
               map_location: str | torch.device = "cpu", compile: bool = False):
    """Any method's ``.ckpt``, exported model directory (``icprl export``) or shipped model name
    (``hub.shipped_models()``) as a deployable agent. ``greedy`` None keeps the method's default (ICRG samples:
    its advantage-weighted policy collapses at its argmax). Read as untrusted (``checkpoints.py``, ``hub.py``:
    ``weights_only=True`` / ``safetensors``, allow-listed class, checksums verified); any problem is one
    ``ValueError`` (or ``FileNotFoundError``) naming the path. ``compile``: see ``Agent``."""
    from icprl_lightning.hub import load_model

    module = load_model(checkpoint, map_location=map_location)
    options = {} if greedy is None else {"greedy": greedy}
    return module.make_agent(use_cache=use_cache, seed=seed, compile=compile, **options)
