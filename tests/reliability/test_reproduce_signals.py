"""Signals reach ``icprl reproduce``'s fits and leave nothing half-done (``reproduce/children.py``): SIGTERM stops
the running fit (it saves ``last.ckpt``), the command records it as interrupted and exits 143 with no fit left
running; a second ``reproduce`` in the same folder is refused meanwhile; the same command again resumes the fit
from that checkpoint instead of training a second copy."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from factories import REPO, tiny_darkroom_args

from icprl_lightning.commands.reproduce import main

EPOCHS = 6


def _fits_of(work: Path) -> list[int]:
    """The pids of the ``icprl fit`` processes writing under ``work``."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if proc.name.isdigit() and b"fit" in argv and any(str(work).encode() in a for a in argv):
            pids.append(int(proc.name))
    return pids


def _wait_for(condition, seconds: float, what: str):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.slow  # two tiny fits in subprocesses: ~1-2 minutes here
def test_sigterm_stops_records_and_a_rerun_resumes_the_fit(tmp_path, capsys):
    data = tiny_darkroom_args(tmp_path / "data")
    overrides = {k.removeprefix("--"): v for k, v in zip(data[::2], data[1::2], strict=True)}
    overrides.update({"trainer.max_epochs": EPOCHS, "trainer.limit_val_batches": 1,
                      "trainer.enable_progress_bar": False, "model.init_args.backbone.n_layer": 1,
                      "model.init_args.backbone.n_embd": 16, "model.init_args.backbone.n_head": 2})
    table = tmp_path / "sig.yaml"
    table.write_text(yaml.safe_dump({"title": "signals", "runs": [
        {"name": "ICPO", "configs": [str(REPO / "configs/icpo_darkroom.yaml")], "overrides": [overrides]}]}))
    work = tmp_path / "work"
    command = [sys.executable, "-m", "icprl_lightning", "reproduce", str(table), "--seeds", "0", "--jobs", "1",
               "--work", str(work), "--only", "ICPO"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "WANDB_MODE": "disabled"}
    first = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        last = _wait_for(lambda: list(work.glob("sig/runs/*/*/checkpoints/last.ckpt")), 300, "the first last.ckpt")
        (fit,) = _fits_of(work)
        with pytest.raises(SystemExit) as refused:  # a second reproduce in the same folder, meanwhile
            main([str(table), "--seeds", "0", "--jobs", "1", "--work", str(work), "--only", "ICPO"])
        assert refused.value.code == 2
        assert f"another icprl reproduce (pid {first.pid}) is running in {work / 'sig'}" in capsys.readouterr().err
        first.send_signal(signal.SIGTERM)
        out, err = first.communicate(timeout=300)
    finally:
        first.kill()
    assert first.returncode == 143, err[-3000:]
    assert "icprl reproduce: interrupted by SIGTERM: the running fits were stopped" in err, err[-3000:]
    assert not _fits_of(work)
    with pytest.raises(ProcessLookupError):
        os.kill(fit, 0)
    record = json.loads((work / "sig" / "ICPO-seed0.json").read_text())
    assert record["status"] == "interrupted" and record["checkpoint"] == str(last[0].absolute())
    stopped = torch.load(record["checkpoint"], weights_only=True)
    assert stopped["global_step"] > 0

    again = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"ICPO seed 0: resuming the interrupted fit from {record['checkpoint']}" in again.stdout
    done = json.loads((work / "sig" / "ICPO-seed0.json").read_text())
    assert "status" not in done and done["inputs_sha256"] == record["inputs_sha256"]
    final = torch.load(done["checkpoint"], weights_only=True)
    assert final["epoch"] == EPOCHS - 1 and final["global_step"] > stopped["global_step"]
    assert f"--ckpt_path {record['checkpoint']}" in done["command"]
    # one copy: the resumed fit started from the stopped one's state, not from step 0
    assert "Restoring states from the checkpoint" in (work / "sig" / "ICPO-seed0.log").read_text()
