"""Every method's optimizer: AdamW as ``models/config.OptimizerConfig`` says, its learning rate constant (the
paper's Adam at a fixed rate, the default) or ``cosine`` — a linear warm-up over ``warmup_steps`` optimizer steps
from 0 to ``lr``, then a half cosine from ``lr`` down to 0 at the fit's last step (Loshchilov & Hutter's SGDR
without restarts, with the warm-up of Goyal et al.):

    lr_t = lr · t / w                                                  for t < w
    lr_t = lr · ½ (1 + cos(π · (t − w) / (T − w)))                     for w ≤ t ≤ T

where w = ``warmup_steps`` and T = the trainer's ``estimated_stepping_batches`` (its ``max_steps``, or
``max_epochs`` × the batches per epoch). The factor is a pure function of the optimizer step, so a resumed fit
continues the same curve (Lightning restores the scheduler's step count from the checkpoint; the closure itself
is not saved, so a checkpoint holds no code).
"""

from __future__ import annotations

import math

import lightning as L
import torch

from icprl_lightning.models.config import OptimizerConfig


def warmup_cosine_factor(step: int, warmup_steps: int, total_steps: int) -> float:
    """The fraction of the base learning rate at optimizer step ``step`` (0-based; see the module docstring)."""
    if step < warmup_steps:
        return (step + 1) / warmup_steps
    span = max(total_steps - warmup_steps, 1)
    progress = min((step - warmup_steps) / span, 1.0)
    return 0.5 * (1.0 + math.cos(math.pi * progress))


def configure_adamw(module: L.LightningModule, config: OptimizerConfig):
    """What ``configure_optimizers`` returns: AdamW on every parameter of ``module``, alone (``constant``) or with its
    per-step scheduler; only ``cosine`` reads the fit's step count (a constant-rate module needs no trainer)."""
    optimizer = torch.optim.AdamW(module.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    schedule, warmup_steps = config.lr_schedule, config.warmup_steps
    if schedule == "constant":
        return optimizer
    total_steps = int(module.trainer.estimated_stepping_batches)
    if total_steps <= warmup_steps:
        raise ValueError(f"lr_schedule 'cosine': warmup_steps ({warmup_steps}) must be fewer than the fit's "
                         f"optimizer steps ({total_steps}: trainer.max_steps, or max_epochs × batches per epoch)")
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: warmup_cosine_factor(step, warmup_steps, total_steps))
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
