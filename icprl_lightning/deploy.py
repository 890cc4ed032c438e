"""The public deployment API (DESIGN.md, "Deployment: the public contract").

    from icprl_lightning import load_agent
    agent = load_agent("run/checkpoints/last.ckpt")   # any method's checkpoint
    agent.reset(context)                              # typed, batched context for B tasks
    action = agent.act(obs)                           # obs [B, S] -> [B] (discrete) | [B, A]
    actions = agent.act_each_prefix(obs)              # obs [B, S] -> [B, T] | [B, T, A]: after D_{1:h}, h = 1..T

``reset`` validates the context; the first ``act`` encodes it once into a KV cache and each ``act`` runs
only the query token against it (paper, "DP²T Deployment" / "ICPO Deployment", with D fixed).
``act_each_prefix`` answers "what would the agent do after only the first h comparisons?" for every h at
once — the dueling-bandit evaluation's question (weak regret vs context size) — with one forward pass in
which query h sees the first h context tokens (the training mask); it never builds the cache.

DPT, DP²T and ICPO act with the argmax of T_θ(· | s_h, D) by default (ICRG samples); ``greedy=False``
samples a_h ~ T_θ(· | s_h, D) as the paper's text writes it. Greedy is their default because ICPO's
λ < 1 objective leaves probability mass on the non-preferred actions, so the sampled policy is much
noisier than its mode (docs/RESULTS.md reports both).
Continuous actions are the policy mean. Wrong shapes or dtypes raise ``ValueError`` naming the expected shape.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import torch
from torch import Tensor

from icprl_lightning.contexts import CONTEXT_TYPES
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.models.transformer import KVCache


class Agent:
    """A deployed in-context policy for B tasks at once (see the module docstring)."""

    def __init__(self, policy: InContextPolicy, greedy: bool = True, use_cache: bool = True,
                 seed: int | None = None) -> None:
        self.policy = policy
        self.greedy = greedy
        self.use_cache = use_cache
        self.generator: torch.Generator | None = None
        if seed is not None:
            self.generator = torch.Generator(device=self.device).manual_seed(seed)
        self.context = None
        self.cache: KVCache | None = None

    @property
    def device(self) -> torch.device:
        return next(self.policy.parameters()).device

    @property
    def context_type(self) -> type:
        return CONTEXT_TYPES[self.policy.context_kind]

    @torch.no_grad()
    def reset(self, context) -> None:
        """Condition on a new batch of contexts (encoded once, at the first ``act``)."""
        if not isinstance(context, self.context_type):
            raise ValueError(f"this agent takes a {self.context_type.__name__}, got {type(context).__name__}")
        context.validate(self.policy.state_dim, self.policy.action_spec)
        length, limit = context.states.shape[1], self.policy.transformer.max_context
        if length > limit:
            raise ValueError(f"context holds {length} steps; this model was trained for at most {limit}")
        self.context = context.to(self.device)
        self.cache = None  # encoded by the first act(); act_each_prefix() does not need it

    @torch.no_grad()
    def act(self, obs: Tensor) -> Tensor:
        """obs [B, S] float -> actions [B] int64 (discrete) or [B, A] float (continuous)."""
        query = self._check_obs(obs)[:, None, :]  # (B, 1, S)
        if self.use_cache:
            if self.cache is None:
                self.cache = self.policy.encode(self.context)
            out = self.policy.query(self.cache, query)
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
        if batch_chunk < 1:
            raise ValueError(f"batch_chunk must be >= 1, got {batch_chunk}")
        b, t = self.context.batch_size, self.context.states.shape[1]
        visible = torch.arange(1, t + 1, device=self.device)  # query h sees D_{1:h}
        out = []
        for start in range(0, b, batch_chunk):
            rows = slice(start, start + batch_chunk)
            queries = obs[rows, None, :].expand(-1, t, -1)  # (b, T, S): the same state after every prefix
            out.append(self.policy(self.context.map(lambda x, rows=rows: x[rows]), queries, visible))
        return self._choose(torch.cat(out))  # (B, T, A) -> (B, T) | (B, T, A)

    def _check_obs(self, obs: Tensor) -> Tensor:
        if self.context is None:
            raise RuntimeError("call reset(context) before act(obs)")
        b, s = self.context.batch_size, self.policy.state_dim
        if not isinstance(obs, Tensor) or obs.shape != (b, s) or not obs.is_floating_point():
            got = f"{list(obs.shape)} {obs.dtype}" if isinstance(obs, Tensor) else type(obs).__name__
            raise ValueError(f"obs must be a float tensor of shape [B={b}, S={s}], got {got}")
        return obs.to(self.device)

    def _choose(self, out: Tensor) -> Tensor:
        """Logits or means (..., A) -> actions: the mean (continuous), argmax or a sample (discrete)."""
        if not self.policy.action_spec.discrete:
            return out
        if self.greedy:
            return out.argmax(-1)
        flat = out.reshape(-1, out.shape[-1]).softmax(-1)
        return torch.multinomial(flat, 1, generator=self.generator).reshape(out.shape[:-1])


def load_agent(checkpoint: str | Path, greedy: bool | None = None, use_cache: bool = True, seed: int | None = None,
               map_location: str | torch.device = "cpu"):
    """Load any icprl_lightning method's checkpoint as a deployable agent.

    ``greedy`` None keeps the method's own default (argmax / Gaussian mean for DPT, DP²T and ICPO;
    sampling for ICRG, whose advantage-weighted policy collapses at its argmax); True or False forces it.
    """
    path = Path(checkpoint)
    if not path.is_file():
        raise FileNotFoundError(f"No checkpoint at {path}")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises many types for a damaged file
        raise ValueError(f"{path} is not a readable checkpoint ({type(e).__name__}: {e})") from None
    class_path = ckpt.get("icprl_class_path") if isinstance(ckpt, dict) else None
    if class_path is None:
        raise ValueError(f"{path} is not an icprl_lightning checkpoint (no 'icprl_class_path' entry)")
    module_name, _, cls_name = class_path.rpartition(".")
    cls = getattr(importlib.import_module(module_name), cls_name)
    module = cls.load_from_checkpoint(path, map_location=map_location, weights_only=False)
    module.eval()
    options = {} if greedy is None else {"greedy": greedy}
    return module.make_agent(use_cache=use_cache, seed=seed, **options)
