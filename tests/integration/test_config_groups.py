"""Config groups compose: ``configs/trainer/`` holds the hardware (cpu, gpu, ddp), stacked after any config with
``--trainer FILE``, which changes the hardware and keeps the experiment (epochs, callbacks, logger). What every
config's trainer starts from is the CLI's ``TRAINER_DEFAULTS``, and ``configs/trainer/cpu.yaml`` spells out exactly
that, so the configs no longer copy it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from icprl_lightning.cli import run_cli
from icprl_lightning.trainer_cli import TRAINER_DEFAULTS

REPO = Path(__file__).resolve().parents[2]
CONFIG = str(REPO / "configs/icpo_darkroom.yaml")


def trainer_of(args: list[str], monkeypatch, tmp_path) -> dict:
    monkeypatch.chdir(tmp_path)
    return run_cli(["--config", CONFIG, *args], run=False).config["trainer"]


def test_cpu_yaml_is_the_cli_default():
    assert yaml.safe_load((REPO / "configs/trainer/cpu.yaml").read_text()) == TRAINER_DEFAULTS


def test_no_base_config_copies_the_default_trainer():
    for path in sorted(REPO.glob("configs/*.yaml")):
        trainer = yaml.safe_load(path.read_text()).get("trainer", {})
        copied = {k for k, v in TRAINER_DEFAULTS.items() if trainer.get(k) == v}
        assert not copied, f"{path.name} repeats the CLI's trainer defaults {sorted(copied)}"


def test_every_trainer_group_sets_only_the_hardware():
    """Nothing about the experiment: a group stacks on any config (gpu.yaml is instantiated only where a GPU is)."""
    hardware = {"accelerator", "devices", "strategy", "precision", "num_nodes"}
    for path in sorted(REPO.glob("configs/trainer/*.yaml")):
        keys = set(yaml.safe_load(path.read_text()))
        assert keys <= hardware | set(TRAINER_DEFAULTS), f"{path.name} sets {sorted(keys - hardware)}"


@pytest.mark.parametrize("group, expected", [("cpu", {"accelerator": "cpu", "devices": 1, "strategy": "auto"}),
                                             ("ddp", {"accelerator": "cpu", "devices": 2, "strategy": "ddp"})])
def test_a_trainer_group_changes_the_hardware_and_keeps_the_experiment(group, expected, monkeypatch, tmp_path):
    base = trainer_of([], monkeypatch, tmp_path)
    stacked = trainer_of(["--trainer", str(REPO / f"configs/trainer/{group}.yaml")], monkeypatch, tmp_path)
    assert {k: stacked[k] for k in expected} == expected
    for key in ("max_epochs", "log_every_n_steps", "callbacks", "logger", "default_root_dir"):
        assert stacked[key] == base[key], key
    assert base["logger"]["class_path"] == "lightning.pytorch.loggers.WandbLogger"
    assert base["logger"]["init_args"]["project"] == "icprl" and base["default_root_dir"] == "runs"



@pytest.mark.parametrize("size", ["small", "tprl_small", "paper", "paper_metaworld_tprl"])
def test_a_backbone_group_stacks_on_any_config(size, monkeypatch, tmp_path):
    """``configs/model/<size>.yaml`` is a backbone: ``--model.init_args.backbone FILE`` gives a run that size; the
    configs themselves write their size inline, so a config copied elsewhere still parses."""
    monkeypatch.chdir(tmp_path)
    written = yaml.safe_load((REPO / f"configs/model/{size}.yaml").read_text())
    cli = run_cli(["--config", CONFIG, "--model.init_args.backbone", str(REPO / f"configs/model/{size}.yaml")],
                  run=False)
    assert {k: cli.model.hparams.backbone[k] for k in written} == written
    sizes = {yaml.safe_load(p.read_text())["model"]["init_args"].get("backbone", {}).get("n_embd")
             for p in [*REPO.glob("configs/*.yaml"), *REPO.glob("configs/paper/*.yaml")]}
    assert written["n_embd"] in sizes  # a size some config of the project uses
