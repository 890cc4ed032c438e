"""Throughput of the batched Meta-World Reach env (``ReachVectorEnv``): env-steps/s for B envs stepping
together with uniform random actions, in-process (0 workers) and over 1 or 2 worker processes.

Startup (process launch, MuJoCo model compile, first reset) is timed separately from stepping. The
machine's load average is recorded because other jobs on the 2 cores skew wall-clock rates; in-process
runs also report steps per CPU-second of this process, which load does not skew.

    python benchmarks/metaworld_reach_env.py [--steps 150] [--batch-sizes 10 50] [--workers 0 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.env import ReachVectorEnv


def measure(goals: np.ndarray, num_workers: int, steps: int, seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, size=(steps, len(goals), 4))
    start = time.perf_counter()
    with ReachVectorEnv(goals, horizon=steps, num_workers=num_workers) as env:
        env.reset(seed=seed)
        ready, cpu_ready = time.perf_counter(), time.process_time()
        for a in actions:
            env.step(a)
        done, cpu_done = time.perf_counter(), time.process_time()
    n = len(goals) * steps
    row = {"batch_size": len(goals), "num_workers": num_workers, "startup_s": round(ready - start, 3),
           "env_steps_per_s": round(n / (done - ready), 1)}
    if num_workers == 0:
        row["env_steps_per_cpu_s"] = round(n / (cpu_done - cpu_ready), 1)
    return row


def main(args: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[10, 50])
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--seed", type=int, default=0)
    opts = parser.parse_args(args)
    train = ReachTaskFamily(seed=opts.seed).train_goals
    load_before = os.getloadavg()[0]
    results = [measure(np.resize(train, (b, 3)), w, opts.steps, opts.seed)
               for b in opts.batch_sizes for w in opts.workers]
    print(json.dumps({"benchmark": "metaworld_reach_env", "steps": opts.steps, "cpu_count": os.cpu_count(),
                      "python": platform.python_version(),
                      "load_average_1min": [load_before, os.getloadavg()[0]], "results": results}, indent=2))


if __name__ == "__main__":
    main()
