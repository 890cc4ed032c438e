"""Training throughput of ICPO (optimizer steps on DarkRoom-shaped batches), beside DPT's reference setup.

    python benchmarks/training_throughput.py [--threads N] [--sizes dpt_small_4L_32d_b64 ...] [--no-reference]

One sample is one context of H = 100 comparisons plus its query states. Each variant of a size changes one
thing of the model's execution, never its function:

* ``heads``: attention heads (the layout is identical; DPT's reference uses 1);
* ``k``: query positions scored per context (``queries_per_context``; 100 = all, the same number of
  supervised predictions per sample as DPT's reference; k < 100 is a sequence of 100 + k tokens instead of
  200 and k predictions per sample);
* ``bf16``: bf16 autocast, what ``--trainer.precision bf16-mixed`` runs on CPU;
* ``compile``: ``torch.compile`` of the policy network (its compile time is printed, not counted);
* ``merged``: the merged layout (``layout: merged``, ``pair_source: next``; ``models/policy.py``): each query
  state summed into the token after the comparisons it sees, so a sample is one causal pass of 100 tokens
  with 100 predictions. This one changes what the model computes (a query's state enters the sequence in
  a different slot, and it scores the context's own next comparison instead of another trajectory's):
  ``learning_speed.py`` compares what the layouts learn per second.

Sizes: DPT's small DarkRoom model (4 layers, 32 wide, batch 64), the paper's I-PRL model (6 layers, 256
wide, batch 32) and this project's CPU default (3 layers, 64 wide, batch 32). With the ``bench`` extra
(``transformers``) installed, DPT's reference (``dpt_reference.py``) runs in the same process at the same
layers, width and batch, and each variant prints its ratio to it. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import torch

from icprl_lightning.methods.icpo import ICPOModule

try:  # run as a script (benchmarks/ on sys.path) or as a module
    import dpt_reference
except ImportError:  # pragma: no cover
    from benchmarks import dpt_reference

H = 100
SIZES = {
    "dpt_small_4L_32d_b64": (dict(n_layer=4, n_embd=32, batch=64),
                             [dict(heads=4), dict(heads=1), dict(heads=1, k=25), dict(heads=1, k=10),
                              dict(heads=4, compile=True), dict(heads=1, compile=True),
                              dict(heads=4, merged=True), dict(heads=1, merged=True),
                              dict(heads=4, merged=True, compile=True), dict(heads=1, merged=True, compile=True)]),
    "paper_6L_256d_b32": (dict(n_layer=6, n_embd=256, batch=32),
                          [dict(heads=8), dict(heads=8, bf16=True), dict(heads=1, bf16=True),
                           dict(heads=8, bf16=True, compile=True), dict(heads=8, bf16=True, k=25),
                           dict(heads=8, bf16=True, k=10, compile=True), dict(heads=8, merged=True),
                           dict(heads=8, bf16=True, merged=True), dict(heads=1, bf16=True, merged=True),
                           dict(heads=8, bf16=True, merged=True, compile=True),
                           dict(heads=1, bf16=True, merged=True, compile=True)]),
    "default_3L_64d_b32": (dict(n_layer=3, n_embd=64, batch=32), [dict(heads=4), dict(heads=1), dict(heads=1, k=25),
                                                                  dict(heads=4, merged=True)]),
}


def batch_for(b: int, t: int = H) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    ctx = {"states": torch.randint(0, 10, (b, t, 2), generator=g).float(),
           "actions": torch.randint(0, 5, (b, t), generator=g), "alt_actions": torch.randint(0, 5, (b, t), generator=g),
           "preferred": torch.randint(0, 2, (b, t), generator=g).float()}
    out = dict(ctx)
    out.update({f"pair_{k}": v.roll(1, 0) for k, v in ctx.items()})
    return out


def name_of(variant: dict) -> str:
    parts = [f"{variant['heads']}head", f"k{variant.get('k', H)}"]
    return "_".join(parts + [flag for flag in ("merged", "bf16", "compile") if variant.get(flag)])


def measure(size: dict, variant: dict, steps: int) -> dict[str, float]:
    torch.manual_seed(0)
    model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=H, n_layer=size["n_layer"],
                       n_embd=size["n_embd"], n_head=variant["heads"], beta=0.1, lam=1.0,
                       queries_per_context=variant.get("k"),
                       **(dict(layout="merged", pair_source="next") if variant.get("merged") else {})).train()
    optimizer = model.configure_optimizers()
    batch = batch_for(size["batch"])
    if variant.get("compile") and variant.get("merged"):  # its training pass is a method, not forward
        model.policy.next_step_outputs = torch.compile(model.policy.next_step_outputs)
    elif variant.get("compile"):
        model.policy = torch.compile(model.policy)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bool(variant.get("bf16"))):
            loss, _ = model.loss(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    began = time.perf_counter()
    for _ in range(3):
        step()
    warmup = time.perf_counter() - began
    start = time.perf_counter()
    for _ in range(steps):
        step()
    samples = steps * size["batch"] / (time.perf_counter() - start)
    k = variant.get("k", H)
    out = {"samples_per_s": round(samples, 1), "predictions_per_sample": k,
           "predictions_per_s": round(samples * k)}
    if variant.get("compile"):
        out["warmup_seconds_with_compile"] = round(warmup, 1)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=None, help="timed steps per variant (default 20 small, 6 paper)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own, = the cores); 1 avoids thread "
                             "oversubscription on a shared machine")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=list(SIZES))
    parser.add_argument("--no-reference", action="store_true", help="skip DPT's reference even if installed")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    reference = not args.no_reference and dpt_reference.available()
    results = {}
    for name in args.sizes:
        size, variants = SIZES[name]
        steps = args.steps or (20 if size["n_embd"] <= 64 else 6)
        row: dict = {}
        if reference and name in dpt_reference.SIZES:
            ref = dpt_reference.train_samples_per_second(size["n_layer"], size["n_embd"], size["batch"], steps)
            row["dpt_reference"] = {"samples_per_s": round(ref, 1), "predictions_per_sample": H,
                                    "predictions_per_s": round(ref * H)}
        for variant in variants:
            row[name_of(variant)] = measure(size, variant, steps)
            if "dpt_reference" in row:
                row[name_of(variant)]["vs_reference"] = round(
                    row[name_of(variant)]["samples_per_s"] / row["dpt_reference"]["samples_per_s"], 2)
            print(f"{name} {name_of(variant)}: {row[name_of(variant)]}", file=sys.stderr, flush=True)
        results[name] = row
    print(json.dumps({"benchmark": "training_samples_per_second", "method": "ICPOModule", "context_length": H,
                      "torch_threads": torch.get_num_threads(),
                      "reference": "DPT DarkRoom setup (benchmarks/dpt_reference.py)" if reference else
                      "not run (pip install -e .[bench] for transformers)", "results": results}, indent=2))


if __name__ == "__main__":
    main()
