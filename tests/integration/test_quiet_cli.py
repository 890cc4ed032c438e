"""Quiet by default: no hardware banner or model summary without ``--verbose``, no colour codes in a log, and the
first mistakes of a new user (no config, a mistyped config or shipped-model name) answered at once, with the
closest match."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from lightning.pytorch.callbacks import ModelSummary

from icprl_lightning import commands as icprl_cli
from icprl_lightning.commands.config_hints import closest_config, config_problem
from icprl_lightning.hub import resolve

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def at_the_repository(monkeypatch):
    monkeypatch.chdir(REPO)


def test_no_config_says_how_to_start_and_a_mistyped_one_gets_the_closest():
    assert "start with `icprl fit --config configs/smoke.yaml`" in config_problem("fit", [])
    assert config_problem("fit", ["--config", "configs/icpo_darkrom.yaml"]) == (
        "--config configs/icpo_darkrom.yaml: no such file (did you mean 'configs/icpo_darkroom.yaml'?)")
    assert closest_config("configs/paper/icpo_metaword.yaml") == "configs/paper/icpo_metaworld.yaml"
    assert config_problem("fit", ["--config=configs/smoke.yaml"]) is None
    assert config_problem("fit", ["-c", "configs/smoke.yaml"]) is None
    assert "did you mean 'configs/smoke.yaml'" in config_problem("validate", ["-c", "configs/smoke.yml"])
    assert config_problem("fit", ["--help"]) is None
    assert config_problem("fit", ["--model", "x", "--data", "y"]) is None  # all on the command line: Lightning's


def test_a_config_error_is_one_line_before_lightning_is_imported():
    code = ("import sys\nfrom icprl_lightning.commands import main\ntry:\n"
            "    main(['fit', '--config', 'configs/smok.yaml'])\nexcept SystemExit as e:\n"
            "    print(e.code, 'lightning' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.stdout.strip() == "2 False", out
    assert out.stderr == ("icprl fit: error: --config configs/smok.yaml: no such file (did you mean "
                          "'configs/smoke.yaml'?)\n")


def test_an_unknown_shipped_model_gets_the_closest_name():
    with pytest.raises(FileNotFoundError, match=r"'bandit-icp' .*\(did you mean 'bandit-icpo'\?\); shipped models"):
        resolve("bandit-icp")


def _banner_shown(verbose: bool) -> bool:
    logger = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    before = list(logger.filters)
    try:
        icprl_cli._quiet_dependency_noise(verbose)
        record = logger.makeRecord(logger.name, logging.INFO, __file__, 0, "GPU available: False, used: False",
                                   None, None)
        return bool(logger.filter(record))
    finally:
        logger.filters[:] = before


def test_the_hardware_banner_is_shown_with_verbose_only():
    assert not _banner_shown(verbose=False)
    assert _banner_shown(verbose=True)


def test_the_model_summary_is_shown_with_verbose_only(tmp_path, monkeypatch):
    args = ["--config", "configs/smoke.yaml", "--trainer.default_root_dir", str(tmp_path),
            "--data.init_args.root_dir", str(tmp_path / "data")]
    monkeypatch.delenv(icprl_cli.VERBOSE_ENV, raising=False)
    quiet = icprl_cli.run_cli(args, run=False).trainer
    monkeypatch.setenv(icprl_cli.VERBOSE_ENV, "1")
    verbose = icprl_cli.run_cli(args, run=False).trainer
    monkeypatch.delenv(icprl_cli.VERBOSE_ENV)
    flag = icprl_cli.run_cli(args, run=False, verbose=True).trainer  # what icprl --verbose passes
    assert not [c for c in quiet.callbacks if isinstance(c, ModelSummary)]
    assert [c for c in verbose.callbacks if isinstance(c, ModelSummary)]
    assert [c for c in flag.callbacks if isinstance(c, ModelSummary)]


@pytest.mark.slow  # a short fit with W&B offline
def test_a_fit_logged_to_a_file_has_no_colour_codes(tmp_path):
    env = {**os.environ, "WANDB_MODE": "offline", "OMP_NUM_THREADS": "1"}
    env.pop(icprl_cli.VERBOSE_ENV, None)
    out = subprocess.run(
        [sys.executable, "-m", "icprl_lightning", "fit", "--config", "configs/smoke.yaml",
         "--trainer.default_root_dir", str(tmp_path), "--trainer.logger=lightning.pytorch.loggers.WandbLogger",
         "--trainer.logger.init_args.save_dir", str(tmp_path), "--trainer.logger.init_args.project", "icprl",
         "--trainer.max_steps", "2", "--trainer.limit_val_batches", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=600, cwd=REPO, env=env)
    assert out.returncode == 0, out.stdout[-3000:]
    assert "wandb sync" in out.stdout and "\x1b[" not in out.stdout, out.stdout[-3000:]
    assert "GPU available" not in out.stdout and "Trainable params" not in out.stdout, out.stdout[-3000:]
