"""Training samples/s of one process vs several (Lightning's DDP, gloo on CPU) for one config.

    python benchmarks/ddp_throughput.py [--config configs/icpo_darkroom.yaml] [--steps 60]
                                        [--runs 1x1 1x2 2x1]

Each run is ``icprl fit`` of the config for ``--steps`` optimizer steps, in a fresh subprocess, on the
config's dataset (generated first if missing, so no run times generation), with the logger, validation,
rollouts and checkpoints off. A run ``PxT`` is P processes of T torch threads each. ``BatchTimer`` (a
callback) times rank 0 from the end of its first training batch to the end of its last, so start-up,
the process launch and the first step's warm-up are not counted; samples/s counts every rank's samples
(P × per-rank batch). With P > 1 the global batch is P × ``batch_size``. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import lightning as L

REPO = Path(__file__).resolve().parents[1]


class BatchTimer(L.Callback):
    """Rank 0 writes ``out``: timed steps, samples per rank in them, seconds (first to last batch end)."""

    def __init__(self, out: str) -> None:
        self.out = out
        self.began: float | None = None
        self.steps = self.samples = 0

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        now = time.perf_counter()
        if self.began is None:  # the first batch is warm-up
            self.began = now
            return
        self.ended, self.steps = now, self.steps + 1
        self.samples += len(next(iter(batch.values())))

    def on_train_end(self, trainer, pl_module) -> None:
        if trainer.is_global_zero:
            Path(self.out).write_text(json.dumps({"world_size": trainer.world_size, "steps": self.steps,
                                                  "samples_per_rank": self.samples,
                                                  "seconds": self.ended - self.began}))


def run(config: str, processes: int, threads: int, steps: int, workdir: Path) -> dict:
    out = workdir / f"timer-{processes}x{threads}.json"
    timer = {"class_path": "ddp_throughput.BatchTimer", "init_args": {"out": str(out)}}
    strategy = ["--trainer.strategy", "ddp"] if processes > 1 else []
    command = [sys.executable, "-m", "icprl_lightning", "fit", "--config", config,
               "--trainer.accelerator", "cpu", "--trainer.devices", str(processes), *strategy,
               "--trainer.max_steps", str(steps), "--trainer.max_epochs", "-1", "--trainer.limit_val_batches", "0",
               "--trainer.num_sanity_val_steps", "0", "--trainer.logger", "false",
               "--trainer.enable_checkpointing", "false", "--trainer.enable_progress_bar", "false",
               "--trainer.enable_model_summary", "false", "--trainer.default_root_dir", str(workdir),
               "--trainer.callbacks", json.dumps([timer]), "--evaluation", "null"]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "WANDB_MODE": "disabled",
           "PYTHONPATH": os.pathsep.join([str(REPO / "benchmarks"), os.environ.get("PYTHONPATH", "")])}
    subprocess.run(command, check=True, env=env, cwd=REPO, stdout=subprocess.DEVNULL)
    timed = json.loads(out.read_text())
    samples = timed["samples_per_rank"] * timed["world_size"]
    return {"processes": processes, "threads_per_process": threads, "timed_steps": timed["steps"],
            "global_batch": samples // timed["steps"], "seconds": round(timed["seconds"], 2),
            "samples_per_s": round(samples / timed["seconds"], 1),
            "steps_per_s": round(timed["steps"] / timed["seconds"], 2)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "configs/icpo_darkroom.yaml"))
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--runs", nargs="+", default=["1x1", "1x2", "2x1"], help="PxT: P processes, T threads each")
    args = parser.parse_args(argv)
    from icprl_lightning.commands import main as icprl

    icprl(["generate", "--config", args.config, "--data.init_args.progress", "false"])
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in args.runs:
            processes, threads = (int(x) for x in spec.split("x"))
            results.append(run(args.config, processes, threads, args.steps, Path(tmp)))
    print(json.dumps({"config": os.path.relpath(args.config, REPO), "steps": args.steps, "cpus": os.cpu_count(),
                      "runs": results}, indent=2))


if __name__ == "__main__":
    main()
