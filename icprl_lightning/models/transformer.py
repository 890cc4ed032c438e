"""A GPT-2-style pre-LN causal transformer over [context tokens ; query tokens], with a KV cache.

Paper, appendix "Implementation Details": all models use the GPT-2 architecture with causal masking
and learned position embeddings. The sequence is the context (one token per transition) followed by
query tokens. Context tokens attend causally to earlier context tokens. Query q attends to the first
``visible[q]`` context tokens and to itself only, and takes position ``visible[q]``. One training
sequence therefore scores its queries against many context sizes at once, and at deployment a query
that sees the whole context is exactly the last token of the sequence:

``forward`` trains on all tokens in one pass; ``causal`` is one plain causal pass (the "merged" layout of
``models/policy.py``); at deployment ``encode`` runs the context once into a KV cache, ``query`` runs only the
new query tokens against it, and ``empty_cache`` / ``extend`` grow the cache one context token at a time
online, never re-encoding what is already there. ``query(encode(c), q)`` equals ``forward(c, q, visible=[T] *
Q)`` and ``extend`` token by token equals ``encode`` (tested). An empty context is a cache of length 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from icprl_lightning.models.config import TransformerConfig

# tasks per chunk of ``CausalTransformer.encode``: 64 DarkRoom contexts of 100 tokens keep a small model's
# MLP activations (6,400 x 128 floats) within the CPU's cache (benchmarks/deployment_throughput.py)
ENCODE_ROWS = 64


@dataclass
class KVCache:
    """Each layer's context keys and values, in buffers with spare slots for the query tokens.

    Slots [0, length) hold the context; a query writes its own key and value into the slots after it in
    place, so an act() never copies the cache (a torch.cat per layer per step did, and was the largest
    cost of deployment with a small model). Keys are stored transposed, (B, nh, hs, slots), so an act()'s
    q kᵀ is a plain batched matrix product over contiguous rows (``decode_attention``).
    """

    keys: list[Tensor]    # per layer (B, nh, hs, T + slots): transposed
    values: list[Tensor]  # per layer (B, nh, T + slots, hs)
    length: int           # T, the context tokens
    # merged layout (models/policy.py): the last context step's token (B, 1, D), added to every query token
    carry: Tensor | None = None

    @property
    def capacity(self) -> int:
        """Slots in the buffers: the context's ``length`` and the free ones after it."""
        return self.values[0].shape[2]

    def reserve(self, n_queries: int) -> None:
        """Make room for ``n_queries`` query slots after the context (copies the cache only when it grows)."""
        if self.capacity - self.length >= n_queries:
            return
        for i, (k, v) in enumerate(zip(self.keys, self.values, strict=True)):
            slots = self.length + n_queries
            self.keys[i] = k.new_empty((*k.shape[:3], slots))
            self.values[i] = v.new_empty((*v.shape[:2], slots, v.shape[3]))
            self.keys[i][..., : self.length] = k[..., : self.length]
            self.values[i][:, :, : self.length] = v[:, :, : self.length]


def decode_attention(q: Tensor, k_t: Tensor, v: Tensor, mask: Tensor | None) -> Tensor:
    """softmax(q kᵀ / √d, masked) v for a few query tokens against a long cache, as two batched matmuls.

    ``k_t`` is the cache's keys already transposed, (B, nh, hs, T). The same attention as
    ``F.scaled_dot_product_attention``; on CPU its fused kernel tiles over query blocks and costs several times
    more than this for one query token per sequence (an act()), which is bound by reading the cache. With the
    keys stored transposed the first product reads contiguous rows; in scratch timings of 100 tasks × 4 heads of
    8 it was about a quarter faster than a transposed view, and ``einsum`` slower still, but the whole act()
    gained only a few percent (``benchmarks/deployment_throughput.py`` measures the act()). ``mask`` None means
    every query sees every key (one query token after the context: an act()), and skips the masking.
    """
    scores = torch.matmul(q, k_t).mul_(q.shape[-1] ** -0.5)
    if mask is not None:
        scores.masked_fill_(~mask, float("-inf"))
    return torch.matmul(scores.softmax(-1), v)


def one_row_padded(q: Tensor, k_t: Tensor, v: Tensor, mask: Tensor | None) -> Tensor:
    """``decode_attention(q, k_t, v, mask)`` for one query token (an act()) computed on two rows, the second zero,
    and the first returned: what a compiled agent's query step runs (``Agent(compile=True)``).

    Inductor lowers a CPU batched matmul with one row into an element-wise product and a sum; for heads of 8
    channels that kernel was slower than eager's two ATen matmuls (the small 4-head model ran at 9.6× DPT's
    reference compiled, 14.6× eager). With two rows the graph keeps the ATen matmuls and fuses the layers' other
    small operators around them (``benchmarks/deployment_throughput.py --compile``). Rows of a batched matmul are
    independent, so the first row is exactly the one-row result."""
    padded = torch.cat([q, torch.zeros_like(q)], dim=-2)
    if mask is not None:
        mask = mask.expand(*mask.shape[:-2], 2, mask.shape[-1])
    return decode_attention(padded, k_t, v, mask)[..., :1, :]


class SelfAttention(nn.Module):
    def __init__(self, n_embd: int, n_head: int, dropout: float) -> None:
        super().__init__()
        assert n_embd % n_head == 0, f"n_embd {n_embd} must be divisible by n_head {n_head}"
        self.n_head = n_head
        self.qkv = nn.Linear(n_embd, 3 * n_embd)
        self.proj = nn.Linear(n_embd, n_embd)
        self.dropout = dropout
        self.resid_drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, mask: Tensor | None, past: tuple[Tensor, Tensor] | None = None, past_length: int = 0,
                causal: bool = False) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        """With ``past`` (cache buffers), x's keys/values go into the slots after ``past_length`` in place.
        ``causal`` (without ``mask`` or ``past``): token i sees tokens 0..i, by the fused kernel's ``is_causal``."""
        b, t, c = x.shape
        q, k, v = self.qkv(x).split(c, dim=2)
        q, k, v = (z.view(b, t, self.n_head, c // self.n_head).transpose(1, 2) for z in (q, k, v))  # (B, nh, t, hs)
        if past is not None:
            end = past_length + t
            past[0][..., past_length:end] = k.transpose(-1, -2)
            past[1][:, :, past_length:end] = v
            attend = one_row_padded if t == 1 and torch.compiler.is_compiling() else decode_attention
            y = attend(q, past[0][..., :end], past[1][:, :, :end], mask)
        else:
            y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, is_causal=causal,
                                               dropout_p=self.dropout if self.training else 0.0)
        y = y.transpose(1, 2).contiguous().view(b, t, c)
        return self.resid_drop(self.proj(y)), (k, v)


class Block(nn.Module):
    def __init__(self, n_embd: int, n_head: int, dropout: float) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(n_embd)
        self.attn = SelfAttention(n_embd, n_head, dropout)
        self.ln2 = nn.LayerNorm(n_embd)
        self.mlp = nn.Sequential(nn.Linear(n_embd, 4 * n_embd), nn.GELU(), nn.Linear(4 * n_embd, n_embd),
                                 nn.Dropout(dropout))

    def forward(self, x: Tensor, mask: Tensor | None, past: tuple[Tensor, Tensor] | None = None, past_length: int = 0,
                causal: bool = False) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        a, kv = self.attn(self.ln1(x), mask, past, past_length, causal)
        x = x + a
        return x + self.mlp(self.ln2(x)), kv


def query_mask(n_context: int, visible: Tensor) -> Tensor:
    """Boolean mask (True = attend) of shape (T + Q, T + Q) for context T and queries seeing ``visible``."""
    q = len(visible)
    n = n_context + q
    mask = torch.zeros(n, n, dtype=torch.bool, device=visible.device)
    mask[:n_context, :n_context] = torch.ones(n_context, n_context, dtype=torch.bool, device=visible.device).tril()
    cols = torch.arange(n_context, device=visible.device)
    mask[n_context:, :n_context] = cols[None, :] < visible[:, None]
    mask[n_context:, n_context:] = torch.eye(q, dtype=torch.bool, device=visible.device)
    return mask


class CausalTransformer(nn.Module):
    """Pre-LN transformer on embedded tokens, sized by ``config``; ``max_context`` bounds the context length."""

    def __init__(self, config: TransformerConfig, max_context: int) -> None:
        super().__init__()
        self.config = config
        self.max_context = max_context
        self.pos = nn.Embedding(max_context + 1, config.n_embd)
        self.drop = nn.Dropout(config.dropout)
        self.blocks = nn.ModuleList(Block(config.n_embd, config.n_head, config.dropout) for _ in range(config.n_layer))
        self.ln_f = nn.LayerNorm(config.n_embd)
        self.apply(self._init)

    @staticmethod
    def _init(m: nn.Module) -> None:
        if isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, std=0.02)
            nn.init.zeros_(m.bias)
        elif isinstance(m, nn.Embedding):
            nn.init.normal_(m.weight, std=0.02)

    def _check_length(self, t: int) -> None:
        if t > self.max_context:
            raise ValueError(f"context of {t} tokens is longer than this model's max_context {self.max_context}")

    def forward(self, context: Tensor, queries: Tensor, visible: Tensor) -> Tensor:
        """context (B, T, D), queries (B, Q, D), visible (Q,) in [0, T] -> query outputs (B, Q, D)."""
        t = context.shape[1]
        self._check_length(t)
        pos = torch.cat([torch.arange(t, device=context.device), visible.to(context.device)])
        x = self.drop(torch.cat([context, queries], dim=1) + self.pos(pos))
        mask = query_mask(t, visible.to(context.device))
        for block in self.blocks:
            x, _ = block(x, mask)
        return self.ln_f(x[:, t:])

    def causal(self, tokens: Tensor) -> Tensor:
        """tokens (B, T, D) -> outputs (B, T, D), token i attending to tokens 0..i at position i.

        The same function as ``encode``'s pass (whose outputs it keeps, not its keys), by the fused causal
        kernel: no mask tensor, and T tokens where ``forward`` runs T context + Q query tokens.
        """
        t = tokens.shape[1]
        self._check_length(t)
        x = self.drop(tokens + self.pos.weight[:t])
        for block in self.blocks:
            x, _ = block(x, None, causal=True)
        return self.ln_f(x)

    def encode(self, context: Tensor) -> KVCache:
        """Run the context (B, T, D) once; keep each layer's keys and values (with one query slot after them).

        The batch goes through ``ENCODE_ROWS`` rows at a time, each chunk through every layer, writing its
        keys and values straight into the cache buffers: a chunk's activations stay in the CPU's cache
        and their buffers are reused, where the whole batch at once (1,000 DarkRoom tasks: 100k tokens)
        streamed every intermediate through memory, and ``reserve`` copied the cache once more. Rows are
        independent, so the result is the whole-batch pass's.
        """
        b, t, d = context.shape
        self._check_length(t)
        x_all = self.drop(context + self.pos(torch.arange(t, device=context.device)))
        mask = torch.ones(t, t, dtype=torch.bool, device=context.device).tril()
        n_head = self.blocks[0].attn.n_head
        shape = (b, n_head, t + 1, d // n_head)  # one act() = one query token
        keys = [x_all.new_empty((b, n_head, d // n_head, t + 1)) for _ in self.blocks]  # transposed
        values = [x_all.new_empty(shape) for _ in self.blocks]
        for start in range(0, b, ENCODE_ROWS):
            rows = slice(start, start + ENCODE_ROWS)
            x = x_all[rows]
            for block, k_buf, v_buf in zip(self.blocks, keys, values, strict=True):
                x, (k, v) = block(x, mask)
                k_buf[rows, :, :, :t] = k.transpose(-1, -2)
                v_buf[rows, :, :t] = v
        return KVCache(keys, values, t)

    def query(self, cache: KVCache, queries: Tensor) -> Tensor:
        """Queries (B, Q, D) that each see the whole cached context and themselves -> (B, Q, D)."""
        t, q = cache.length, queries.shape[1]
        cache.reserve(q)
        x = self.drop(queries + self.pos(torch.full((q,), t, device=queries.device)))
        mask = None if q == 1 else torch.cat([torch.ones(q, t, dtype=torch.bool, device=queries.device),
                                              torch.eye(q, dtype=torch.bool, device=queries.device)], dim=1)
        for block, k, v in zip(self.blocks, cache.keys, cache.values, strict=True):
            x, _ = block(x, mask, past=(k, v), past_length=t)
        return self.ln_f(x)

    def empty_cache(self, batch_size: int, device: torch.device | str | None = None) -> KVCache:
        """A cache of B empty contexts (length 0), with one query slot, for ``extend`` to grow."""
        param = next(self.parameters())
        device = param.device if device is None else torch.device(device)
        attn = self.blocks[0].attn
        n_embd = attn.qkv.in_features
        shape = (batch_size, attn.n_head, 1, n_embd // attn.n_head)  # (B, nh, 1 slot, hs)
        keys = [torch.zeros(shape, dtype=param.dtype, device=device).transpose(-1, -2).contiguous()
                for _ in self.blocks]
        values = [torch.zeros(shape, dtype=param.dtype, device=device) for _ in self.blocks]
        return KVCache(keys, values, 0)

    def extend(self, cache: KVCache, tokens: Tensor) -> KVCache:
        """Append context tokens (B, n, D) at the end of the cached context, in place; returns the cache.

        Token i takes position ``cache.length + i`` and attends to the whole cached context, the tokens
        before it and itself: the keys and values ``encode`` would have computed for the longer context.
        Buffers grow geometrically (at most to ``max_context`` plus one query slot), so T single-token
        extends copy the cache O(log T) times, not T times.
        """
        b, d = cache.keys[0].shape[0], self.pos.embedding_dim
        if tokens.dim() != 3 or tokens.shape[0] != b or tokens.shape[2] != d:
            raise ValueError(f"tokens must have shape [B={b}, n, D={d}], got {list(tokens.shape)}")
        t, n = cache.length, tokens.shape[1]
        self._check_length(t + n)
        capacity = cache.capacity
        if capacity < t + n + 1:  # room for the new tokens and one query slot after them
            target = max(t + n + 1, min(2 * capacity, self.max_context + 1))
            cache.reserve(target - t)
        x = self.drop(tokens + self.pos(torch.arange(t, t + n, device=tokens.device)))
        mask = torch.cat([torch.ones(n, t, dtype=torch.bool, device=tokens.device),
                          torch.ones(n, n, dtype=torch.bool, device=tokens.device).tril()], dim=1)  # (n, t + n)
        for block, k, v in zip(self.blocks, cache.keys, cache.values, strict=True):
            x, _ = block(x, mask, past=(k, v), past_length=t)
        cache.length = t + n
        return cache
