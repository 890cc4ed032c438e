"""Slow learning test: ICPO, trained from preferences alone on a tiny budget, beats the behavior policy."""

import lightning as L
import numpy as np
import pytest
import torch
from factories import darkroom_data  # noqa: E402

from icprl_lightning.callbacks.rollout import InContextRolloutCallback
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig


@pytest.mark.slow
def test_icpo_beats_the_behavior_policy_on_held_out_goals(tmp_path):
    L.seed_everything(0)
    dm = darkroom_data(root_dir=str(tmp_path), trajectories_per_task=12, val_trajectories_per_task=2,
                            eval_contexts_per_task=3, calibration_episodes=10, pairs=True, batch_size=32,
                            progress=False)
    # β and λ of configs/icpo_darkroom.yaml (the β × λ sweep's pick)
    model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100,
                       backbone=TransformerConfig(n_layer=2, n_embd=64, n_head=4),
                       optimizer={"lr": 1e-3}, beta=0.1, lam=1.0)
    rollout = InContextRolloutCallback(seed=0, diagnostics=["flipped_labels", "random_labels", "other_task"])
    # 960 contexts / 32 = 30 steps an epoch: about 400 optimizer steps, validated (and rolled out) once at the end
    trainer = L.Trainer(max_epochs=13, check_val_every_n_epoch=13, limit_val_batches=1, logger=False,
                        enable_checkpointing=False, enable_progress_bar=False, callbacks=[rollout],
                        default_root_dir=tmp_path)
    torch.set_num_threads(2)
    trainer.fit(model, datamodule=dm)
    results = rollout.last_results
    for quality in ("low", "medium", "high"):
        r = results[f"val/darkroom/{quality}"]
        assert np.isfinite(r["return"])
        assert r["return"] > r["behavior_return"], (quality, r)
        # the diagnostics ran on the same episodes; another goal's context leaves the policy lost
        diagnosed = {f"val/darkroom/{quality}/{d}" for d in ("flipped_labels", "random_labels", "other_task")}
        assert diagnosed <= set(results)
        assert results[f"val/darkroom/{quality}/other_task"]["return"] < r["return"], (quality, results)


def test_rollout_callback_names_a_wrong_diagnostic():
    with pytest.raises(ValueError, match="diagnostics must be among"):
        InContextRolloutCallback(diagnostics=["labels_flipped"])
