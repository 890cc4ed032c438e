"""Meta-World Reach I-PRL generation throughput, and its ratio to the raw batched env's.

    python benchmarks/reach_generation.py [--trajectories-per-goal 20] [--workers 2] [--seed 0]

The generic I-PRL generator (``StepPreferences`` on ``ReachTaskFamily``: pair proposals from the mixture
behavior policies, the scripted expert's utility, Bradley–Terry labels, the state following the preferred
action, the query labels) for every trajectory of every training goal at once, the MuJoCo envs stepped in
``--workers`` worker processes. Beside it, the same batch of envs stepped with uniform random actions and
nothing else (what ``metaworld_reach_env.py`` measures): the ratio says what the labeling costs on top of
the simulator. Calibration and process startup are timed separately. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from icprl_lightning.data.settings import StepPreferences
from icprl_lightning.families.metaworld_reach import ReachTaskFamily
from icprl_lightning.families.metaworld_reach.env import ReachVectorEnv


def raw_env_steps_per_second(goals: np.ndarray, horizon: int, workers: int, seed: int) -> float:
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(horizon, len(goals), 4))
    with ReachVectorEnv(goals, horizon=horizon, num_workers=workers) as env:
        env.reset(seed=seed)
        start = time.perf_counter()
        for a in actions:
            env.step(a)
        return len(goals) * horizon / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trajectories-per-goal", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    family = ReachTaskFamily(seed=args.seed, num_workers=args.workers)
    began = time.perf_counter()
    calibration = family.calibrate({"low": 0.2, "medium": 0.4, "high": 0.8}, episodes=2, seed=args.seed)
    calibration_seconds = time.perf_counter() - began
    mixing = np.array([calibration[q]["mixing"] for q in ("low", "medium", "high")])
    goals = np.repeat(family.train_goals, args.trajectories_per_goal, axis=0)
    quality = np.tile(np.arange(args.trajectories_per_goal) % 3, len(family.train_goals))
    began = time.perf_counter()
    arrays, stats = StepPreferences().contexts(family, goals, quality, mixing, np.random.default_rng(args.seed),
                                               False, False, "")
    seconds = time.perf_counter() - began
    steps = len(goals) * family.horizon
    raw = raw_env_steps_per_second(goals[: min(len(goals), family.max_parallel)], family.horizon, args.workers,
                                   args.seed)
    print(json.dumps({
        "benchmark": "metaworld_reach_ipref_generation", "goals": len(family.train_goals),
        "trajectories_per_goal": args.trajectories_per_goal, "horizon": family.horizon, "workers": args.workers,
        "labeled_steps": steps, "generation_seconds_with_env_startup": round(seconds, 2),
        "labeled_steps_per_second": round(steps / seconds), "raw_env_steps_per_second": round(raw),
        "generation_vs_raw_env": round(steps / seconds / raw, 2), "calibration_seconds": round(calibration_seconds, 2),
        "label_agreement": round(stats["label_agreement"], 4), "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0], "seed": args.seed,
    }, indent=2))


if __name__ == "__main__":
    main()
