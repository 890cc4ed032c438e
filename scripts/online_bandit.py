"""ICPO played online on held-out dueling-bandit problems, beside Double Thompson Sampling. Prints JSON.

    python scripts/online_bandit.py --ckpt runs/reproduce/bandit/runs/ICPO-seed0/version_0/checkpoints/last.ckpt \
        [--ckpt CKPT ...] [--config configs/icpo_bandit.yaml] [--rounds 200] [--seeds 0 1 2] [--n-problems 200] \
        [--rule action_uniform --rule top_two ...] [--labels own|flipped|random] [--figure PNG]

Both start from no comparisons. Each round ICPO (``online.OnlineAgent``, greedy as the checkpoint's
default) proposes a duel by a pair rule (``--rule``, ``online.PAIR_RULES``; default ``action_uniform``: its
argmax arm against a uniformly random other arm, the rule of the offline evaluation, ``evaluation/duels.py``),
the family's Bradley–Terry oracle labels it (``LinearDuelingBanditFamily.sample_labels``) and the answered
duel is appended to the agent's KV cache as one token. DTS (``families/dueling_bandit/dts.run_dts``)
selects, is labelled by the same BT preference matrix, and updates. Round r's duel is chosen after r − 1
comparisons (ICPO's first duel is its output on an empty context, a query position training never scores).

Two regrets per round:

* the **weak regret** of the duel played, min(R* − R(a), R* − R(a')) (``evaluation.duels.regret_curve``):
  the online dueling-bandit objective, which charges exploration;
* the **recommendation regret** R* − R(â_r) of the arm the agent would pick after r answered queries
  (ICPO's greedy ``act``; DTS's first arm of round r + 1): what a query buys, the measure of active querying
  (``--rule``: which pair to ask at the same query budget). ``queries_to_reach[target]`` is the first round
  from which the mean recommendation regret stays at or below ``target`` until ``--rounds`` (``null``: never).

``--labels flipped`` / ``random`` is the online label diagnostic: the oracle's answers are inverted, or
replaced by fair coins, before the agent sees them (DTS keeps the true ones). If ICPO's regret does not
suffer, its online gains do not come from the labels.

Per problem, the curves are averaged over ``--seeds`` (the pair rule's draws, the labels and DTS's draws;
``evaluation.duels.seed_streams``), then over problems; with several ``--ckpt`` (training seeds) each
checkpoint is reported and the mean ± standard error over checkpoints is ``mean``. The held-out problems
are the ``test_theta`` of the config's dataset (generated if missing).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.evaluation.duels import seed_streams
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.dts import run_dts
from icprl_lightning.metrics import mean_sem, mean_sem_or_none, weak_regret
from icprl_lightning.online import PAIR_RULES, OnlineAgent

BUDGETS = (10, 25, 50, 100, 200)
TARGETS = (0.4, 0.35, 0.3, 0.25)
LABELS = ("own", "flipped", "random")


def icpo_online(agent: OnlineAgent, family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int,
                rng: np.random.Generator, labels: str = "own") -> dict[str, torch.Tensor]:
    """``rounds`` duels per problem, each proposed after the previous ones were answered, and the greedy arm
    after each answer: ``first``, ``second``, ``recommended`` each ``[P, rounds]``."""
    n = len(theta)

    def label(states: torch.Tensor, first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        y = family.sample_labels(theta, first.cpu().numpy(), second.cpu().numpy(), rng)
        if labels == "flipped":
            y = 1 - y
        elif labels == "random":
            y = rng.integers(0, 2, size=n).astype(y.dtype)
        return torch.from_numpy(y)

    agent.reset(n)
    obs = torch.zeros(n, 0)  # a bandit has no state
    first, second, recommended = [], [], []
    for _ in range(rounds):
        a, b, _ = agent.step(obs, label)
        first.append(a.cpu())
        second.append(b.cpu())
        recommended.append(agent.act(obs).cpu())
    return {k: torch.stack(v, 1) for k, v in (("first", first), ("second", second), ("recommended", recommended))}


def dts_online(family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int, rng: np.random.Generator
               ) -> dict[str, torch.Tensor]:
    """DTS's duels over ``rounds + 1`` rounds; its recommendation after r comparisons is round r + 1's first arm."""
    played = run_dts(family.preference_matrix(theta), rounds + 1, rng, alpha=family.dts_alpha)
    first, second = torch.from_numpy(played["arms_first"]), torch.from_numpy(played["arms_second"])
    return {"first": first[:, :rounds], "second": second[:, :rounds], "recommended": first[:, 1:]}


def regrets(rewards: torch.Tensor, play: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Weak regret of each duel and recommendation regret after each answer, ``[P, rounds]`` each."""
    p, r = play["first"].shape
    flat = rewards.repeat_interleave(r, dim=0)
    out = {"weak": weak_regret(flat, play["first"].reshape(-1), play["second"].reshape(-1))}
    rec = play["recommended"].reshape(-1)
    out["recommendation"] = weak_regret(flat, rec, rec)
    return {k: v.reshape(p, r).double() for k, v in out.items()}


def summarize(curves: dict[str, torch.Tensor]) -> dict:
    """Mean ± sem over problems: cumulative and final weak regret, recommendation regret at the budgets and
    its mean curve, and the first round reaching each target."""
    weak, rec = curves["weak"].numpy(), curves["recommendation"].numpy()
    out = {}
    for key, values in (("cumulative_weak_regret", weak.sum(1)), ("final_weak_regret", weak[:, -1])):
        out[key], out[f"{key}_sem"] = mean_sem(values)
    budgets = [b for b in BUDGETS if b <= rec.shape[1]]
    out["recommendation_regret"] = {str(b): dict(zip(("mean", "sem"), mean_sem(rec[:, b - 1]), strict=True))
                                    for b in budgets}
    mean_curve = rec.mean(0)
    out["recommendation_curve"] = [round(float(v), 5) for v in mean_curve]
    out["queries_to_reach"] = queries_to_reach(mean_curve)
    return out


def queries_to_reach(curve) -> dict[str, int | None]:
    """Per target: the first round r (1-based) with curve[r:] ≤ target throughout, ``None`` if the last is above."""
    curve = np.asarray(curve)
    out = {}
    for t in TARGETS:
        above = np.flatnonzero(curve > t)
        out[str(t)] = (1 if len(above) == 0 else int(above[-1]) + 2) if curve[-1] <= t else None
    return out


def over_checkpoints(per_ckpt: list[dict]) -> dict:
    """Mean ± sem over training seeds of every scalar of ``summarize`` (budgets included; sem ``None`` for one)."""
    stats = mean_sem_or_none
    out = {}
    for key in ("cumulative_weak_regret", "final_weak_regret"):
        out[key], out[f"{key}_sem"] = stats([s[key] for s in per_ckpt])
    budgets = per_ckpt[0]["recommendation_regret"]
    out["recommendation_regret"] = {b: dict(zip(("mean", "sem"), stats(
        [s["recommendation_regret"][b]["mean"] for s in per_ckpt]), strict=True)) for b in budgets}
    curve = np.mean([s["recommendation_curve"] for s in per_ckpt], 0)
    out["recommendation_curve"] = [round(float(v), 5) for v in curve]
    out["queries_to_reach"] = queries_to_reach(out["recommendation_curve"])
    out["queries_to_reach_per_seed"] = {str(t): [s["queries_to_reach"][str(t)] for s in per_ckpt] for t in TARGETS}
    return out


def figure(out: dict, path: Path) -> None:
    """Recommendation regret vs answered queries, one line per pair rule (mean over training seeds), DTS dashed."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.6), layout="tight")
    ax = fig.subplots()
    for i, (rule, result) in enumerate(out["icpo"].items()):
        curve = result["mean"]["recommendation_curve"]
        ax.plot(range(1, len(curve) + 1), curve, color=f"C{i}", label=f"ICPO, {rule} pairs")
    dts = out["dts"]["recommendation_curve"]
    ax.plot(range(1, len(dts) + 1), dts, color="k", linestyle="--", label="DTS")
    ax.set_xlabel("answered queries")
    ax.set_ylabel("regret of the recommended arm")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"online dueling bandits, {out['problems']} held-out problems, labels: {out['labels']} "
                 f"({len(out['checkpoints'])} training seeds)", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ckpt", required=True, action="append",
                        help="an ICPO dueling-bandit checkpoint (repeat for several training seeds)")
    parser.add_argument("--config", action="append", default=None,
                        help="the config(s) of the checkpoint's dataset (default configs/icpo_bandit.yaml)")
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--n-problems", type=int, default=None, help="the first N held-out problems (default all)")
    parser.add_argument("--rule", action="append", choices=sorted(PAIR_RULES), default=None,
                        help="ICPO's pair rule (repeat to compare rules; default action_uniform)")
    parser.add_argument("--labels", choices=LABELS, default="own", help="the online label diagnostic")
    parser.add_argument("--figure", type=Path, default=None, help="write the recommendation-regret figure here")
    args = parser.parse_args(argv)
    rules = args.rule or ["action_uniform"]
    started = time.perf_counter()
    dm = datamodule_from_config(*(args.config or ["configs/icpo_bandit.yaml"]), progress=False)
    if not isinstance(dm.family, LinearDuelingBanditFamily):
        parser.error(f"the config's family is {type(dm.family).__name__}, not a LinearDuelingBanditFamily")
    dm.prepare_data()
    family = dm.family
    theta = np.asarray(dm.load()["tasks"]["test_theta"])[:args.n_problems]
    loaded = {ckpt: OnlineAgent.load(ckpt) for ckpt in args.ckpt}  # read once; each seed below reuses the policy
    for ckpt, probe in loaded.items():
        policy = probe.policy
        if policy.state_dim != 0 or policy.action_spec != family.action_spec:
            parser.error(f"{ckpt} is not a policy of this bandit (state_dim {policy.state_dim}, actions "
                         f"{policy.action_spec}; the family has state_dim 0 and {family.action_spec})")
        if not 1 <= args.rounds <= policy.transformer.max_context:
            parser.error(f"--rounds must be in [1, {policy.transformer.max_context}] (the model's max_context), "
                         f"got {args.rounds}")
    rewards = torch.from_numpy(family.expected_rewards(theta))

    def seed_mean(play) -> dict[str, torch.Tensor]:
        per_seed = [regrets(rewards, play(seed)) for seed in args.seeds]
        return {k: torch.stack([c[k] for c in per_seed]).mean(0) for k in per_seed[0]}

    icpo = {}
    for rule in rules:
        per_ckpt = []
        for ckpt in args.ckpt:
            def play(seed: int, ckpt: str = ckpt, rule: str = rule) -> dict[str, torch.Tensor]:
                probe = loaded[ckpt]
                agent = OnlineAgent(probe.policy, greedy=probe.greedy, seed=seed, pair_rule=PAIR_RULES[rule]())
                return icpo_online(agent, family, theta, args.rounds, seed_streams(seed)[0], args.labels)
            per_ckpt.append(summarize(seed_mean(play)))
        icpo[rule] = {"mean": over_checkpoints(per_ckpt), "per_checkpoint": per_ckpt}
    dts = summarize(seed_mean(lambda seed: dts_online(family, theta, args.rounds, seed_streams(seed)[1])))
    out = {"checkpoints": [str(c) for c in args.ckpt], "dataset": str(dm.path), "problems": len(theta),
           "rounds": args.rounds, "seeds": args.seeds, "labels": args.labels, "icpo": icpo, "dts": dts,
           "seconds": round(time.perf_counter() - started, 1)}
    if args.figure:
        figure(out, args.figure)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
