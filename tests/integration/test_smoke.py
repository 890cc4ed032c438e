"""``make smoke`` stays a two-minute run of the whole pipeline, writing only under runs/ and data/.

The smoke config is instantiated with every other config (tests/integration/test_configs.py); here: its training stays
within the step budget its two minutes were measured at, and the Makefile recipe trains on it and deploys
its last checkpoint through ``icprl evaluate`` with an explicit output under the smoke run's directory.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import yaml

from icprl_lightning.commands import run_cli

REPO = Path(__file__).resolve().parents[2]
# make smoke measured at 250 optimizer steps (2 epochs of 4000 contexts): ~90 CPU-seconds in all
MAX_STEPS = 250


def test_the_smoke_config_trains_within_its_step_budget(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    cli = run_cli(["--config", str(REPO / "configs/smoke.yaml"), "--trainer.default_root_dir", str(tmp_path)],
                  run=False)
    dm = cli.datamodule
    contexts = dm.family.n_train_tasks * dm.setting.trajectories_per_task
    steps = math.ceil(contexts / dm.batch_size) * cli.trainer.max_epochs
    assert steps <= MAX_STEPS, f"configs/smoke.yaml trains {steps} steps; make smoke is budgeted for {MAX_STEPS}"
    written = yaml.safe_load((REPO / "configs/smoke.yaml").read_text())
    assert dm.root_dir.startswith("data/") and written["trainer"]["default_root_dir"].startswith("runs/")  # ignored


def test_make_smoke_trains_then_deploys_under_its_run_directory():
    recipe = subprocess.run(["make", "-n", "-C", str(REPO), "smoke"], capture_output=True, text=True,
                            check=True).stdout
    fit, evaluate = recipe.index("icprl fit --config configs/smoke.yaml"), recipe.index("icprl evaluate")
    assert fit < evaluate, recipe
    deploy = recipe[evaluate:]
    assert "--run ICPO=configs/smoke.yaml:$ckpt" in deploy and "--out $run/evaluation" in deploy, deploy
    assert "run=runs/smoke/" in recipe, recipe
