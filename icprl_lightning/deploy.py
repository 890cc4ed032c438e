"""The public deployment API (DESIGN.md, "Deployment: the public contract").

    from icprl_lightning import load_agent
    agent = load_agent("run/checkpoints/last.ckpt")   # any method's checkpoint
    agent = load_agent("bandit-icpo")                 # or a model directory, or a shipped model's name
    agent.obs_dim, agent.action_spec, agent.max_context, agent.context_kind   # what it takes (below)
    agent.reset(context)                              # typed, batched context for B tasks
    action = agent.act(obs)                           # obs [B, S] -> [B] (discrete) | [B, A]
    actions = agent.act_each_prefix(obs)              # obs [B, S] -> [B, T] | [B, T, A]: after D_{1:h}, h = 1..T

``obs_dim`` (S), ``action_spec`` (discrete with ``size`` choices, or a continuous vector of ``size``),
``max_context`` (the most context steps ``reset`` accepts) and ``context_kind`` / ``context_type`` (the
context class ``reset`` takes) say what a checkpoint expects, so a script need not guess them.
``reset`` validates the context; the first ``act`` encodes it once into a KV cache and each ``act`` runs
only the query token against it (paper, "DP²T Deployment" / "ICPO Deployment", with D fixed).
``act_each_prefix`` answers "what would the agent do after only the first h comparisons?" for every h at
once — the dueling-bandit evaluation's question (weak regret vs context size) — with one forward pass in
which query h sees the first h context tokens (the training mask); it never builds the cache.

DPT, DP²T and ICPO act with the argmax of T_θ(· | s_h, D) by default (DIT and ICRG sample); ``greedy=False``
samples a_h ~ T_θ(· | s_h, D) as the paper's text writes it. Greedy is their default because ICPO's
policy is only as sharp as its β makes it: for λ = 1 the optimum is T ∝ exp(A*/(β τ)) (τ the label
temperature), about softmax(A*) at β = τ = 1, whose samples are noisy where advantages differ by 1–2
(DarkRoom); a smaller β samples almost as well as the mode (``icprl reproduce darkroom_lambda_beta``).
Continuous actions are the policy mean. Wrong shapes, dtypes or values (labels outside {0, 1}, NaN/inf,
an empty context, bool or out-of-range actions) raise ``ValueError`` naming the field and what it expects;
float64 inputs are converted to float32 (``contexts.py`` lists the rules). Calling ``act`` before
``reset`` is a ``RuntimeError``, as is a policy output that is not finite.
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
        """Condition on a new batch of contexts (encoded once, at the first ``act``).

        The context is validated and normalized (``contexts.py``: dtypes converted where lossless, invalid
        values refused with a ``ValueError`` naming the field). A failed reset leaves the agent without a
        context, so a later ``act`` cannot silently use the previous one.
        """
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
        """The action at ``obs`` after each prefix D_{1:h} of the context, h = 1..T.

        obs [B, S] float -> [B, T] int64 (discrete) or [B, T, A] float (continuous); column h − 1 is
        conditioned on the first h context steps only, so column T − 1 is ``act(obs)`` on the whole
        context (the same action when greedy; a draw from the same distribution when sampling). One
        forward pass per ``batch_chunk`` rows of the batch (each pass attends over 2T tokens, so the
        chunk bounds memory); the KV cache is neither used nor changed.
        """
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
        """Logits or means (..., A) -> actions: the mean (continuous), argmax or a sample (discrete).

        Finite inputs of huge magnitude can overflow the network; a non-finite output is an error, never
        a NaN action or an arbitrary argmax.
        """
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
    """Load any icprl_lightning method's checkpoint as a deployable agent.

    ``checkpoint`` is a ``.ckpt`` file, a model directory in the Hugging Face layout (``icprl export``), or the
    short name of a model shipped with the package (``"bandit-icpo"``; ``hub.shipped_models()`` lists them).
    ``greedy`` None keeps the method's own default (argmax / Gaussian mean for DPT, DP²T and ICPO;
    sampling for ICRG, whose advantage-weighted policy collapses at its argmax); True or False forces it.
    Either is read as untrusted (``checkpoints.py``, ``hub.py``): a ``.ckpt`` with ``weights_only=True``, a
    directory's tensors with ``safetensors``; the class from the allow-list of this package's methods, the stored
    checksums verified; any problem is one ``ValueError`` (or ``FileNotFoundError``) naming the path.
    ``compile`` runs each act()'s query step through ``torch.compile`` (``Agent``): worth its one-time compile
    for many episodes of small models.
    """
    from icprl_lightning.hub import load_model

    module = load_model(checkpoint, map_location=map_location)
    options = {} if greedy is None else {"greedy": greedy}
    return module.make_agent(use_cache=use_cache, seed=seed, compile=compile, **options)
