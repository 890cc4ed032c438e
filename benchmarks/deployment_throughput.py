"""Deployment rate (env-steps/s) on batched DarkRoom tasks, with and without the KV cache, beside DPT's reference.

    python benchmarks/deployment_throughput.py [--tasks 100] [--seed 0] [--threads N] [--no-reference] [--compile]

A full episode (H = 100 steps) for each of ``--tasks`` tasks (the 20 held-out goals repeated), all in one
vector env, through the public Agent API: the first act() after reset() encodes the 100-comparison
contexts; each act() runs the query token only (cache) or re-runs the whole context plus the query (no
cache, what DPT's evaluation does every step). The rate counts the whole loop (env steps included).
Untrained weights: speed does not depend on them. With the ``bench`` extra installed, DPT's reference
evaluation (``dpt_reference.py``: a full 101-token forward per step, the same number of tasks) runs in the
same process, and each size prints its ratio to it. ``--compile`` adds the cached agent with its query step
under ``torch.compile`` (``load_agent(..., compile=True)``): a first episode compiles (its seconds printed as
``compile_episode_seconds``), the next is timed, as the reference is timed after a warm-up forward. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.settings import StepPreferences
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig

try:  # run as a script (benchmarks/ on sys.path) or as a module
    import dpt_reference
except ImportError:  # pragma: no cover
    from benchmarks import dpt_reference

# name: (layers, width, heads, the reference size it compares with)
SIZES = {"default_3L_64d": (3, 64, 4, None), "dpt_small_4L_32d": (4, 32, 4, "dpt_small_4L_32d_b64"),
         "dpt_small_4L_32d_1head": (4, 32, 1, "dpt_small_4L_32d_b64"),
         "paper_6L_256d": (6, 256, 8, "paper_6L_256d_b32")}


def episode(agent, context: StepPreferenceContext, goals: np.ndarray, fam: DarkRoomFamily) -> float:
    """Seconds for one full episode of every task (reset, encode at the first act, H steps)."""
    env = fam.make_env(goals)
    start = time.perf_counter()
    obs, _ = env.reset(seed=0)
    agent.reset(context)
    for _ in range(fam.horizon):
        obs, *_ = env.step(agent.act(torch.from_numpy(obs)).numpy())
    return time.perf_counter() - start


def run(model: ICPOModule, context: StepPreferenceContext, goals: np.ndarray, fam: DarkRoomFamily,
        use_cache: bool) -> float:
    return len(goals) * fam.horizon / episode(model.make_agent(use_cache=use_cache, seed=0), context, goals, fam)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--tasks", type=int, default=100, help="tasks deployed at once (held-out goals repeated)")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=list(SIZES))
    parser.add_argument("--no-reference", action="store_true", help="skip DPT's reference even if installed")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compile", action="store_true", help="also time the cached agent under torch.compile")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own, = the cores); 1 avoids thread "
                             "oversubscription on a shared machine")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    fam = DarkRoomFamily(seed=args.seed)
    if args.tasks < 1:
        parser.error(f"--tasks must be ≥ 1, got {args.tasks}")
    goals = np.resize(fam.test_goals, (args.tasks, fam.test_goals.shape[1]))
    arrays, _ = StepPreferences().contexts(fam, goals, np.zeros(len(goals), dtype=int), np.array([0.5]),
                                           np.random.default_rng(0), False, False, "")
    context = StepPreferenceContext(torch.from_numpy(arrays["states"]), torch.from_numpy(arrays["actions"]).long(),
                                    torch.from_numpy(arrays["alt_actions"]).long(),
                                    torch.from_numpy(arrays["preferred"]).float())
    reference = not args.no_reference and dpt_reference.available()
    results, references = {}, {}
    for name in args.sizes:
        n_layer, n_embd, n_head, ref_size = SIZES[name]
        torch.manual_seed(0)
        model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100,
                           backbone=TransformerConfig(n_layer=n_layer, n_embd=n_embd, n_head=n_head)).eval()
        cached = run(model, context, goals, fam, use_cache=True)
        full = run(model, context, goals, fam, use_cache=False)
        results[name] = {"kv_cache": round(cached), "no_cache": round(full), "speedup": round(cached / full, 1)}
        if args.compile:
            agent = model.make_agent(use_cache=True, seed=0, compile=True)
            results[name]["compile_episode_seconds"] = round(episode(agent, context, goals, fam), 1)
            results[name]["kv_cache_compiled"] = round(len(goals) * fam.horizon / episode(agent, context, goals, fam))
        if reference and ref_size is not None:
            if ref_size not in references:
                layers, width, _ = dpt_reference.SIZES[ref_size]
                references[ref_size] = dpt_reference.deploy_env_steps_per_second(layers, width, len(goals))
            results[name]["dpt_reference"] = round(references[ref_size])
            results[name]["kv_cache_vs_reference"] = round(cached / references[ref_size], 1)
            if args.compile:
                results[name]["kv_cache_compiled_vs_reference"] = round(
                    results[name]["kv_cache_compiled"] / references[ref_size], 1)
        print(f"{name}: {results[name]}", file=sys.stderr, flush=True)
    print(json.dumps({"benchmark": "deployment_env_steps_per_second", "tasks": len(goals),
                      "horizon": fam.horizon, "torch_threads": torch.get_num_threads(),
                      "reference": "DPT DarkRoom evaluation (benchmarks/dpt_reference.py)" if reference else
                      "not run (pip install -e .[bench] for transformers)", "results": results}, indent=2))


if __name__ == "__main__":
    main()
