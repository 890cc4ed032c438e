"""ICPO played online on held-out dueling-bandit problems, beside Double Thompson Sampling. Prints JSON.

    python scripts/online_bandit.py --ckpt runs/reproduce/bandit/runs/ICPO-seed0/version_0/checkpoints/last.ckpt \
        [--config configs/icpo_bandit.yaml] [--rounds 200] [--seeds 0 1 2] [--n-problems 200]

Both start from no comparisons. Each round ICPO (``online.OnlineAgent``, greedy as the checkpoint's
default) proposes a duel by the default pair rule — its argmax arm against a uniformly random other arm,
the rule of the offline evaluation (``evaluation/duels.py``) — the family's Bradley–Terry oracle labels
it (``LinearDuelingBanditFamily.sample_labels``) and the answered duel is appended to the agent's KV
cache as one token. DTS (``families/dueling_bandit/dts.run_dts``) selects, is labelled by the same BT
preference matrix, and updates. Round r's duel is chosen after r − 1 comparisons (ICPO's first duel is
its output on an empty context, a query position training never scores).

Each duel is scored by the weak regret min(R* − R(a), R* − R(a')) (``evaluation.duels.regret_curve``).
Per problem, the curves are averaged over ``--seeds`` (the random second arm, the labels and DTS's
draws; ``evaluation.duels.seed_streams``); reported as mean ± standard error over the problems: the
cumulative weak regret (sum over rounds) and the final one (round ``--rounds``). The held-out problems are
the ``test_theta`` of the config's dataset (generated if missing).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.evaluation.duels import Duels, regret_curve, seed_streams
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.dts import run_dts
from icprl_lightning.metrics import mean_sem
from icprl_lightning.online import OnlineAgent


def icpo_online_duels(agent: OnlineAgent, family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int,
                      rng: np.random.Generator) -> Duels:
    """``rounds`` duels per problem, each proposed after the previous ones were answered: ``[P, rounds]`` each."""
    n = len(theta)

    def label(states: torch.Tensor, first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(family.sample_labels(theta, first.cpu().numpy(), second.cpu().numpy(), rng))

    agent.reset(n)
    obs = torch.zeros(n, 0)  # a bandit has no state
    duels = [agent.step(obs, label)[:2] for _ in range(rounds)]
    return torch.stack([d[0].cpu() for d in duels], 1), torch.stack([d[1].cpu() for d in duels], 1)


def dts_online_duels(family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int,
                     rng: np.random.Generator) -> Duels:
    played = run_dts(family.preference_matrix(theta), rounds, rng, alpha=family.dts_alpha)
    return torch.from_numpy(played["arms_first"]), torch.from_numpy(played["arms_second"])


def summarize(curve: torch.Tensor) -> dict[str, float]:
    """Cumulative (sum over rounds) and final weak regret, mean ± standard error over problems."""
    values = curve.double().numpy()
    cumulative, cumulative_sem = mean_sem(values.sum(axis=1))
    final, final_sem = mean_sem(values[:, -1])
    return {"cumulative_weak_regret": cumulative, "cumulative_weak_regret_sem": cumulative_sem,
            "final_weak_regret": final, "final_weak_regret_sem": final_sem}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ckpt", required=True, help="an ICPO dueling-bandit checkpoint")
    parser.add_argument("--config", action="append", default=None,
                        help="the config(s) of the checkpoint's dataset (default configs/icpo_bandit.yaml)")
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--n-problems", type=int, default=None, help="the first N held-out problems (default all)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    dm = datamodule_from_config(*(args.config or ["configs/icpo_bandit.yaml"]), progress=False)
    if not isinstance(dm.family, LinearDuelingBanditFamily):
        parser.error(f"the config's family is {type(dm.family).__name__}, not a LinearDuelingBanditFamily")
    dm.prepare_data()
    family = dm.family
    theta = np.asarray(dm.load()["tasks"]["test_theta"])[:args.n_problems]
    probe = OnlineAgent.load(args.ckpt)
    policy = probe.policy
    if policy.state_dim != 0 or policy.action_spec != family.action_spec:
        parser.error(f"{args.ckpt} is not a policy of this bandit (state_dim {policy.state_dim}, actions "
                     f"{policy.action_spec}; the family has state_dim 0 and {family.action_spec})")
    if not 1 <= args.rounds <= policy.transformer.max_context:
        parser.error(f"--rounds must be in [1, {policy.transformer.max_context}] (the model's max_context), "
                     f"got {args.rounds}")
    rewards = torch.from_numpy(family.expected_rewards(theta))
    curves: dict[str, list[torch.Tensor]] = {"icpo": [], "dts": []}
    for seed in args.seeds:
        label_rng, dts_rng = seed_streams(seed)
        agent = OnlineAgent.load(args.ckpt, seed=seed)
        curves["icpo"].append(regret_curve(rewards, icpo_online_duels(agent, family, theta, args.rounds, label_rng)))
        curves["dts"].append(regret_curve(rewards, dts_online_duels(family, theta, args.rounds, dts_rng)))
    out = {"checkpoint": str(args.ckpt), "dataset": str(dm.path), "problems": len(theta), "rounds": args.rounds,
           "seeds": args.seeds, "greedy": probe.greedy,
           **{name: summarize(torch.stack(c).double().mean(0)) for name, c in curves.items()},
           "seconds": round(time.perf_counter() - started, 1)}
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
