"""Config groups compose: ``configs/trainer/`` holds the hardware (cpu, gpu, ddp), stacked after any config with
``--trainer FILE``, which changes the hardware and keeps the experiment (epochs, callbacks, logger). What every
config's trainer starts from is the CLI's ``TRAINER_DEFAULTS``, and ``configs/trainer/cpu.yaml`` spells out exactly
that, so the configs no longer copy it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from icprl_lightning.commands import run_cli
from icprl_lightning.commands.trainer import TRAINER_DEFAULTS

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



DATA_GROUPS = sorted(p.stem for p in (REPO / "configs/data").glob("*.yaml"))


def _values(namespace) -> dict:
    """The parsed values, without jsonargparse's record of which file gave them (``__path__``)."""
    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k != "__path__"}
        return [strip(v) for v in value] if isinstance(value, list) else value
    return strip(namespace.as_dict())


def _named_configs(group: str) -> list[str]:
    """The public configs a data group's header names as having its family and setting."""
    header = (REPO / f"configs/data/{group}.yaml").read_text().splitlines()[1]
    return [word.rstrip(",.") for word in header.split() if word.startswith("configs/")]


@pytest.mark.parametrize("group", DATA_GROUPS)
def test_a_data_group_is_the_data_of_the_configs_it_names(group, monkeypatch, tmp_path):
    """Stacking ``--data configs/data/<group>.yaml`` on each config it names changes nothing: the group is exactly
    their family and setting, and the config's own data flags (batch size, pairs, query labels) stay."""
    monkeypatch.chdir(tmp_path)
    configs = _named_configs(group)
    assert configs, f"configs/data/{group}.yaml names no config on its second line"
    group_data = yaml.safe_load((REPO / f"configs/data/{group}.yaml").read_text())
    for config in configs:
        data = yaml.safe_load((REPO / config).read_text())["data"]
        assert data["class_path"] == group_data["class_path"], config
        assert {k: data["init_args"][k] for k in ("family", "setting")} == group_data["init_args"], config
        if "icrg" in config:  # ICRG is built only with its stage-1 reward model: the file comparison above suffices
            continue
        base = run_cli(["--config", str(REPO / config)], run=False).config["data"]
        stacked = run_cli(["--config", str(REPO / config), "--data", str(REPO / f"configs/data/{group}.yaml")],
                          run=False).config["data"]
        assert _values(stacked) == _values(base), config


def test_every_public_config_has_its_data_group():
    groups = {config for group in DATA_GROUPS for config in _named_configs(group)}
    public = {f"configs/{p.name}" for p in REPO.glob("configs/*.yaml")
              if "data" in (yaml.safe_load(p.read_text()) or {})
              # not family x setting: the smoke run, recorded data, a learner's histories
              and p.stem not in ("smoke", "recorded_icpo", "ad_darkroom", "ad_bandit")}
    assert public <= groups, sorted(public - groups)


def test_a_data_group_swaps_the_family_and_keeps_the_methods_flags(monkeypatch, tmp_path):
    """ICPO's DarkRoom config on the bandit group: the family and setting are the bandit's, ICPO's pairs stay."""
    monkeypatch.chdir(tmp_path)
    bandit = str(REPO / "configs/data/bandit_duels.yaml")
    data = run_cli(["--config", CONFIG, "--data", bandit], run=False).config["data"]
    assert data["init_args"]["family"]["class_path"].endswith("LinearDuelingBanditFamily")
    assert data["init_args"]["setting"]["class_path"].endswith("BanditDuels")
    assert data["init_args"]["pairs"] is True
