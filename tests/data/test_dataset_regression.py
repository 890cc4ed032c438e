"""Same config, same bytes: every DarkRoom and bandit config's dataset against the checksums recorded
before the task-family refactor (tests/fixtures/dataset_checksums.json, made by
``icprl analyze checksums CONFIGS...``, ``data/checksums.py``, at commit 8ed6734's generators).

The Meta-World entries of that file take minutes each to regenerate (MuJoCo); they were compared with
the same command when the refactor landed, and are left to it rather than to the suite.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from icprl_lightning.data.checksums import changed_files, dataset_checksums

REPO = Path(__file__).resolve().parents[2]

REFERENCE = json.loads((REPO / "tests/fixtures/dataset_checksums.json").read_text())
FAST = sorted(k for k in REFERENCE if "metaworld" not in k and "paper" not in k)
PAPER = sorted(k for k in REFERENCE if "metaworld" not in k and "paper" in k)


def _check(config: str, tmp_path) -> None:
    parts = [str(REPO / p) for p in config.split("+")]
    assert changed_files(REFERENCE[config], dataset_checksums("+".join(parts), tmp_path)) == []


@pytest.mark.parametrize("config", FAST)
def test_dataset_bytes_are_unchanged(config, tmp_path):
    _check(config, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("config", PAPER)
def test_paper_scale_dataset_bytes_are_unchanged(config, tmp_path):
    _check(config, tmp_path)


def test_the_reference_covers_every_config():
    configs = {str(p.relative_to(REPO)) for p in (REPO / "configs").glob("*.yaml")} - {"configs/recorded_icpo.yaml"}
    assert configs <= set(REFERENCE), sorted(configs - set(REFERENCE))


def test_the_command_compares_against_a_reference(tmp_path, capsys):
    """``icprl analyze checksums --compare``: status 0 when the bytes match, 1 naming every changed file."""
    from icprl_lightning.commands import main

    config = "configs/icpo_bandit.yaml"
    assert config in FAST
    good = tmp_path / "good.json"
    good.write_text(json.dumps({str(REPO / config): REFERENCE[config]}))
    assert main(["analyze", "checksums", str(REPO / config), "--compare", str(good)]) is None
    assert json.loads(capsys.readouterr().out) == {str(REPO / config): REFERENCE[config]}
    forged = dict(REFERENCE[config])
    changed = sorted(forged)[0]
    forged[changed] = "0" * 64
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({str(REPO / config): forged}))
    with pytest.raises(SystemExit) as info:
        main(["analyze", "checksums", str(REPO / config), "--compare", str(bad)])
    assert info.value.code == 1
    assert f"CHANGED: {changed}" in capsys.readouterr().err
