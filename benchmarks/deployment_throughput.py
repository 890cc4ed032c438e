"""Deployment rate (env-steps/s) on batched DarkRoom tasks, with and without the KV cache, beside DPT's reference.

    python benchmarks/deployment_throughput.py [--tasks 100] [--seed 0] [--threads N] [--no-reference] [--compile]
                                               [--repeats 3]

A full episode (H = 100 steps) for each of ``--tasks`` tasks (the 20 held-out goals repeated), all in one
vector env, through the public Agent API: the first act() after reset() encodes the 100-comparison
contexts; each act() runs the query token only (cache) or re-runs the whole context plus the query (no
cache, what DPT's evaluation does every step). The rate counts the whole loop (env steps included).
Untrained weights: speed does not depend on them. With the ``bench`` extra installed, DPT's reference
evaluation (``dpt_reference.py``: a full 101-token forward per step, the same number of tasks) runs in the
same process, and each size prints its ratio to it.

Timing: every agent runs one untimed episode first (allocation, a compile), then ``--repeats`` timed episodes,
each right after a timed block of the reference (20 of its steps): env-steps/s is the median episode, and
``kv_cache_vs_reference`` the median ratio of these adjacent pairs, so a change of the machine's speed during a
run (tens of percent over minutes here) moves both sides of a ratio alike. ``--compile`` adds the cached agent
with its query step under ``torch.compile`` (``load_agent(..., compile=True)``): its untimed first episode compiles
(its seconds printed as ``compile_episode_seconds``), as the reference is timed after a warm-up forward.
Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import time
from functools import partial

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


def timed(agent, context: StepPreferenceContext, goals: np.ndarray, fam: DarkRoomFamily, repeats: int,
          reference=None) -> tuple[float, float | None, float, list[float]]:
    """(median env-steps/s, median ratio to ``reference`` or None, the untimed first episode's seconds, the
    reference's rates).

    ``reference`` is a callable returning the reference's env-steps/s over one block; each timed episode runs
    right after one of its blocks."""
    first = episode(agent, context, goals, fam)
    rates, reference_rates = [], []
    for _ in range(repeats):
        if reference is not None:
            reference_rates.append(reference())
        rates.append(len(goals) * fam.horizon / episode(agent, context, goals, fam))
    ratio = statistics.median(r / q for r, q in zip(rates, reference_rates, strict=True)) if reference_rates else None
    return statistics.median(rates), ratio, first, reference_rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--tasks", type=int, default=100, help="tasks deployed at once (held-out goals repeated)")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=list(SIZES))
    parser.add_argument("--no-reference", action="store_true", help="skip DPT's reference even if installed")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compile", action="store_true", help="also time the cached agent under torch.compile")
    parser.add_argument("--repeats", type=int, default=3,
                        help="timed episodes per agent, each after a block of the reference; medians are printed")
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
    with_reference = not args.no_reference and dpt_reference.available()
    results = {}
    for name in args.sizes:
        n_layer, n_embd, n_head, ref_size = SIZES[name]
        torch.manual_seed(0)
        model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100,
                           backbone=TransformerConfig(n_layer=n_layer, n_embd=n_embd, n_head=n_head)).eval()
        reference = None
        if with_reference and ref_size is not None:
            layers, width, _ = dpt_reference.SIZES[ref_size]
            reference = partial(dpt_reference.deploy_env_steps_per_second, layers, width, len(goals))
        row: dict = {}
        cached, ratio, _, reference_rates = timed(model.make_agent(use_cache=True, seed=0), context, goals, fam,
                                                  args.repeats, reference)
        full, _, _, _ = timed(model.make_agent(use_cache=False, seed=0), context, goals, fam, 1)
        row.update(kv_cache=round(cached), no_cache=round(full), speedup=round(cached / full, 1))
        if args.compile:
            compiled, compiled_ratio, first, more = timed(model.make_agent(use_cache=True, seed=0, compile=True),
                                                          context, goals, fam, args.repeats, reference)
            reference_rates += more
            row.update(compile_episode_seconds=round(first, 1), kv_cache_compiled=round(compiled))
        if ratio is not None:
            row.update(dpt_reference=round(statistics.median(reference_rates)), kv_cache_vs_reference=round(ratio, 1))
            if args.compile:
                row["kv_cache_compiled_vs_reference"] = round(compiled_ratio, 1)
        results[name] = row
        print(f"{name}: {results[name]}", file=sys.stderr, flush=True)
    print(json.dumps({"benchmark": "deployment_env_steps_per_second",
                      "command": shlex.join(["python", *sys.argv]), "tasks": len(goals),
                      "horizon": fam.horizon, "torch_threads": torch.get_num_threads(),
                      "repeats": args.repeats,
                      "reference": "DPT DarkRoom evaluation (benchmarks/dpt_reference.py)" if with_reference else
                      "not run (pip install -e .[bench] for transformers)", "results": results}, indent=2))


if __name__ == "__main__":
    main()
