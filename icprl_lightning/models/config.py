"""The backbone's sizes in one frozen dataclass, ``TransformerConfig`` (nanoGPT's ``GPTConfig`` habit).

Paper, appendix "Implementation Details": every model (the policy T_θ, RewardGen's R_ψ, DIT's Q̂ and V̂) is a
GPT-2-style causal transformer. Its sizes travel together: each method takes one ``backbone``, every network it
builds reads it, and it is checked once, here, when it is made. In a config::

    model:
      init_args:
        backbone: {n_layer: 3, n_embd: 64, n_head: 4}   # or --model.init_args.backbone.n_layer 4

The context length (``max_context``) is not here: the CLI links it from the DataModule into each method, and the
learning rate and weight decay belong to the optimizer. A checkpoint stores the backbone as a plain dict
(``as_dict``), since a checkpoint is read without unpickling any class; ``coerce`` turns that dict back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from numbers import Integral, Real
from typing import Any

from icprl_lightning.validation import HyperparameterError


def _fail(key: str, rule: str, value: Any) -> None:
    raise HyperparameterError(f"backbone.{key}: must be {rule}, got {value!r}")


def _positive_int(key: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, Integral):
        _fail(key, "an integer", value)
    if value < 1:
        _fail(key, ">= 1", value)


@dataclass(frozen=True)
class TransformerConfig:
    """The sizes of a GPT-2-style pre-LN causal transformer (``models/transformer.py``)."""

    n_layer: int = 3      # transformer blocks
    n_embd: int = 64      # width of every token: the embeddings and the residual stream
    n_head: int = 4       # attention heads per block, each of n_embd / n_head channels
    dropout: float = 0.0  # on the embeddings, the attention weights and each block's outputs, in training only

    def __post_init__(self) -> None:
        for key in ("n_layer", "n_embd", "n_head"):
            _positive_int(key, getattr(self, key))
        if self.n_embd % self.n_head:
            raise HyperparameterError(f"backbone.n_head: must divide backbone.n_embd (each head gets n_embd / n_head "
                                      f"channels), got n_head={self.n_head} with n_embd={self.n_embd}")
        dropout = self.dropout
        if isinstance(dropout, bool) or not isinstance(dropout, Real) or not math.isfinite(dropout):
            _fail("dropout", "a finite number", dropout)
        if not 0.0 <= dropout < 1.0:
            _fail("dropout", "in [0.0, 1.0)", dropout)

    def as_dict(self) -> dict[str, Any]:
        """The sizes as plain values: what a checkpoint's hyperparameters hold."""
        return asdict(self)

    @classmethod
    def coerce(cls, value: TransformerConfig | Mapping[str, Any]) -> TransformerConfig:
        """``value`` itself, or the config its mapping describes (a checkpoint's ``as_dict``; missing keys take
        the defaults above). Anything else, or a key that is not a size, is a ``HyperparameterError``."""
        if isinstance(value, cls):
            return value
        known = [f.name for f in fields(cls)]
        if not isinstance(value, Mapping):
            raise HyperparameterError(f"backbone: must be a TransformerConfig or a mapping of {known}, got {value!r}")
        unknown = [k for k in value if k not in known]
        if unknown:
            raise HyperparameterError(f"backbone: has no key {unknown[0]!r}; its keys are {known}")
        return cls(**value)


DEFAULT_BACKBONE = TransformerConfig()  # every method's default but RewardGen's (methods/reward_gen.py)
