"""The settings that travel together, each in one frozen dataclass (nanoGPT's ``GPTConfig`` habit): the backbone's
sizes, ``TransformerConfig``, and the optimizer's, ``OptimizerConfig``.

Paper, appendix "Implementation Details": every model (the policy T_θ, RewardGen's R_ψ, DIT's Q̂ and V̂) is a
GPT-2-style causal transformer trained with Adam (3e-4 at the paper's sizes). Each method takes one ``backbone``
and one ``optimizer``, every network it builds reads the first, its ``configure_optimizers`` the second, and each is
checked once, here, when it is made. In a config::

    model:
      init_args:
        backbone: {n_layer: 3, n_embd: 64, n_head: 4}   # or --model.init_args.backbone.n_layer 4
        optimizer: {lr: 0.001}                          # or --model.init_args.optimizer.lr 1e-3

The CLI links the context length (``max_context``) from the DataModule. A checkpoint stores each group as a plain
dict (``as_dict``: it is read without unpickling any class); ``coerce`` turns that dict back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

from icprl_lightning.validation import (
    HyperparameterError,
    check_choice,
    check_int,
    check_interval,
    check_nonnegative,
    check_positive,
)

LR_SCHEDULES = ("constant", "cosine")  # methods/schedule.py


@dataclass(frozen=True)  # a dataclass too: jsonargparse reads a dataclass as a group only if its bases all are
class _Group:
    """What both groups share: the key a method takes them by (errors read "backbone.n_layer: must be ..."),
    ``as_dict`` and ``coerce``."""

    group: ClassVar[str]

    def as_dict(self) -> dict[str, Any]:
        """The values as plain values: what a checkpoint's hyperparameters hold."""
        return asdict(self)

    @classmethod
    def coerce(cls, value: Any) -> Any:
        """``value`` itself, or the config its mapping describes (a checkpoint's ``as_dict``; missing keys take
        the defaults). Anything else, or a key the group does not have, is a ``HyperparameterError``."""
        if isinstance(value, cls):
            return value
        known = [f.name for f in fields(cls)]
        if not isinstance(value, Mapping):
            raise HyperparameterError(f"{cls.group}: must be a {cls.__name__} or a mapping of {known}, got {value!r}")
        unknown = [k for k in value if k not in known]
        if unknown:
            raise HyperparameterError(f"{cls.group}: has no key {unknown[0]!r}; its keys are {known}")
        return cls(**value)


@dataclass(frozen=True)
class TransformerConfig(_Group):
    """The sizes of a GPT-2-style pre-LN causal transformer (``models/transformer.py``)."""

    group: ClassVar[str] = "backbone"
    n_layer: int = 3      # transformer blocks
    n_embd: int = 64      # width of every token: the embeddings and the residual stream
    n_head: int = 4       # attention heads per block, each of n_embd / n_head channels
    dropout: float = 0.0  # on the embeddings, the attention weights and each block's outputs, in training only

    def __post_init__(self) -> None:
        for key in ("n_layer", "n_embd", "n_head"):
            check_int("backbone.", key, getattr(self, key), 1)
        if self.n_embd % self.n_head:
            raise HyperparameterError(f"backbone.n_head: must divide backbone.n_embd (each head gets n_embd / n_head "
                                      f"channels), got n_head={self.n_head} with n_embd={self.n_embd}")
        check_interval("backbone.", "dropout", self.dropout, 0.0, 1.0, closed="left")


@dataclass(frozen=True)
class OptimizerConfig(_Group):
    """AdamW's settings and its learning-rate schedule (``methods/schedule.py``)."""

    group: ClassVar[str] = "optimizer"
    lr: float = 3e-4               # the learning rate (the paper's Adam: 3e-4), the peak of a cosine schedule
    weight_decay: float = 0.0      # AdamW's decoupled weight decay
    lr_schedule: str = "constant"  # "constant" (the paper's), or "cosine": linear warm-up, then half a cosine to 0
    warmup_steps: int = 0          # optimizer steps of the cosine schedule's warm-up

    def __post_init__(self) -> None:
        check_positive("optimizer.", "lr", self.lr)
        check_nonnegative("optimizer.", "weight_decay", self.weight_decay)
        check_choice("optimizer.", "lr_schedule", self.lr_schedule, LR_SCHEDULES)
        check_int("optimizer.", "warmup_steps", self.warmup_steps, 0)


DEFAULT_BACKBONE = TransformerConfig()  # every method's default but RewardGen's (methods/reward_gen.py)
DEFAULT_OPTIMIZER = OptimizerConfig()
