"""The speed reference: DPT's published DarkRoom training and evaluation setup, rebuilt here.

Its published configuration: a Hugging Face GPT-2 backbone with one attention head and no dropout, one
linear embedding of each (s, a, s', r) transition, the query state as the first of 1 + H = 101 causal
tokens, an action prediction at every context position (H = 100 per sample), AdamW; its offline evaluation
re-runs the whole sequence at every step (no KV cache, no ``torch.no_grad``), 100 tasks batched.

    python benchmarks/dpt_reference.py [--threads N]   # needs the bench extra: pip install -e .[bench]

``training_throughput.py`` and ``deployment_throughput.py`` import ``train_step`` and
``deploy_env_steps_per_second`` to print it beside this project's numbers, measured in the same process.
Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import torch

STATE_DIM, N_ACTIONS, HORIZON = 2, 5, 100
SIZES = {"dpt_small_4L_32d_b64": (4, 32, 64), "paper_6L_256d_b32": (6, 256, 32)}


def available() -> bool:
    try:
        import transformers  # noqa: F401
    except ImportError:
        return False
    return True


class DPTReference(torch.nn.Module):
    def __init__(self, n_layer: int, n_embd: int) -> None:
        super().__init__()
        from transformers import GPT2Config, GPT2Model

        config = GPT2Config(n_positions=4 * (1 + HORIZON), n_embd=n_embd, n_layer=n_layer, n_head=1,
                            resid_pdrop=0.0, embd_pdrop=0.0, attn_pdrop=0.0, use_cache=False)
        self.backbone = GPT2Model(config)
        self.embed = torch.nn.Linear(2 * STATE_DIM + N_ACTIONS + 1, n_embd)
        self.head = torch.nn.Linear(n_embd, N_ACTIONS)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:  # (B, 1 + H, 2S + A + 1) -> (B, 1 + H, A)
        return self.head(self.backbone(inputs_embeds=self.embed(tokens)).last_hidden_state)


def _tokens(batch: int) -> torch.Tensor:
    return torch.rand(batch, 1 + HORIZON, 2 * STATE_DIM + N_ACTIONS + 1, generator=torch.Generator().manual_seed(0))


def train_step(n_layer: int, n_embd: int, batch: int) -> Callable[[], None]:
    """One optimizer step of the reference on a fixed batch, warmed up (3 steps already taken)."""
    torch.manual_seed(0)
    model = DPTReference(n_layer, n_embd)
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-4)
    tokens = _tokens(batch)
    labels = torch.randint(0, N_ACTIONS, (batch * HORIZON,), generator=torch.Generator().manual_seed(1))

    def step() -> None:
        logits = model(tokens)[:, 1:]  # one prediction per context position
        loss = torch.nn.functional.cross_entropy(logits.reshape(-1, N_ACTIONS), labels)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    for _ in range(3):
        step()
    return step


def train_samples_per_second(n_layer: int, n_embd: int, batch: int, steps: int) -> float:
    step = train_step(n_layer, n_embd, batch)
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return steps * batch / (time.perf_counter() - start)


def deploy_env_steps_per_second(n_layer: int, n_embd: int, tasks: int = 100, steps: int = 20) -> float:
    """One evaluation step = one full forward of every task's 101-token sequence (as its evaluation does)."""
    torch.manual_seed(0)
    model = DPTReference(n_layer, n_embd).eval()
    tokens = _tokens(tasks)
    model(tokens)
    start = time.perf_counter()
    for _ in range(steps):
        model(tokens)
    return steps * tasks / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's own)")
    parser.add_argument("--tasks", type=int, default=100)
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    out = {"reference": "DPT DarkRoom setup (GPT-2, 1 head, 101 causal tokens, AdamW)",
           "torch_threads": torch.get_num_threads()}
    for name, (n_layer, n_embd, batch) in SIZES.items():
        out[f"train_{name}_samples_per_s"] = round(train_samples_per_second(n_layer, n_embd, batch,
                                                                            20 if n_embd <= 64 else 8), 1)
        out[f"deploy_{name}_env_steps_per_s"] = round(deploy_env_steps_per_second(n_layer, n_embd, args.tasks), 1)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
