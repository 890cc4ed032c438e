"""Evaluation callbacks under several processes: compute once on global rank 0, hand the result to all.

A held-out rollout (or weak-regret duel, or pair score) is the same on every rank, and running it on each
would multiply its cost by the world size. ``on_rank_zero`` runs it on rank 0 only and broadcasts the
result, so every rank then logs the same values: a callback such as ``ModelCheckpoint`` may monitor them
on every rank (a value logged on rank 0 only, ``rank_zero_only=True``, could not be monitored, and the
other ranks would stop at the checkpoint's missing key). ``log_broadcast`` logs such values: they are
the same on every rank already, so they need no ``sync_dist`` all-reduce, and Lightning's advice to add
one is silenced for exactly those keys. One process: ``compute()`` and ``log_dict``, nothing else.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable
from typing import TypeVar

import lightning as L
import torch.distributed as dist
from lightning.fabric.utilities.warnings import PossibleUserWarning

T = TypeVar("T")


def on_rank_zero(trainer: L.Trainer, compute: Callable[[], T]) -> T:
    """``compute()`` on global rank 0; every rank returns its (picklable) result. Every rank must call it."""
    result = compute() if trainer.is_global_zero else None
    return trainer.strategy.broadcast(result, src=0)


def log_broadcast(pl_module: L.LightningModule, values: dict[str, float]) -> None:
    """Log epoch-level ``values`` that ``on_rank_zero`` made identical on every rank."""
    if dist.is_available() and dist.is_initialized():
        for key in values:
            warnings.filterwarnings("ignore", message=re.escape(f"It is recommended to use `self.log({key!r}"),
                                    category=PossibleUserWarning)
    pl_module.log_dict(values, on_epoch=True)
