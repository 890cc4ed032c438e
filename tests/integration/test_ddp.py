"""Two CPU processes on Lightning's DDP (gloo): disjoint shards, synced validation, rank-0 rollouts and files.

``icprl fit --trainer.strategy ddp --trainer.devices 2`` runs in a subprocess (Lightning's launcher starts
the second rank by running the same command again) with ``RowRecorder`` added to the config's callbacks:
each rank writes the rows it drew per epoch and the metrics it saw to ``rank<r>.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import pytest
from factories import tiny_darkroom_args

from icprl_lightning import load_agent

REPO = Path(__file__).resolve().parents[2]
ROWS, BATCH = 80 * 3, 40  # tiny DarkRoom: 80 training tasks × 3 contexts; 120 rows a rank = 3 whole batches


class RowRecorder(L.Callback):
    """Writes ``<out_dir>/rank<r>.json``: the row indices of every training batch, per epoch, and the
    validation metrics this rank saw. Rows are read where the loader takes them, from its batch sampler."""

    def __init__(self, out_dir: str) -> None:
        self.out_dir = out_dir
        self.epochs: list[list[int]] = []
        self.val: list[dict[str, float]] = []

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        datamodule, make_loader, epochs = trainer.datamodule, trainer.datamodule.train_dataloader, self.epochs

        def recorded_loader():  # before Lightning's fit loop makes the first epoch's iterator
            loader = make_loader()

            class Recording(type(loader.sampler)):
                def __iter__(self):
                    epochs.append([])  # one pass of the batch sampler per epoch
                    for batch in super().__iter__():
                        epochs[-1].extend(int(i) for i in batch)
                        yield batch

            loader.sampler.__class__ = Recording
            return loader

        datamodule.train_dataloader = recorded_loader

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self.val.append({k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")})

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        record = {"world_size": trainer.world_size, "epochs": self.epochs, "val": self.val}
        Path(self.out_dir, f"rank{trainer.global_rank}.json").write_text(json.dumps(record))


@pytest.mark.slow
def test_two_processes_shard_the_epoch_and_write_one_run(tmp_path):
    record_dir = tmp_path / "ranks"
    record_dir.mkdir()
    recorder = {"class_path": "test_ddp.RowRecorder", "init_args": {"out_dir": str(record_dir)}}
    command = [sys.executable, "-m", "icprl_lightning", "fit", "--config", str(REPO / "configs/icpo_darkroom.yaml"),
               "--trainer.accelerator", "cpu", "--trainer.strategy", "ddp", "--trainer.devices", "2",
               "--trainer.max_epochs", "2", "--trainer.enable_progress_bar", "false",
               "--trainer.default_root_dir", str(tmp_path),
               "--trainer.logger", "lightning.pytorch.loggers.CSVLogger",
               "--trainer.logger.save_dir", str(tmp_path / "runs"),
               f"--trainer.callbacks+={json.dumps(recorder)}",
               "--data.init_args.batch_size", str(BATCH), *tiny_darkroom_args(tmp_path / "data")]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "WANDB_MODE": "disabled",
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parent), str(REPO / "tests"),
                                          os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=180)
    assert proc.returncode == 0, proc.stderr[-3000:]

    ranks = [json.loads((record_dir / f"rank{r}.json").read_text()) for r in (0, 1)]
    assert [r["world_size"] for r in ranks] == [2, 2]
    for epoch in range(2):
        shards = [r["epochs"][epoch] for r in ranks]
        assert [len(s) for s in shards] == [ROWS // 2, ROWS // 2]
        assert not set(shards[0]) & set(shards[1])  # disjoint
        assert sorted(shards[0] + shards[1]) == list(range(ROWS))  # together: every row once
    assert ranks[0]["epochs"][0] != ranks[0]["epochs"][1]  # set_epoch reached the sampler: a new shuffle

    # validation: val/loss reduced over both shards, rollouts (rank 0's) logged on both ranks, equal
    for epoch in range(2):
        seen = [r["val"][epoch] for r in ranks]
        assert {"val/loss", "val/darkroom/high/return"} <= seen[0].keys()
        assert seen[0] == seen[1]

    runs = sorted(p.parent for p in (tmp_path / "runs").rglob("config.yaml"))  # one run directory, one config
    assert len(runs) == 1, sorted((tmp_path / "runs").rglob("*"))
    run = runs[0]
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"val/loss", "val/darkroom/high/return"} <= set(header)
    agent = load_agent(run / "checkpoints" / "last.ckpt")
    assert agent is not None
