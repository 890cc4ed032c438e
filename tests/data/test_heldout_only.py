"""``PreferenceDataModule.prepare_heldout`` (what ``icprl evaluate`` prepares): only the held-out splits, drawn from
the generator state recorded after the training splits (``icprl_lightning/data/heldout_streams.json``, made by
``benchmarks/heldout_streams.py --write``), byte for byte the whole generation's, in a directory of their own that
a fit never takes for the whole dataset."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

import icprl_lightning.data.datamodule as datamodule
from icprl_lightning.data.config import datamodule_from_config

REPO = Path(__file__).resolve().parents[2]
REFERENCE = json.loads((REPO / "tests/fixtures/dataset_checksums.json").read_text())
SHIPPED = ["configs/icpo_darkroom.yaml"]  # the data of darkroom-icpo
DARKROOM = "configs/icpo_darkroom.yaml"


def _files(dm) -> dict[str, str]:
    return {name: meta["sha256"] for name, meta in dm.load().manifest["files"].items()}


@pytest.mark.parametrize("config", SHIPPED)
def test_the_recorded_checksums_are_the_pinned_whole_datasets(config, tmp_path):
    """Each shipped model's entry holds the pinned checksums (``test_dataset_regression.py``) of every file made
    after the training splits: the recorded state can only be accepted if it reproduces today's held-out data."""
    table = json.loads(datamodule.HELDOUT_STREAMS.read_text())
    name = datamodule_from_config(REPO / config, root_dir=str(tmp_path)).path.name
    recorded = table[name]["files"]
    assert sorted(recorded) == sorted(k for k in REFERENCE[config] if not k.startswith(("train/", "val/")))
    assert recorded == {k: REFERENCE[config][k] for k in recorded}


def test_heldout_only_data_is_the_whole_datasets_and_marked(tmp_path):
    dm = datamodule_from_config(REPO / DARKROOM, root_dir=str(tmp_path), progress=False)
    whole = dm.path
    dm.prepare_heldout()
    assert dm.path == whole.with_name(whole.name + ".heldout") and not whole.exists()
    assert dm.load().manifest["info"]["heldout_only"] is True
    assert _files(dm) == {k: v for k, v in REFERENCE[DARKROOM].items() if not k.startswith(("train/", "val/"))}
    assert [s.quality for s in dm.held_out("rollouts")] == ["low", "medium", "high"]
    fit = datamodule_from_config(REPO / DARKROOM, root_dir=str(tmp_path), progress=False)
    fit.prepare_data()  # a fit's prepare makes the whole dataset beside it, with the pinned bytes
    assert fit.path == whole and _files(fit) == REFERENCE[DARKROOM]
    again = datamodule_from_config(REPO / DARKROOM, root_dir=str(tmp_path), progress=False)
    again.prepare_heldout()  # the whole dataset, now that it exists
    assert again.path == whole


def test_a_stale_record_falls_back_to_the_whole_dataset(tmp_path, monkeypatch, capsys):
    """Held-out bytes that differ from the record (other generators, other numerics) are never used: their
    directory is removed and the whole dataset generated, with a note naming the files."""
    table = json.loads(datamodule.HELDOUT_STREAMS.read_text())
    dm = datamodule_from_config(REPO / DARKROOM, root_dir=str(tmp_path / "data"), progress=False)
    whole = dm.path
    table[whole.name]["stream"]["state"]["state"] += 1  # another state: other held-out bytes
    stale = tmp_path / "streams.json"
    stale.write_text(json.dumps(table))
    monkeypatch.setattr(datamodule, "HELDOUT_STREAMS", stale)
    dm.prepare_heldout()
    assert re.search(r"\.heldout differ from the whole generation's .*eval_high/actions\.npy", capsys.readouterr().out)
    assert dm.path == whole and _files(dm) == REFERENCE[DARKROOM]
    assert sorted(p.name for p in whole.parent.iterdir() if not p.name.startswith(".")) == [whole.name]


@pytest.mark.slow
def test_metaworld_icpo_held_out_data_is_made_alone(tmp_path):
    """The record of metaworld-icpo's data holds on this machine: its held-out splits are made without the
    training splits and kept (a byte that differs would fall back to the whole dataset)."""
    dm = datamodule_from_config(REPO / "configs/icpo_metaworld.yaml", root_dir=str(tmp_path), progress=False)
    dm.prepare_heldout()
    assert dm.path.name.endswith(".heldout") and sorted(dm.load().splits) == ["eval_high", "eval_low", "eval_medium",
                                                                                "tasks"]
