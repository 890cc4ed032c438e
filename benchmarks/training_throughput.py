"""Training throughput (samples/s) of the in-context policy: optimizer steps on DarkRoom-shaped batches.

    python benchmarks/training_throughput.py [--steps 20] [--threads N]

One sample is one context of H = 100 comparisons plus H query states, scored against every context
prefix 1..H in one pass (the same work per sample as DPT's training, which predicts the query's
action at all 100 prefixes). Sizes: the CPU default (3 layers, 64 hidden, batch 32), DPT's small
DarkRoom model (4 layers, 32 hidden, batch 64) and the paper's I-PRL model (6 layers, 256 hidden,
8 heads, batch 32). Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from icprl_lightning.methods.dpt import DP2TModule
from icprl_lightning.methods.icpo import ICPOModule

SIZES = {
    "default_3L_64d_b32": dict(n_layer=3, n_embd=64, n_head=4, batch=32),
    "dpt_small_4L_32d_b64": dict(n_layer=4, n_embd=32, n_head=4, batch=64),
    "paper_6L_256d_b32": dict(n_layer=6, n_embd=256, n_head=8, batch=32),
}


def batch_for(b: int, t: int = 100) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    ctx = {"states": torch.randint(0, 10, (b, t, 2), generator=g).float(),
           "actions": torch.randint(0, 5, (b, t), generator=g), "alt_actions": torch.randint(0, 5, (b, t), generator=g),
           "preferred": torch.randint(0, 2, (b, t), generator=g).float()}
    out = dict(ctx)
    out.update({f"pair_{k}": v.roll(1, 0) for k, v in ctx.items()})
    out["query_states"] = torch.randint(0, 10, (b, t, 2), generator=g).float()
    out["optimal_actions"] = torch.randint(0, 5, (b, t), generator=g)
    return out


def measure(cls, size: dict, steps: int) -> float:
    torch.manual_seed(0)
    model = cls(state_dim=2, action_dim=5, discrete=True, max_context=100,
                **{k: v for k, v in size.items() if k != "batch"})
    opt = model.configure_optimizers()
    batch = batch_for(size["batch"])
    for i in range(steps + 3):
        if i == 3:
            start = time.perf_counter()
        loss, _ = model.loss(batch)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return steps * size["batch"] / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own, = the cores); 1 avoids thread "
                             "oversubscription on a shared machine")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    results = {f"{method.__name__}/{name}": round(measure(method, size, args.steps), 1)
               for name, size in SIZES.items() for method in (ICPOModule, DP2TModule)}
    print(json.dumps({"benchmark": "training_samples_per_second", "context_length": 100,
                      "torch_threads": torch.get_num_threads(), "results": results}, indent=2))


if __name__ == "__main__":
    main()
