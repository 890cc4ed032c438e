"""What every in-context method shares: the policy network T_θ(a | s, D), the optimizer, deployment.

A method subclass defines ``loss(batch) -> (loss, metrics)`` — its training objective from the paper, read off
the typed samples of ``samples.py`` — and inherits logging, Adam, checkpoint metadata for ``load_agent`` and
``make_agent``. The environment's sizes (``state_dim``, ``action_dim``, ``discrete``, ``max_context``) are linked
from the DataModule by the CLI, so a config names them once; the network's sizes come whole as ``backbone`` and the
optimizer's settings as ``optimizer`` (``models/config.py``), passed on by keyword.
"""

from __future__ import annotations

import inspect

import lightning as L
import torch
from torch import Tensor

from icprl_lightning.contexts import ActionSpec, Context
from icprl_lightning.methods.schedule import configure_adamw
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.normalization import InputNormalizer
from icprl_lightning.models.policy import LAYOUTS, InContextPolicy
from icprl_lightning.samples import Samples
from icprl_lightning.validation import (
    check_bool,
    check_choice,
    check_int,
    check_kind,
    check_sizes,
)


def save_groups(module: L.LightningModule, backbone: TransformerConfig,
                optimizer: OptimizerConfig) -> tuple[TransformerConfig, OptimizerConfig]:
    """Save ``module``'s constructor arguments as its hyperparameters, the backbone and the optimizer as plain dicts
    (a checkpoint is read without unpickling any class, ``checkpoints.py``); returns them as their dataclasses
    (given as one, or as the dict a checkpoint holds)."""
    groups = TransformerConfig.coerce(backbone), OptimizerConfig.coerce(optimizer)
    module.save_hyperparameters(frame=inspect.currentframe().f_back)
    module.save_hyperparameters({**module.hparams, **{g.group: g.as_dict() for g in groups}})
    return groups


class MethodModule(L.LightningModule):
    """What every method shares (``InContextModule``, ``RewardGenModule``): the checks and statistics of a fit's
    start, AdamW as its ``optimizer`` group says (``methods/schedule.py``), the checkpoint's class and checksum."""

    optimizer_config: OptimizerConfig

    def on_fit_start(self) -> None:
        """Checks this model against the data it is fitted on (``validation.check_pairing``: what ``icprl fit``
        checks, here for a fit without the CLI too), then fits every input normalizer not fitted yet on what the
        data hands over for it: the training split's arrays of the fields its batches serve
        (``PreferenceData.train_arrays``; so a preference method never sees the scale of a stored reward). Once: a
        resumed or fine-tuned fit, or a frozen stage loaded from its checkpoint, keeps its statistics. Every rank
        reads the whole split, so all agree."""
        from icprl_lightning.data_contract import PreferenceData
        from icprl_lightning.validation import check_pairing

        data = self.trainer.datamodule
        if isinstance(data, PreferenceData):
            check_pairing(self, data)
        normalizers = [m for m in self.modules() if isinstance(m, InputNormalizer) and not m.fitted]
        if normalizers and not isinstance(data, PreferenceData):
            raise ValueError(f"{type(self).__name__}: normalize_inputs fits its statistics on the training arrays a "
                             "DataModule of the data contract hands over (icprl_lightning.data_contract."
                             f"PreferenceData.train_arrays), and this fit's DataModule is {type(data).__name__}")
        split = data.train_arrays() if normalizers else None
        for normalizer in normalizers:
            normalizer.fit(split)

    def configure_optimizers(self):
        return configure_adamw(self, self.optimizer_config)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """The class ``load_agent`` rebuilds and the checksum it verifies (``checkpoints.py``)."""
        from icprl_lightning.checkpoints import stamp

        stamp(self, checkpoint)


class InContextModule(MethodModule):
    """Base LightningModule of DPT, DP²T and ICPO (see the module docstring).

    ``consumes``: the context kinds of the data it trains on (by default its ``context_kind``); the CLI
    checks it against the DataModule's ``context_kind`` before any data is generated. ``needs_pairs`` /
    ``needs_query_labels``: the DataModule flags its loss reads.
    """

    needs_pairs = False
    needs_query_labels = False

    def __init__(self, context_kind: str, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 backbone: TransformerConfig = DEFAULT_BACKBONE, optimizer: OptimizerConfig = DEFAULT_OPTIMIZER,
                 queries_per_context: int | None = None, normalize_inputs: bool = False,
                 layout: str = "appended") -> None:
        owner = type(self).__name__
        check_kind(owner, "context_kind", context_kind)
        check_sizes(owner, state_dim, action_dim)
        check_bool(owner, "discrete", discrete)
        check_int(owner, "max_context", max_context, 1)
        if queries_per_context is not None:
            check_int(owner, "queries_per_context", queries_per_context, 1)
        check_bool(owner, "normalize_inputs", normalize_inputs)
        check_choice(owner, "layout", layout, LAYOUTS)
        super().__init__()
        # kept on the module, not read back from hparams: a subclass's constructor (a user's method) need not
        # re-declare every argument of this one for save_hyperparameters to record it
        self.backbone, self.optimizer_config = save_groups(self, backbone, optimizer)
        self.queries_per_context = queries_per_context
        self.context_kind = context_kind
        self.action_spec = ActionSpec(discrete=discrete, size=action_dim)
        self.policy = InContextPolicy(context_kind, state_dim, self.action_spec, self.backbone, max_context,
                                      normalize_inputs, layout)

    @property
    def consumes(self) -> tuple[str, ...]:
        """The context kinds of the training data (the policy's own context kind)."""
        return (self.context_kind,)

    def forward(self, context: Context, query_states: Tensor, visible: Tensor) -> Tensor:
        return self.policy(context, query_states, visible)

    def query_positions(self, length: int, device: torch.device) -> Tensor:
        """The query positions a step scores, sorted: all ``length`` of them, or in training
        ``queries_per_context`` of them drawn without replacement (the same for the whole batch, new each step).

        Query t sees the first t + 1 context tokens, so the drawn positions still cover context sizes 1..H,
        and the sequence is H + k tokens instead of 2H (``benchmarks/training_throughput.py`` measures the
        gain). Validation always scores all H, so ``val/loss`` does not depend on k.
        """
        k = self.queries_per_context
        if k is None or k >= length or not self.training:
            return torch.arange(length, device=device)
        return torch.randperm(length, device=device)[:k].sort().values

    def loss(self, batch: Samples) -> tuple[Tensor, dict[str, Tensor]]:
        raise NotImplementedError

    def training_step(self, batch: Samples, batch_idx: int) -> Tensor:
        loss, metrics = self.loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.batch_size)
        self.log_dict({f"train/{k}": v for k, v in metrics.items()}, batch_size=batch.batch_size)
        return loss

    def validation_step(self, batch: Samples, batch_idx: int) -> None:
        loss, metrics = self.loss(batch)
        # sync_dist: under several processes the epoch's value is the batch-weighted mean over every rank's
        # shard (one all-reduce per metric at the epoch's end), so ModelCheckpoint sees the same val/loss on
        # each rank; a no-op in one process. Train metrics are per step and stay rank 0's own.
        self.log("val/loss", loss, prog_bar=True, sync_dist=True, batch_size=batch.batch_size)
        self.log_dict({f"val/{k}": v for k, v in metrics.items()}, sync_dist=True, batch_size=batch.batch_size)

    def make_agent(self, greedy: bool = True, use_cache: bool = True, seed: int | None = None, compile: bool = False):
        from icprl_lightning.deploy import Agent

        return Agent(self.policy, greedy=greedy, use_cache=use_cache, seed=seed, compile=compile)
