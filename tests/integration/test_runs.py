"""Run directories and resume: every ``fit`` writes only under its own run directory, a pipeline stage takes
the previous stage's checkpoint by path, and a killed run resumed from its last checkpoint ends where an
uninterrupted one does.

- two fits of one config in one working directory (logger off, W&B logger, CSV logger) get two run
  directories, and the working directory gains nothing but the data directory the test names;
- RewardGen → ICRG (configs/reward_gen_darkroom.yaml then configs/icrg_darkroom.yaml) with the logger off
  and on, stage 2 started from another working directory with the path stage 1 printed;
- ``kill -9`` of ``icprl fit`` after its first checkpoint, then ``--ckpt_path <last.ckpt>``: the same final
  global step, weights and val/loss as the uninterrupted run of the same seed.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from factories import TINY_DATA, TINY_MODEL

from icprl_lightning.commands import run_cli

REPO = Path(__file__).resolve().parents[2]
LOGGERS = {
    "off": lambda out: ["--trainer.logger", "false", "--trainer.default_root_dir", str(out)],
    "wandb": lambda out: ["--trainer.logger.init_args.save_dir", str(out)],  # the configs' WandbLogger
    "csv": lambda out: ["--trainer.logger", "lightning.pytorch.loggers.CSVLogger",
                        "--trainer.logger.init_args.save_dir", str(out)],
}


@pytest.fixture(autouse=True)
def _wandb_disabled(monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "disabled")


def _listing(path: Path) -> list[str]:
    return sorted(p.relative_to(path).as_posix() for p in path.rglob("*"))


def _printed(text: str, what: str) -> str:
    """The path a run printed as ``<what>: <path>`` or ``<what> (<details>): <path>`` (RunDirectory: run
    directory, best checkpoint; LastCheckpoint: last checkpoint)."""
    found = re.findall(rf"^{what}(?: \([^)]*\))?: (\S+)$", text, re.MULTILINE)
    assert len(found) == 1, (what, text[-2000:])
    return found[0]


@pytest.mark.parametrize("logger", list(LOGGERS))
def test_two_runs_of_one_config_get_two_run_directories(logger, tmp_path, monkeypatch, capsys):
    cwd, out = tmp_path / "cwd", tmp_path / "out"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    before = _listing(cwd)
    run_dirs = []
    for _ in range(2):
        run_cli(["fit", "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--data.init_args.root_dir", "data",
                 *TINY_DATA, *TINY_MODEL, "--trainer.max_steps", "2", *LOGGERS[logger](out)])
        printed = capsys.readouterr().out
        run_dir = Path(_printed(printed, "run directory"))
        assert out in run_dir.parents, (run_dir, out)
        assert (run_dir / "config.yaml").is_file()
        last = Path(_printed(printed, "last checkpoint"))
        assert last == run_dir / "checkpoints" / "last.ckpt" and last.is_file()
        run_dirs.append(run_dir)
    assert run_dirs[0] != run_dirs[1]
    # nothing but the data directory landed in the working directory: no config.yaml, checkpoints/, wandb/
    after = [p for p in _listing(cwd) if p != "data" and not p.startswith("data/")]
    assert after == before
    assert len([p for p in (cwd / "data").iterdir() if p.name.startswith("darkroom")]) == 1
    # each run directory holds its own config and checkpoint, none overwritten by the other run
    for run_dir in run_dirs:
        assert yaml.safe_load((run_dir / "config.yaml").read_text())["model"]["init_args"]["backbone"]["n_embd"] == 16


def test_fast_dev_run_leaves_nothing_in_the_working_directory(tmp_path, monkeypatch, capsys):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    run_cli(["fit", "--config", str(REPO / "configs/icpo_darkroom.yaml"), "--data.init_args.root_dir",
             str(tmp_path / "data"), *TINY_DATA, *TINY_MODEL, "--trainer.fast_dev_run", "1", "--trainer.logger",
             "false", "--trainer.default_root_dir", str(tmp_path / "out")])
    assert _listing(cwd) == []  # Lightning's save_last still writes under fast_dev_run: into the run dir
    assert (tmp_path / "out") in Path(_printed(capsys.readouterr().out, "run directory")).parents


@pytest.mark.parametrize("logger", ["off", "wandb"])
def test_icrg_pipeline_takes_stage_one_checkpoint_by_path(logger, tmp_path, monkeypatch, capsys):
    data, out = tmp_path / "data", tmp_path / "out"
    common = ["--data.init_args.root_dir", str(data), *TINY_DATA, *TINY_MODEL, "--trainer.max_steps", "2",
              "--trainer.limit_train_batches", "2", *LOGGERS[logger](out)]
    for name in ("stage1", "stage2"):
        (tmp_path / name).mkdir()
    monkeypatch.chdir(tmp_path / "stage1")
    run_cli(["fit", "--config", str(REPO / "configs/reward_gen_darkroom.yaml"), *common])
    printed = capsys.readouterr().out
    best = Path(_printed(printed, "best checkpoint"))
    assert best.name == "best.ckpt" and best.parent == Path(_printed(printed, "run directory")) / "checkpoints"
    # stage 2 from another working directory, with the path stage 1 printed
    monkeypatch.chdir(tmp_path / "stage2")
    cli = run_cli(["fit", "--config", str(REPO / "configs/icrg_darkroom.yaml"), *common,
                   "--model.init_args.reward_gen_checkpoint", str(best)])
    assert cli.trainer.state.finished and cli.trainer.global_step == 2
    assert cli.model.hparams.reward_gen_hparams["backbone"]["n_embd"] == 16
    stage2 = Path(_printed(capsys.readouterr().out, "run directory"))
    assert stage2 != best.parent.parent and (stage2 / "config.yaml").is_file()
    assert _listing(tmp_path / "stage1") == [] and _listing(tmp_path / "stage2") == []


def test_icrg_without_a_stage_one_checkpoint_says_what_to_pass(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="needs reward_gen_checkpoint"):
        run_cli(["--config", str(REPO / "configs/icrg_darkroom.yaml"), "--data.init_args.root_dir",
                 str(tmp_path / "data"), *TINY_DATA, *TINY_MODEL, "--trainer.logger", "false"], run=False)


# ---- kill and resume ---------------------------------------------------------------------------------

STEPS_PER_EPOCH, EPOCHS = 4, 8  # last.ckpt at the end of every epoch (LastCheckpoint, a default callback)


def _resume_config(tmp_path: Path) -> Path:
    """configs/icpo_darkroom.yaml with only the default callbacks (last.ckpt at every epoch's end), no logger."""
    config = yaml.safe_load((REPO / "configs/icpo_darkroom.yaml").read_text())
    config["trainer"].update(logger=False, max_epochs=EPOCHS, limit_train_batches=STEPS_PER_EPOCH,
                             enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0)
    config.update(evaluation=None, best_checkpoint=None)
    path = tmp_path / "icpo_resume.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def _fit_command(config: Path, data: Path, root: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "icprl_lightning", "fit", "--config", str(config), "--data.init_args.root_dir",
            str(data), *TINY_DATA, *TINY_MODEL, "--trainer.default_root_dir", str(root), *extra]


def _val_loss(config: Path, data: Path, ckpt: Path) -> float:
    cli = run_cli(["validate", "--config", str(config), "--data.init_args.root_dir", str(data), *TINY_DATA,
                   *TINY_MODEL, "--ckpt_path", str(ckpt)])
    return float(cli.trainer.callback_metrics["val/loss"])


@pytest.mark.slow
def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config, data = _resume_config(tmp_path), tmp_path / "data"
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONUNBUFFERED": "1"}
    # the uninterrupted run (it also generates the dataset the other two reuse)
    full = subprocess.run(_fit_command(config, data, tmp_path / "full"), capture_output=True, text=True, env=env,
                          timeout=600)
    assert full.returncode == 0, full.stderr[-3000:]
    full_last = Path(_printed(full.stdout, "last checkpoint"))

    # the same run, killed with SIGKILL once its first checkpoint is on disk
    log = (tmp_path / "killed.log").open("w")
    proc = subprocess.Popen(_fit_command(config, data, tmp_path / "killed"), stdout=log, stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)
    deadline = time.monotonic() + 300
    last = None
    while time.monotonic() < deadline and proc.poll() is None:
        found = list((tmp_path / "killed").glob("*/checkpoints/last.ckpt"))
        if found:
            last = found[0]
            break
        time.sleep(0.02)
    assert last is not None and proc.poll() is None, "the run ended before it could be killed"
    time.sleep(0.3)  # mid-training, past the first checkpoint
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    log.close()
    assert proc.returncode == -signal.SIGKILL
    killed_step = torch.load(last, map_location="cpu", weights_only=True)["global_step"]  # complete, loadable
    assert 0 < killed_step < STEPS_PER_EPOCH * EPOCHS, killed_step

    # resume from the killed run's last.ckpt (a fresh run directory) to the end
    resumed = subprocess.run(_fit_command(config, data, tmp_path / "resumed", "--ckpt_path", str(last)),
                             capture_output=True, text=True, env=env, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    resumed_last = Path(_printed(resumed.stdout, "last checkpoint"))
    assert resumed_last.parent.parent != last.parent.parent  # its own run directory

    a, b = (torch.load(p, map_location="cpu", weights_only=False) for p in (full_last, resumed_last))
    assert a["global_step"] == b["global_step"] == STEPS_PER_EPOCH * EPOCHS
    assert a["epoch"] == b["epoch"]
    # deterministic CPU training: the same batches and pair draws in the same order (RunDirectory stores and
    # restores the RNG states, and validation runs RNG-isolated) give the same weights; measured: identical.
    # Tolerance 1e-5 (absolute and relative) on every weight, 1e-4 relative on val/loss.
    for key, value in a["state_dict"].items():
        torch.testing.assert_close(b["state_dict"][key], value, rtol=1e-5, atol=1e-5, msg=key)
    full_loss, resumed_loss = _val_loss(config, data, full_last), _val_loss(config, data, resumed_last)
    assert resumed_loss == pytest.approx(full_loss, rel=1e-4, abs=1e-5), (full_loss, resumed_loss)


@pytest.mark.parametrize("config", sorted(p.relative_to(REPO).as_posix() for p in REPO.glob("configs/**/*.yaml")))
def test_no_config_pins_a_shared_directory(config):
    """No checkpoint ``dirpath`` (it would be shared by every run of the config, relative to the working
    directory), no W&B ``offline: true`` (Lightning makes it override WANDB_MODE=disabled), and no default
    RewardGen path for ICRG (stage 2 names stage 1's checkpoint explicitly)."""
    written = yaml.safe_load((REPO / config).read_text())
    trainer = written.get("trainer", {})
    for callback in trainer.get("callbacks") or []:
        assert "dirpath" not in (callback.get("init_args") or {}), config
    logger = trainer.get("logger")
    assert not (isinstance(logger, dict) and (logger.get("init_args") or {}).get("offline")), config
    assert (written.get("model", {}).get("init_args") or {}).get("reward_gen_checkpoint") is None, config
