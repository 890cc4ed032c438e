"""Same config, same bytes: every DarkRoom and bandit config's dataset against the checksums recorded
before the task-family refactor (tests/fixtures/dataset_checksums.json, made by
``python scripts/dataset_checksums.py CONFIGS...`` at commit 8ed6734's generators).

The Meta-World entries of that file take minutes each to regenerate (MuJoCo); they were compared with
the same script when the refactor landed, and are left to it rather than to the suite.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

from dataset_checksums import checksums  # noqa: E402

REFERENCE = json.loads((REPO / "tests/fixtures/dataset_checksums.json").read_text())
FAST = sorted(k for k in REFERENCE if "metaworld" not in k and "paper" not in k)
PAPER = sorted(k for k in REFERENCE if "metaworld" not in k and "paper" in k)


def _check(config: str, tmp_path) -> None:
    parts = [str(REPO / p) for p in config.split("+")]
    assert checksums("+".join(parts), str(tmp_path)) == REFERENCE[config]


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
