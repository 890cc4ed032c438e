"""The learning-rate schedule (methods/schedule.py): the warm-up + cosine curve by hand, the rate a real fit
steps with, a resumed fit continuing the same curve, and clear errors for a wrong name or too long a warm-up."""

import math

import lightning as L
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint

from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.schedule import warmup_cosine_factor
from icprl_lightning.models.config import OptimizerConfig, TransformerConfig
from icprl_lightning.validation import HyperparameterError

pytestmark = pytest.mark.usefixtures("one_thread")

ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100,
           backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2), pair_source="other_trajectory")
COSINE = OptimizerConfig(lr=0.01, lr_schedule="cosine", warmup_steps=2)


def test_the_factor_ramps_up_then_follows_half_a_cosine_to_zero():
    assert [warmup_cosine_factor(t, 4, 12) for t in range(4)] == [0.25, 0.5, 0.75, 1.0]
    assert warmup_cosine_factor(4, 4, 12) == 1.0
    assert warmup_cosine_factor(8, 4, 12) == pytest.approx(0.5)
    assert warmup_cosine_factor(6, 4, 12) == pytest.approx(0.5 * (1 + math.cos(math.pi / 4)))
    assert warmup_cosine_factor(12, 4, 12) == pytest.approx(0.0)
    assert warmup_cosine_factor(50, 4, 12) == pytest.approx(0.0)  # past the end: stays at 0
    assert warmup_cosine_factor(0, 0, 10) == 1.0  # no warm-up


class RecordLR(L.Callback):
    def __init__(self):
        self.rates: dict[int, float] = {}

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        self.rates[trainer.global_step] = trainer.optimizers[0].param_groups[0]["lr"]


def _trainer(steps, *callbacks, **kw):
    return L.Trainer(max_steps=steps, limit_val_batches=0, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, callbacks=list(callbacks), **kw)


def test_a_fit_steps_on_the_curve_and_a_resumed_fit_continues_it(tiny_ipref, tmp_path):
    torch.manual_seed(0)
    record = RecordLR()
    saver = ModelCheckpoint(dirpath=tmp_path, every_n_train_steps=3, save_top_k=-1, filename="{step}")
    _trainer(8, record, saver).fit(ICPOModule(**ENV, optimizer=COSINE), datamodule=tiny_ipref)
    expected = {t: 0.01 * warmup_cosine_factor(t, 2, 8) for t in range(8)}
    assert record.rates == pytest.approx(expected)

    resumed = RecordLR()
    _trainer(8, resumed, enable_checkpointing=False).fit(
        ICPOModule(**ENV, optimizer=COSINE), datamodule=tiny_ipref,
        ckpt_path=tmp_path / "step=3.ckpt", weights_only=False)
    assert resumed.rates == pytest.approx({t: expected[t] for t in range(3, 8)})


def test_the_default_is_the_constant_rate(tiny_ipref):
    record = RecordLR()
    _trainer(3, record, enable_checkpointing=False).fit(ICPOModule(**ENV, optimizer={"lr": 0.01}),
                                                        datamodule=tiny_ipref)
    assert record.rates == pytest.approx({0: 0.01, 1: 0.01, 2: 0.01})


def test_a_wrong_schedule_or_a_warm_up_longer_than_the_fit_is_a_clear_error(tiny_ipref):
    with pytest.raises(HyperparameterError, match="lr_schedule"):
        ICPOModule(**ENV, optimizer={"lr_schedule": "linear"})
    with pytest.raises(HyperparameterError, match="warmup_steps"):
        ICPOModule(**ENV, optimizer={"lr_schedule": "cosine", "warmup_steps": -1})
    with pytest.raises(ValueError, match=r"warmup_steps \(5\) must be fewer than the fit's optimizer steps \(4"):
        _trainer(4, enable_checkpointing=False).fit(
            ICPOModule(**ENV, optimizer={"lr_schedule": "cosine", "warmup_steps": 5}), datamodule=tiny_ipref)
