"""Deployment rate (env-steps/s) on the 20 held-out DarkRoom tasks, with and without the KV cache.

    python benchmarks/deployment_throughput.py [--episodes-per-task 1] [--seed 0] [--threads N]

A full episode (H = 100 steps) for each of 20 held-out goals, through the public Agent API: the
first act() after reset() encodes the 100-comparison contexts; each act() runs the query token only
(cache) or re-runs the whole context plus the query (no cache, what DPT's evaluation does every step).
Untrained weights: speed does not depend on them. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.settings import StepPreferences
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.methods.icpo import ICPOModule

SIZES = {"default_3L_64d": (3, 64, 4), "dpt_small_4L_32d": (4, 32, 4), "paper_6L_256d": (6, 256, 8)}


def run(model: ICPOModule, context: StepPreferenceContext, goals: np.ndarray, fam: DarkRoomFamily,
        use_cache: bool) -> float:
    agent = model.make_agent(use_cache=use_cache, seed=0)
    env = fam.make_env(goals)
    start = time.perf_counter()
    obs, _ = env.reset(seed=0)
    agent.reset(context)
    for _ in range(fam.horizon):
        obs, *_ = env.step(agent.act(torch.from_numpy(obs)).numpy())
    return len(goals) * fam.horizon / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes-per-task", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own, = the cores); 1 avoids thread "
                             "oversubscription on a shared machine")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    fam = DarkRoomFamily(seed=args.seed)
    goals = np.repeat(fam.test_goals, args.episodes_per_task, axis=0)
    arrays, _ = StepPreferences().contexts(fam, goals, np.zeros(len(goals), dtype=int), np.array([0.5]),
                                           np.random.default_rng(0), False, False, "")
    context = StepPreferenceContext(torch.from_numpy(arrays["states"]), torch.from_numpy(arrays["actions"]).long(),
                                    torch.from_numpy(arrays["alt_actions"]).long(),
                                    torch.from_numpy(arrays["preferred"]).float())
    results = {}
    for name, (n_layer, n_embd, n_head) in SIZES.items():
        torch.manual_seed(0)
        model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100, n_layer=n_layer,
                           n_embd=n_embd, n_head=n_head).eval()
        cached = run(model, context, goals, fam, use_cache=True)
        full = run(model, context, goals, fam, use_cache=False)
        results[name] = {"kv_cache": round(cached), "no_cache": round(full), "speedup": round(cached / full, 1)}
    print(json.dumps({"benchmark": "deployment_env_steps_per_second", "episodes": len(goals),
                      "horizon": fam.horizon, "torch_threads": torch.get_num_threads(), "results": results},
                     indent=2))


if __name__ == "__main__":
    main()
