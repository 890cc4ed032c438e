"""The subcommands that neither train nor deploy never import Lightning: each is run as a user runs it, under
``python -X importtime``, whose list of every imported module must hold no ``lightning``. (Importing Lightning
takes seconds; ``benchmarks/cli_latency.py`` times these commands beside it.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
LEGACY_ICPO = REPO / "tests/fixtures/legacy/icpo_1x8.ckpt"  # a real checkpoint: verify reads its every part


def imported_modules(argv: list[str], cwd: Path) -> set[str]:
    """The modules ``icprl ARGV`` imports, from ``-X importtime``'s report; the command must succeed."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "icprl_lightning", *argv], cwd=cwd,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [line.split("|")[-1].strip() for line in out.stderr.splitlines() if line.startswith("import time:")]
    assert len(rows) > 10, out.stderr[-2000:]  # the report is there: the check below can fail
    return set(rows[1:])  # the first row is the header


def lightning(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m == "lightning" or m.startswith(("lightning.", "pytorch_lightning")))


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """A recorded step-preference dataset (``icprl import``) and a run's ``metrics.csv``."""
    tmp = tmp_path_factory.mktemp("fast")
    rng = np.random.default_rng(0)
    n, steps = 12, 4
    actions, alt = rng.integers(0, 5, (2, n, steps))
    np.savez(tmp / "prefs.npz", states=rng.integers(0, 10, (n, steps, 2)).astype(np.float32), actions=actions,
             alt_actions=alt, preferred=rng.integers(0, 2, (n, steps)), task_index=np.repeat(np.arange(4), 3))
    run = tmp / "run"
    run.mkdir()
    (run / "metrics.csv").write_text("epoch,step,train/loss,val/darkroom/low/return\n0,9,0.9,\n0,9,,3.0\n"
                                     "1,19,0.7,\n1,19,,4.0\n")
    return tmp


@pytest.mark.parametrize("argv", [
    ["--help"],
    ["report", "run", "--no-figure"],
    ["import", "prefs.npz", "--out", "data/mine", "--kind", "step_preference", "--n-actions", "5"],
    ["export-data", "data/mine", "--format", "parquet", "--out", "exported"],
    ["checkpoint", "--help"],
    ["checkpoint", "verify", "--resumable", str(LEGACY_ICPO)],
    ["label", "--session", "labels", "--view", "darkroom_trajectories", "--pairs", "3", "--export", "answers"],
], ids=lambda argv: " ".join(argv[:2]))
def test_a_subcommand_that_neither_trains_nor_deploys_imports_no_lightning(argv, workdir):
    modules = imported_modules(argv, workdir)
    assert lightning(modules) == [], f"icprl {' '.join(argv)} imported {lightning(modules)[:3]}"


def test_the_check_sees_lightning_where_it_is_imported(workdir):
    """The same check on commands that do import Lightning (the fit's parser; a checkpoint's module rebuilt)
    reports it."""
    assert "lightning.pytorch" in imported_modules(["fit", "--help"], workdir)
    assert "lightning.pytorch" in imported_modules(["checkpoint", "verify", "--rebuild", str(LEGACY_ICPO)], workdir)
