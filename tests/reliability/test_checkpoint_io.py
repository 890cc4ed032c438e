"""Atomic checkpoints whatever the plugins (``callbacks/atomic_io.use_atomic_saves``): ``AsyncCheckpointIO`` saves
through the atomic writer, any other checkpoint IO is refused in one line; every ``trainer.precision`` either
trains on CPU or is refused in one line before anything is generated (``commands/trainer.PRECISIONS``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
from factories import TINY_DATA, TINY_MODEL
from lightning.pytorch.plugins.io import AsyncCheckpointIO, TorchCheckpointIO

from icprl_lightning.callbacks.atomic_io import AtomicCheckpointIO, use_atomic_saves
from icprl_lightning.commands import main

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[2]


def _trainer(*plugins) -> L.Trainer:
    return L.Trainer(plugins=list(plugins), logger=False, enable_checkpointing=False, enable_progress_bar=False,
                     enable_model_summary=False, accelerator="cpu")


def test_async_checkpoint_io_saves_through_the_atomic_writer(tmp_path):
    trainer = _trainer(AsyncCheckpointIO())
    use_atomic_saves(trainer)
    io = trainer.strategy.checkpoint_io
    assert isinstance(io, AsyncCheckpointIO) and isinstance(io.checkpoint_io, AtomicCheckpointIO)
    elsewhere = tmp_path / "elsewhere.ckpt"
    elsewhere.write_bytes(b"the file a link pointed at")
    target = tmp_path / "last.ckpt"
    target.symlink_to(elsewhere)  # the plain writer writes through it; the atomic one replaces the link
    io.save_checkpoint({"global_step": 3, "w": torch.arange(3.0)}, target)
    io.teardown()  # waits for the saving thread
    assert not target.is_symlink() and elsewhere.read_bytes() == b"the file a link pointed at"
    assert torch.load(target, weights_only=True)["global_step"] == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere.ckpt", "last.ckpt"]


def test_the_default_io_is_replaced_and_a_users_io_is_refused():
    trainer = _trainer()
    use_atomic_saves(trainer)
    assert type(trainer.strategy.checkpoint_io) is AtomicCheckpointIO

    class UsersIO(TorchCheckpointIO):
        pass

    for plugin in (UsersIO(), AsyncCheckpointIO(UsersIO())):
        with pytest.raises(ValueError, match=r"trainer.plugins: UsersIO writes checkpoints its own way, which can "
                                             r"leave a partial last.ckpt"):
            use_atomic_saves(_trainer(plugin))


def _fit(tmp: Path, *extra: str) -> list[str]:
    return ["fit", "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--data.init_args.root_dir", str(tmp / "data"),
            *TINY_DATA, *TINY_MODEL, "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2",
            "--trainer.limit_val_batches", "1", "--trainer.logger", "false", "--trainer.enable_progress_bar", "false",
            "--trainer.default_root_dir", str(tmp / "runs"), *extra]


@pytest.mark.parametrize("precision", ["16-true", "bf16-true", "64-true", "64", "transformer-engine"])
def test_a_precision_that_cannot_train_is_refused_in_one_line_before_any_data(tmp_path, capsys, precision):
    with pytest.raises(SystemExit) as exit_:
        main(_fit(tmp_path, "--trainer.precision", precision))
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"icprl fit: error: trainer.precision '{precision}' is refused: "
                                                   "the batches are float32"), err
    assert not (tmp_path / "data").exists()


@pytest.mark.slow  # three tiny fits in subprocesses, ~15 s each here
@pytest.mark.parametrize("precision", ["32-true", "bf16-mixed", "16-mixed"])
def test_the_accepted_precisions_train_on_cpu_with_async_atomic_saves(tmp_path, precision):
    command = [sys.executable, "-m", "icprl_lightning", *_fit(tmp_path, "--trainer.precision", precision,
                                                                  "--trainer.plugins", "AsyncCheckpointIO")]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    (last,) = (tmp_path / "runs").glob("*/checkpoints/last.ckpt")
    assert not list(last.parent.glob(".*.tmp"))
    main(["checkpoint", "verify", "--resumable", str(last)])
