"""Training throughput of ICPO (optimizer steps on DarkRoom-shaped batches), beside DPT's reference setup.

    python benchmarks/training_throughput.py [--threads N] [--sizes dpt_small_4L_32d_b64 ...] [--repeats 3]
                                             [--no-reference] [--profile 1head_k100_merged]

One sample is one context of H = 100 comparisons plus its query states. Each variant of a size changes one
thing of the model's execution, never its function:

* ``heads``: attention heads (the layout is identical; DPT's reference uses 1);
* ``k``: query positions scored per context (``queries_per_context``; 100 = all, the same number of
  supervised predictions per sample as DPT's reference; k < 100 is a sequence of 100 + k tokens instead of
  200 and k predictions per sample);
* ``bf16``: bf16 autocast, what ``--trainer.precision bf16-mixed`` runs on CPU;
* ``compile``: ``torch.compile`` of the policy network (its compile time is in ``warmup_seconds``);
* ``merged``: the merged layout (``layout: merged``, ``pair_source: next``; ``models/policy.py``): each query
  state summed into the token after the comparisons it sees, so a sample is one causal pass of 100 tokens
  with 100 predictions. This one changes what the model computes (a query's state enters the sequence in
  a different slot, and it scores the context's own next comparison instead of another trajectory's):
  ``learning_speed.py`` compares what the layouts learn per second.

Beside them, ``floor``: the arithmetic any 1-head transformer of that size must do on 100 tokens, alone
(each layer's four linear maps, its causal attention and residual adds, forward and backward; no embedding,
normalization, activation, loss or optimizer; ``floor_bf16`` under bf16 autocast), and ``floor_Nhead``, the
same with the configs' N heads: attention scores and weights are T × T per head, so N heads do N times the
attention's element-wise work whatever the layout. DPT's reference does the same
arithmetic on 101 tokens, so ``floor``'s ratio to the reference bounds what any 100-token layout of this
size can reach on this machine with these matmul and attention kernels: it is the reference's speed if
everything else in its step were free.

Timing: each variant takes 3 warm-up steps (``warmup_seconds``; a compile happens there), then ``--repeats``
timed blocks of ``--steps`` optimizer steps, each block right after a block of the reference. samples/s is
the median block; ``vs_reference`` is the median ratio of adjacent blocks, so a change of this machine's
speed during a run (tens of percent, over minutes) moves both sides of each ratio alike.

Sizes: DPT's small DarkRoom model (4 layers, 32 wide, batch 64), the paper's I-PRL model (6 layers, 256
wide, batch 32) and this project's CPU default (3 layers, 64 wide, batch 32). With the ``bench`` extra
(``transformers``) installed, DPT's reference (``dpt_reference.py``) runs in the same process at the same
layers, width and batch, and each variant prints its ratio to it. Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial

import torch
import torch.nn.functional as F

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.samples import ContextSamples

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

# the configs' heads at each size (configs/*_darkroom.yaml: 4; the paper's I-PRL model: 8), in the appended layout
DEFAULT_HEADS = {"dpt_small_4L_32d_b64": 4, "paper_6L_256d_b32": 8, "default_3L_64d_b32": 4}


def batch_for(b: int, t: int = H) -> ContextSamples:
    g = torch.Generator().manual_seed(0)
    ctx = StepPreferenceContext(torch.randint(0, 10, (b, t, 2), generator=g).float(),
                                torch.randint(0, 5, (b, t), generator=g), torch.randint(0, 5, (b, t), generator=g),
                                torch.randint(0, 2, (b, t), generator=g).float())
    return ContextSamples(ctx, pair=ctx.map(lambda x: x.roll(1, 0)))


def name_of(variant: dict) -> str:
    parts = [f"{variant['heads']}head", f"k{variant.get('k', H)}"]
    return "_".join(parts + [flag for flag in ("merged", "bf16", "compile") if variant.get(flag)])


def block_rate(step: Callable[[], None], steps: int) -> float:
    """Calls of ``step`` per second over one block of ``steps`` calls."""
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return steps / (time.perf_counter() - start)


class DenseFloor(torch.nn.Module):
    """Only the linear maps and causal attention of a 1-head pre-LN block stack (see the module docstring)."""

    def __init__(self, n_layer: int, n_embd: int, n_head: int = 1) -> None:
        super().__init__()
        self.n_head = n_head
        self.layers = torch.nn.ModuleList(
            torch.nn.ModuleList([torch.nn.Linear(n_embd, 3 * n_embd), torch.nn.Linear(n_embd, n_embd),
                                 torch.nn.Linear(n_embd, 4 * n_embd), torch.nn.Linear(4 * n_embd, n_embd)])
            for _ in range(n_layer))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, c = x.shape
        nh = self.n_head
        for qkv, proj, fc, fc_out in self.layers:
            q, k, v = (z.view(b, t, nh, c // nh).transpose(1, 2) for z in qkv(x).split(c, dim=2))
            x = x + proj(F.scaled_dot_product_attention(q, k, v, is_causal=True).transpose(1, 2).reshape(b, t, c))
            x = x + fc_out(fc(x))
        return x


def floor_step(size: dict, bf16: bool, n_head: int = 1) -> Callable[[], None]:
    torch.manual_seed(0)
    model = DenseFloor(size["n_layer"], size["n_embd"], n_head)
    x = torch.randn(size["batch"], H, size["n_embd"])

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            out = model(x)
        out.float().sum().backward()

    return step


def icpo_step(size: dict, variant: dict) -> Callable[[], None]:
    torch.manual_seed(0)
    backbone = TransformerConfig(n_layer=size["n_layer"], n_embd=size["n_embd"], n_head=variant["heads"])
    model = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=H, backbone=backbone, beta=0.1, lam=1.0,
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

    return step


def measure(step: Callable[[], None], reference: Callable[[], None] | None, batch: int, predictions: int,
            steps: int, repeats: int) -> tuple[dict[str, float], list[float]]:
    """Warm ``step`` up (3 calls, timed: a compile happens there), then time ``repeats`` blocks of it, each
    right after a block of ``reference`` when given: the ratio is the median of these adjacent pairs, so a
    change of the machine's speed during the run moves both sides of a ratio alike."""
    began = time.perf_counter()
    for _ in range(3):
        step()
    out: dict[str, float] = {"warmup_seconds": round(time.perf_counter() - began, 1)}
    rates, reference_rates = [], []
    for _ in range(repeats):
        if reference is not None:
            reference_rates.append(block_rate(reference, steps))
        rates.append(block_rate(step, steps))
    samples = statistics.median(rates) * batch
    out.update({"samples_per_s": round(samples, 1), "predictions_per_sample": predictions,
                "predictions_per_s": round(samples * predictions)})
    if reference is not None:
        out["vs_reference"] = round(statistics.median(r / q for r, q in zip(rates, reference_rates, strict=True)), 2)
    return out, reference_rates


def profile(size_and_variants: tuple[dict, list[dict]], variant_name: str) -> None:
    size, variants = size_and_variants
    by_name = {name_of(variant): variant for variant in variants}
    if variant_name not in by_name:
        raise SystemExit(f"--profile: no variant {variant_name!r} at this size; choose from {sorted(by_name)}")
    step = icpo_step(size, by_name[variant_name])
    for _ in range(5):
        step()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        for _ in range(10):
            step()
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=None, help="timed steps per variant (default 20 small, 6 paper)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch intra-op threads (default: torch's own, = the cores); 1 avoids thread "
                             "oversubscription on a shared machine")
    parser.add_argument("--repeats", type=int, default=3,
                        help="timed blocks per variant, each after a block of the reference; medians are printed")
    parser.add_argument("--sizes", nargs="+", choices=sorted(SIZES), default=list(SIZES))
    parser.add_argument("--no-reference", action="store_true", help="skip DPT's reference even if installed")
    parser.add_argument("--profile", metavar="VARIANT", default=None,
                        help="instead of timing, print torch.profiler's table of 10 steps of one variant of the first "
                             "size (e.g. 1head_k100_merged), operators by their own time")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    if args.profile is not None:
        profile(SIZES[args.sizes[0]], args.profile)
        return
    with_reference = not args.no_reference and dpt_reference.available()
    results = {}
    for name in args.sizes:
        size, variants = SIZES[name]
        steps = args.steps or (20 if size["n_embd"] <= 64 else 6)
        row: dict = {}
        reference = (dpt_reference.train_step(size["n_layer"], size["n_embd"], size["batch"])
                     if with_reference and name in dpt_reference.SIZES else None)
        steps_of = [("floor", partial(floor_step, size, False), H), ("floor_bf16", partial(floor_step, size, True), H)]
        steps_of = steps_of[: 2 if size["n_embd"] > 64 else 1]  # bf16 autocast pays only at the wide size
        heads = DEFAULT_HEADS[name]
        steps_of.append((f"floor_{heads}head", partial(floor_step, size, False, heads), H))
        steps_of += [(name_of(v), partial(icpo_step, size, v), v.get("k", H)) for v in variants]
        reference_rates: list[float] = []
        for key, make_step, predictions in steps_of:
            row[key], paired = measure(make_step(), reference, size["batch"], predictions, steps, args.repeats)
            reference_rates += paired
            print(f"{name} {key}: {row[key]}", file=sys.stderr, flush=True)
        if reference is not None:
            samples = statistics.median(reference_rates) * size["batch"]
            row = {"dpt_reference": {"samples_per_s": round(samples, 1), "predictions_per_sample": H,
                                     "predictions_per_s": round(samples * H)}} | row
        row[name_of(dict(heads=heads))]["default"] = True
        results[name] = row
    print(json.dumps({"benchmark": "training_samples_per_second",
                      "command": shlex.join(["python", *sys.argv]), "method": "ICPOModule", "context_length": H,
                      "torch_threads": torch.get_num_threads(),
                      "default": "the configs' layout and head count at each size (appended, all 100 queries, "
                                 "fp32): the row marked \"default\": true",
                      "steps_per_block": args.steps or "20 (width <= 64), 6 (wider)", "repeats": args.repeats,
                      "reference": "DPT DarkRoom setup (benchmarks/dpt_reference.py)" if with_reference else
                      "not run (pip install -e .[bench] for transformers)", "results": results}, indent=2))


if __name__ == "__main__":
    main()
