"""Every config instantiates: each base in configs/, and each configs/paper/ overlay stacked on its base.

An overlay holds values only (no ``class_path``: its base picks the classes) and its header names the base
(``# base: configs/x.yaml``) and the exact command (the ``icprl fit`` line, ``\\``-continued). The test runs
that command's arguments, so the documented command is the tested one. jsonargparse merges a second
``--config`` into the first: ``model.init_args`` / ``data.init_args`` and the named callbacks (``evaluation``,
``best_checkpoint``) without a ``class_path`` keep the base's class; nothing is merged by list position.
Instantiating builds the trainer, the model and the DataModule; it generates no data.
"""

from __future__ import annotations

import importlib
import json
import re
import shlex
from pathlib import Path
from typing import Any

import lightning as L
import pytest
import yaml
from jsonargparse import Namespace
from lightning.pytorch.callbacks import EarlyStopping

from icprl_lightning.callbacks.defaults import NAMED_CALLBACKS
from icprl_lightning.commands import run_cli

REPO = Path(__file__).resolve().parents[2]
BASES = sorted(p.relative_to(REPO).as_posix() for p in REPO.glob("configs/*.yaml"))
OVERLAYS = sorted(p.relative_to(REPO).as_posix() for p in REPO.glob("configs/paper/*.yaml"))
# A DataModule over recorded data reads its dataset when built (there is no generator): these configs are
# instantiated on an imported dataset by the test named here.
NEEDS_RECORDED_DATA = {
    "configs/recorded_icpo.yaml": "tests/data/test_recorded_data.py::test_import_fit_icpo_and_deploy"}
# ICRG reads its stage-1 checkpoint when built; an architecture instead lets it build without the file.
NO_CHECKPOINT = ["--model.init_args.reward_gen_hparams",
                 json.dumps({"backbone": {"n_layer": 1, "n_embd": 8, "n_head": 1}, "max_context": 1000})]


def base_of(overlay: str) -> str:
    match = re.search(r"^# base: (\S+)$", (REPO / overlay).read_text(), re.MULTILINE)
    assert match, f"{overlay} has no '# base: configs/<name>.yaml' line"
    return match.group(1)


def header_command(overlay: str) -> list[str]:
    """The arguments after ``icprl fit`` of the overlay's header command, joined over ``\\`` continuations."""
    lines = (REPO / overlay).read_text().splitlines()
    start = next((i for i, line in enumerate(lines) if re.match(r"#\s+icprl fit ", line)), None)
    assert start is not None, f"{overlay} has no '#   icprl fit --config <base> --config {overlay}' line"
    command, i = lines[start].lstrip("# ").rstrip(), start
    while command.endswith("\\"):
        i += 1
        assert lines[i].startswith("#"), f"{overlay}: the command continues past the header"
        command = command[:-1] + " " + lines[i].lstrip("# ").rstrip()
    return shlex.split(command)[2:]


def instantiate(args: list[str], monkeypatch, tmp_path) -> Any:
    """``run_cli(args, run=False)`` from an empty directory (absolute config paths), so nothing lands in the repo."""
    args = [str(REPO / a) if a.startswith("configs/") else a for a in args]
    configs = [yaml.safe_load(Path(a).read_text()) for a in args if a.endswith(".yaml")]
    if any("reward_gen_checkpoint" in c.get("model", {}).get("init_args", {}) for c in configs):
        args = [*args, *NO_CHECKPOINT]
    monkeypatch.chdir(tmp_path)
    return run_cli([*args, "--trainer.default_root_dir", str(tmp_path)], run=False)


def leaves(tree: Any, prefix: tuple = ()) -> list[tuple[tuple, Any]]:
    """(path, value) of every scalar (list items indexed)."""
    if isinstance(tree, dict):
        return [leaf for key, value in tree.items() for leaf in leaves(value, (*prefix, key))]
    if isinstance(tree, list):
        return [leaf for i, value in enumerate(tree) for leaf in leaves(value, (*prefix, i))]
    return [(prefix, tree)]


def lookup(config: Namespace, path: tuple) -> Any:
    node: Any = config
    for key in path:
        node = node[key]
    return node


def resolve(class_path: str) -> type:
    """The class a config's ``class_path`` names (it may name a re-export, e.g. ``package.Class``)."""
    module, _, name = class_path.rpartition(".")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("config", [
    pytest.param(c, marks=pytest.mark.skip(reason=f"needs recorded data; built in {NEEDS_RECORDED_DATA[c]}"))
    if c in NEEDS_RECORDED_DATA else c for c in BASES])
def test_base_config_instantiates(config, monkeypatch, tmp_path):
    cli = instantiate(["--config", config], monkeypatch, tmp_path)
    written = yaml.safe_load((REPO / config).read_text())
    assert isinstance(cli.model, L.LightningModule) and isinstance(cli.datamodule, L.LightningDataModule)
    assert type(cli.model) is resolve(written["model"]["class_path"])
    assert type(cli.datamodule) is resolve(written["data"]["class_path"])
    assert cli.model.hparams.max_context == cli.datamodule.context_length  # linked from the data
    assert cli.trainer.max_epochs == written["trainer"]["max_epochs"]


@pytest.mark.parametrize("overlay", OVERLAYS)
def test_overlay_holds_values_only_and_names_its_base(overlay):
    written = yaml.safe_load((REPO / overlay).read_text())
    assert all("class_path" not in path for path, _ in leaves(written)), f"{overlay} sets a class_path"
    base = base_of(overlay)
    assert base in BASES, f"{overlay}: its base {base} is not a config in configs/"
    assert header_command(overlay)[:4] == ["--config", base, "--config", overlay]


@pytest.mark.parametrize("overlay", OVERLAYS)
def test_overlay_stacks_on_its_base(overlay, monkeypatch, tmp_path):
    base = base_of(overlay)
    cli = instantiate(header_command(overlay), monkeypatch, tmp_path)
    written, base_written = (yaml.safe_load((REPO / f).read_text()) for f in (overlay, base))
    # the classes are the base's ...
    assert type(cli.model) is resolve(base_written["model"]["class_path"])
    assert type(cli.datamodule) is resolve(base_written["data"]["class_path"])
    for key, (_, default, _) in NAMED_CALLBACKS.items():  # a named callback's class too (None: dropped by the base)
        expected = base_written.get(key, default)
        assert (cli.config[key] and cli.config[key].class_path) == (
            expected and expected.get("class_path", default["class_path"])), key
    # ... every value the overlay writes is in the resolved config ...
    for path, value in leaves({k: v for k, v in written.items() if k not in NAMED_CALLBACKS}):
        if isinstance(value, str) and value.endswith(".yaml"):  # a config group's file, e.g. the backbone
            held = lookup(cli.config, path)
            value = yaml.safe_load(((REPO / overlay).parent / value).read_text())
            assert {k: held[k] for k in value} == value, (overlay, ".".join(map(str, path)))
            continue
        assert lookup(cli.config, path) == value, (overlay, ".".join(map(str, path)))
    # ... and reached the instances
    for key, value in written["model"]["init_args"].items():
        held = cli.model.hparams[key]
        if isinstance(value, str) and value.endswith(".yaml"):
            value = yaml.safe_load(((REPO / overlay).parent / value).read_text())
        if isinstance(value, dict):  # a dataclass argument (the backbone): the keys the overlay writes
            held = {k: held[k] for k in value}
        assert held == value, (overlay, key)
    for name in set(written) & set(NAMED_CALLBACKS):
        callback = next(c for c in cli.trainer.callbacks if type(c) is resolve(cli.config[name].class_path))
        for key, value in written[name].items():
            held = getattr(callback, key, getattr(callback, f"_{key}", None))
            assert held == (str(Path(value).resolve()) if key == "dirpath" else value), (overlay, key, held)
    assert cli.trainer.max_epochs == lookup(cli.config, ("trainer", "max_epochs"))
    # the paper's optimizer settings, common to every paper-sized run (appendix "Implementation Details")
    assert cli.model.hparams.optimizer["lr"] == 3e-4 and cli.config.data.init_args.batch_size == 32
    assert cli.model.hparams.max_context == cli.datamodule.context_length


@pytest.mark.parametrize("overlay", [o for o in OVERLAYS if "early stopping" in (REPO / o).read_text().lower()])
def test_paper_early_stopping_is_in_the_command(overlay, monkeypatch, tmp_path):
    """Appending a callback the base lacks needs its class, which an overlay may not name: the command adds it."""
    cli = instantiate(header_command(overlay), monkeypatch, tmp_path)
    stops = [c for c in cli.trainer.callbacks if isinstance(c, EarlyStopping)]
    assert len(stops) == 1 and stops[0].monitor == "val/loss"


# ---- named callbacks (callbacks/defaults.py NAMED_CALLBACKS) --------------------------------------------------

@pytest.mark.parametrize(("extra", "kinds"), [
    ([], ["InContextRolloutCallback", "ModelCheckpoint", "LastCheckpoint"]),
    (["--trainer.callbacks+=lightning.pytorch.callbacks.EarlyStopping", "--trainer.callbacks.monitor=val/loss",
      "--best_checkpoint", "null"], ["InContextRolloutCallback", "EarlyStopping", "LastCheckpoint"]),
    (["--evaluation.every_n_epochs", "3", "--trainer.enable_checkpointing", "false"], ["InContextRolloutCallback"]),
    (["--evaluation", "null", "--best_checkpoint.filename", "best"], ["ModelCheckpoint", "LastCheckpoint"]),
])
def test_named_callbacks_come_first_change_by_key_and_null_drops_one(extra, kinds, monkeypatch, tmp_path):
    cli = instantiate(["--config", "configs/icpo_darkroom.yaml", *extra], monkeypatch, tmp_path)
    named = {"InContextRolloutCallback", "ModelCheckpoint", "LastCheckpoint", "EarlyStopping"}
    assert [type(c).__name__ for c in cli.trainer.callbacks if type(c).__name__ in named] == kinds
    rollout = next((c for c in cli.trainer.callbacks if type(c).__name__ == "InContextRolloutCallback"), None)
    assert rollout is None or rollout.every_n_epochs == (3 if "3" in extra else 1)
    assert all(c.filename == ("best" if "best" in extra else None) for c in cli.trainer.callbacks
               if type(c).__name__ == "ModelCheckpoint")


def test_a_config_listing_its_evaluation_and_checkpoint_itself_runs_each_once(monkeypatch, tmp_path):
    """The form before the named callbacks: what ``trainer.callbacks`` holds replaces the default of its kind."""
    written = yaml.safe_load((REPO / "configs/icpo_darkroom.yaml").read_text())
    written["trainer"]["callbacks"] = [
        {"class_path": "icprl_lightning.callbacks.rollout.InContextRolloutCallback",
         "init_args": {"every_n_epochs": 3}},
        {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
         "init_args": {"monitor": "val/loss", "filename": "mine"}}]
    path = tmp_path / "old_form.yaml"
    path.write_text(yaml.safe_dump(written))
    cli = instantiate(["--config", str(path)], monkeypatch, tmp_path)
    rollouts = [c.every_n_epochs for c in cli.trainer.callbacks if type(c).__name__ == "InContextRolloutCallback"]
    best = [c.filename for c in cli.trainer.callbacks if type(c).__name__ == "ModelCheckpoint"]
    assert rollouts == [3] and best == ["mine"]
