"""DarkRoom I-PRL generation throughput at paper scale (80 tasks x 1000 trajectories x 100 steps).

    python benchmarks/darkroom_generation.py [--trajectories-per-task 1000] [--seed 0]

Prints JSON: labeled steps per second of the generic I-PRL generator (``StepPreferences`` on
``DarkRoomFamily``: pair proposals, A*, BT sampling, state transitions and the query labels, for every
trajectory of every task at once), excluding disk writes, plus the time to write the dataset to disk
through the store.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time

import numpy as np

from icprl_lightning.data.settings import StepPreferences
from icprl_lightning.data.store import write_dataset
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.family import calibrate_mixing


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trajectories-per-task", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    fam = DarkRoomFamily(seed=args.seed)
    t0 = time.perf_counter()
    cal = calibrate_mixing(fam, {"low": 0.2, "medium": 0.4, "high": 0.8}, seed=args.seed)
    t_cal = time.perf_counter() - t0
    p = np.array([cal[q]["mixing"] for q in ("low", "medium", "high")])
    goals = np.repeat(fam.train_goals, args.trajectories_per_task, axis=0)
    quality = np.tile(np.arange(args.trajectories_per_task) % 3, fam.n_train_tasks)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    arrays, stats = StepPreferences().contexts(fam, goals, quality, p, rng, False, False, "")
    t_gen = time.perf_counter() - t0
    steps = len(goals) * fam.horizon
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_dataset(os.path.join(tmp, "d"), {"train": arrays}, {"benchmark": True})
        t_write = time.perf_counter() - t0
    print(json.dumps({
        "benchmark": "darkroom_ipref_generation",
        "tasks": fam.n_train_tasks, "trajectories_per_task": args.trajectories_per_task, "horizon": fam.horizon,
        "labeled_steps": steps, "generation_seconds": round(t_gen, 3),
        "labeled_steps_per_second": round(steps / t_gen),
        "calibration_seconds": round(t_cal, 3),
        "write_seconds_with_checksums": round(t_write, 3), "label_agreement": round(stats["label_agreement"], 4),
        "cpu_count": os.cpu_count(), "machine": platform.machine(), "seed": args.seed,
    }, indent=2))


if __name__ == "__main__":
    main()
