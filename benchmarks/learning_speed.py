"""Learning per second, not samples per second: ICPO on DarkRoom until its held-out greedy return at medium
context quality first reaches a target (85 by default), for each execution variant, same data, same seed.

    python benchmarks/learning_speed.py [--target 85] [--max-steps 2000] [--every 100] [--threads 2]

Each variant is one ``icprl fit --config configs/icpo_darkroom.yaml`` (the default data and training seed 0)
with the rollout callback every ``--every`` optimizer steps, stopped by ``EarlyStopping(stopping_threshold=)``
once the medium-quality return reaches the target. ``TrainingClock`` (a default callback of every fit) logs the
training seconds without validation and rollouts, so a variant that is faster per step but learns worse per step
shows it here. The
variants run one after another, each with the whole machine (``--threads``). Prints JSON: per variant the
first step and training seconds at which the target was reached (or null), and its whole curve.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
METRIC = "val/darkroom/medium/return"
MERGED_OBJECTIVE = ("--model.init_args.pair_source", "next", "--data.init_args.pairs", "false")
ONE_HEAD = ("--model.init_args.backbone.n_head", "1")
VARIANTS = {
    "4 heads, all 100 queries (the config's default)": (),
    "1 head, all 100 queries": ONE_HEAD,
    "1 head, 25 queries per context": (*ONE_HEAD, "--model.init_args.queries_per_context", "25"),
    # the context's own next comparison, scored in the appended layout: the merged layout's objective at the
    # appended layout's speed, which separates what the objective changes from what the layout changes
    "4 heads, appended layout, pair_source next": MERGED_OBJECTIVE,
    "4 heads, merged layout": ("--config", "configs/overlays/merged_layout.yaml"),
    "1 head, merged layout": ("--config", "configs/overlays/merged_layout.yaml", *ONE_HEAD),
    # the context in its stored episode order in training, as the deployed agent reads it
    "4 heads, merged layout, episode order": ("--config", "configs/overlays/merged_layout.yaml",
                                              "--model.init_args.pair_steps", "aligned"),
    "4 heads, appended layout, pair_source next, episode order": (*MERGED_OBJECTIVE, "--model.init_args.pair_steps",
                                                                  "aligned"),
}


def fit(overrides: tuple[str, ...], out: Path, target: float, max_steps: int, every: int, threads: int) -> list[dict]:
    command = [sys.executable, "-m", "icprl_lightning", "fit", "--config", "configs/icpo_darkroom.yaml",
               *overrides, "--seed_everything", "0", "--trainer.max_steps", str(max_steps),
               "--trainer.max_epochs", "1000", "--trainer.val_check_interval", str(every),
               "--trainer.check_val_every_n_epoch", "null", "--trainer.limit_val_batches", "1",
               "--trainer.logger", "lightning.pytorch.loggers.CSVLogger", "--trainer.logger.init_args.save_dir",
               str(out), "--trainer.default_root_dir", str(out),
               "--trainer.callbacks+=lightning.pytorch.callbacks.EarlyStopping",
               "--trainer.callbacks.monitor", METRIC, "--trainer.callbacks.mode", "max",
               "--trainer.callbacks.stopping_threshold", str(target), "--trainer.callbacks.patience", "1000000",
               "--trainer.callbacks.check_on_train_epoch_end", "false"]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "WANDB_MODE": "disabled"}
    out.mkdir(parents=True, exist_ok=True)
    log = out / "fit.log"
    with open(log, "w") as f:
        code = subprocess.run(command, cwd=REPO, stdout=f, stderr=subprocess.STDOUT, env=env).returncode
    if code != 0:
        raise RuntimeError(f"fit failed (exit {code}):\n{log.read_text()[-3000:]}")
    rows = []
    for path in out.rglob("metrics.csv"):
        with open(path) as f:
            for row in csv.DictReader(f):
                if row.get(METRIC) and row.get("time/train_seconds"):
                    rows.append({"step": int(float(row["time/optimizer_steps"])),
                                 "train_seconds": round(float(row["time/train_seconds"]), 1),
                                 "medium_return": round(float(row[METRIC]), 2)})
    return sorted(rows, key=lambda r: r["step"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--target", type=float, default=85.0)
    parser.add_argument("--max-steps", type=int, default=2000)
    parser.add_argument("--every", type=int, default=100, help="optimizer steps between held-out rollouts")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--variants", nargs="+", type=int, help="indices into the variant list (default: all)")
    args = parser.parse_args()
    names = list(VARIANTS)
    chosen = [names[i] for i in args.variants] if args.variants else names
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, name in enumerate(chosen):
            began = time.perf_counter()
            curve = fit(VARIANTS[name], Path(tmp) / f"v{i}", args.target, args.max_steps, args.every, args.threads)
            hit = next((p for p in curve if p["medium_return"] >= args.target), None)
            results[name] = {"reached_at_step": hit and hit["step"],
                             "reached_after_train_seconds": hit and hit["train_seconds"],
                             "best_medium_return": max((p["medium_return"] for p in curve), default=None),
                             "wall_seconds": round(time.perf_counter() - began, 1), "curve": curve}
            print(f"{name}: {({k: v for k, v in results[name].items() if k != 'curve'})}", file=sys.stderr, flush=True)
    print(json.dumps({"benchmark": "learning_speed", "config": "configs/icpo_darkroom.yaml", "seed": 0,
                      "target_medium_return": args.target, "max_steps": args.max_steps, "threads": args.threads,
                      "results": results}, indent=2))


if __name__ == "__main__":
    main()
