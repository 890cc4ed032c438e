"""``TrainingClock``: training seconds without validation, logged at every validation (learning_speed.py reads it)."""

from __future__ import annotations

import time

import lightning as L
from lightning.pytorch.demos.boring_classes import BoringModel

from icprl_lightning.callbacks.training_clock import TrainingClock


class SlowValidation(BoringModel):
    def validation_step(self, batch, batch_idx):
        time.sleep(0.25)  # validation time the clock must leave out
        return super().validation_step(batch, batch_idx)


def test_the_clock_counts_training_steps_and_leaves_validation_out(tmp_path):
    seen = []

    class Record(L.Callback):
        def on_validation_end(self, trainer, pl_module):
            if not trainer.sanity_checking:
                seen.append({k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("time/")})

    trainer = L.Trainer(max_steps=8, val_check_interval=4, limit_val_batches=4, logger=False,
                        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0, callbacks=[TrainingClock(), Record()], default_root_dir=tmp_path)
    trainer.fit(SlowValidation())
    assert [s["time/optimizer_steps"] for s in seen] == [4.0, 8.0]
    first, second = seen
    assert 0 < first["time/train_seconds"] < second["time/train_seconds"]
    assert first["time/validation_seconds"] == 0.0 and second["time/validation_seconds"] >= 4 * 0.25
    # 8 steps of a tiny model take well under the first validation's 1 s of sleeping, which a clock that
    # counted validation would include in the second reading
    assert second["time/train_seconds"] < 0.8
