"""ICPO played online on held-out dueling-bandit problems, beside Double Thompson Sampling and the feature-aware
baselines MaxInP and BT Thompson sampling.

All start from no comparisons. Each round ICPO (``online.OnlineAgent``, greedy as the checkpoint's default)
proposes a duel by a pair rule (``online.PAIR_RULES``; default ``action_uniform``: its argmax arm against a
uniformly random other arm, the rule of the offline evaluation, ``evaluation/duels.py``), the family's
Bradley–Terry oracle labels it (``LinearDuelingBanditFamily.sample_labels``) and the answered duel is
appended to the agent's KV cache as one token. DTS (``families/dueling_bandit/dts.run_dts``) selects, is
labelled by the same BT preference matrix, and updates; so do MaxInP and BT Thompson sampling
(``linear_baselines.run_online``), which model the arm features, with the knobs ``tuning.TUNED`` chose on
training problems (MaxInP β = 0.1, prior variance 0.01; BT Thompson sampling prior variance 1.0, posterior
scale 0.1; ``evaluation.duels``). Round r's duel is chosen after r − 1 comparisons (ICPO's first duel is
its output on an empty context, a query position training never scores).

Three regrets per round:

* the **weak regret** of the duel played, min(R* − R(a), R* − R(a')) (``metrics.weak_regret``): the online
  dueling-bandit objective, which charges exploration;
* the **strong regret** of the duel played, ((R* − R(a)) + (R* − R(a'))) / 2 (``metrics.strong_regret``, the
  standard average of the two gaps), which charges both arms (ICPO's default pair rule pays for its uniformly
  random second arm here);
* the **recommendation regret** R* − R(â_r) of the arm the agent would pick after r answered queries (ICPO's
  greedy ``act``; DTS's first arm of round r + 1; MaxInP's and BT Thompson sampling's ``recommend``, the best
  arm under their estimate): what a query buys, the measure of active querying (the
  pair rules: which pair to ask at the same query budget). ``queries_to_reach[target]`` is the first round
  from which the mean recommendation regret stays at or below ``target`` until the last round (``None``:
  never).

Algorithm Distillation on DTS's duels (``ad_checkpoints``; ``methods/ad.py`` with ``context_kind:
step_preference``, docs/ad_bandit.md) is another row, ``ad``: its ``DuelHistoryAgent`` samples each duel from the
model (AD's own pair; no pair rule), the same BT oracle answers, the answered duel enters its KV cache, and like
DTS its recommendation after r answers is the first arm of duel r + 1 (so it plays ``rounds + 1`` duels and needs
``max_context >= rounds + 1``). Its draws are ICPO's streams (the torch generator seeded by the episode seed, the
labels from ``seed_streams``' first generator).

``labels="flipped"`` / ``"random"`` is the online label diagnostic: the oracle's answers are inverted, or
replaced by fair coins, before the agent sees them (the baselines keep the true ones). If ICPO's regret does
not suffer, its online gains do not come from the labels.

Per problem, the curves are averaged over the episode seeds (the pair rule's draws, the labels and DTS's
draws, ``evaluation.duels.seed_streams``; the baselines' own, ``evaluation.duels.baseline_seeds``), then over
problems; with several checkpoints (training seeds)
each checkpoint is reported and the mean ± standard error over checkpoints is ``mean``. The held-out
problems are the ``test_theta`` of the dataset.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.base import HeldOutEvaluation, Run
from icprl_lightning.evaluation.duels import baseline_seeds, linear_learner, seed_streams
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.dts import run_dts
from icprl_lightning.families.dueling_bandit.linear_baselines import run_online
from icprl_lightning.io import save_figure
from icprl_lightning.methods.ad import DuelHistoryAgent
from icprl_lightning.metrics import mean_sem, mean_sem_or_none, strong_regret, weak_regret
from icprl_lightning.online import PAIR_RULES, OnlineAgent

BUDGETS = (10, 25, 50, 100, 200)
TARGETS = (0.4, 0.35, 0.3, 0.25)
LABELS = ("own", "flipped", "random")
ONLINE_BASELINES = ("maxinp", "bt_thompson")
REGRET_KEYS = ("cumulative_weak_regret", "final_weak_regret", "cumulative_strong_regret", "final_strong_regret")


def oracle_labeler(family: LinearDuelingBanditFamily, theta: np.ndarray, rng: np.random.Generator,
                   labels: str = "own"):
    """``label(states, first, second) -> y [P]``: the family's BT answers for ``theta``'s problems, or (``labels``)
    their inverse or fair coins."""
    if labels not in LABELS:
        raise ValueError(f"labels must be one of {', '.join(LABELS)}, got {labels!r}")
    n = len(theta)

    def label(states: torch.Tensor, first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        y = family.sample_labels(theta, first.cpu().numpy(), second.cpu().numpy(), rng)
        if labels == "flipped":
            y = 1 - y
        elif labels == "random":
            y = rng.integers(0, 2, size=n).astype(y.dtype)
        return torch.from_numpy(y)

    return label


def icpo_online(agent: OnlineAgent, family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int,
                rng: np.random.Generator, labels: str = "own") -> dict[str, torch.Tensor]:
    """``rounds`` duels per problem, each proposed after the previous ones were answered, and the greedy arm
    after each answer: ``first``, ``second``, ``recommended`` each ``[P, rounds]``."""
    label = oracle_labeler(family, theta, rng, labels)
    n = len(theta)
    agent.reset(n)
    obs = torch.zeros(n, 0)  # a bandit has no state
    first, second, recommended = [], [], []
    for _ in range(rounds):
        a, b, _ = agent.step(obs, label)
        first.append(a.cpu())
        second.append(b.cpu())
        recommended.append(agent.act(obs).cpu())
    return {k: torch.stack(v, 1) for k, v in (("first", first), ("second", second), ("recommended", recommended))}


def ad_online(agent: DuelHistoryAgent, family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int,
              rng: np.random.Generator, labels: str = "own") -> dict[str, torch.Tensor]:
    """AD's ``rounds + 1`` duels per problem from an empty context, each answered and observed before the next
    (the last one only proposed): ``first``, ``second`` ``[P, rounds]`` and, as for DTS, ``recommended`` = the
    first arm of the next duel."""
    label = oracle_labeler(family, theta, rng, labels)
    n = len(theta)
    agent.reset(n)
    obs = torch.zeros(n, 0)  # a bandit has no state
    first, second = [], []
    for r in range(rounds + 1):
        a, b = agent.propose(obs)
        first.append(a.cpu())
        second.append(b.cpu())
        if r < rounds:
            agent.observe(obs, a, b, label(obs, a, b))
    first_t, second_t = torch.stack(first, 1), torch.stack(second, 1)
    return {"first": first_t[:, :rounds], "second": second_t[:, :rounds], "recommended": first_t[:, 1:]}


def dts_online(family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int, rng: np.random.Generator
               ) -> dict[str, torch.Tensor]:
    """DTS's duels over ``rounds + 1`` rounds; its recommendation after r comparisons is round r + 1's first arm."""
    played = run_dts(family.preference_matrix(theta), rounds + 1, rng, alpha=family.dts_alpha)
    first, second = torch.from_numpy(played["arms_first"]), torch.from_numpy(played["arms_second"])
    return {"first": first[:, :rounds], "second": second[:, :rounds], "recommended": first[:, 1:]}


def linear_online(family: LinearDuelingBanditFamily, theta: np.ndarray, rounds: int, name: str,
                  seed: np.random.SeedSequence) -> dict[str, torch.Tensor]:
    """The feature-aware baseline ``name`` (``ONLINE_BASELINES``) over ``rounds`` rounds: its duels and its
    ``recommend``-ed arm after each answer; the learner and the labels draw from two children of ``seed``."""
    if name not in ONLINE_BASELINES:
        raise ValueError(f"an online baseline is one of {', '.join(ONLINE_BASELINES)}, got {name!r}")
    learner_seed, label_seed = seed.spawn(2)
    learner = linear_learner(name, family, len(theta), np.random.default_rng(learner_seed))
    played = run_online(learner, family.preference_matrix(theta), rounds, np.random.default_rng(label_seed),
                        recommend=True)
    return {"first": torch.from_numpy(played["arms_first"]), "second": torch.from_numpy(played["arms_second"]),
            "recommended": torch.from_numpy(played["recommended"])}


def regrets(rewards: torch.Tensor, play: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Weak and strong regret of each duel and recommendation regret after each answer, ``[P, rounds]`` each."""
    p, r = play["first"].shape
    flat = rewards.repeat_interleave(r, dim=0)
    first, second = play["first"].reshape(-1), play["second"].reshape(-1)
    out = {"weak": weak_regret(flat, first, second), "strong": strong_regret(flat, first, second)}
    rec = play["recommended"].reshape(-1)
    out["recommendation"] = weak_regret(flat, rec, rec)
    return {k: v.reshape(p, r).double() for k, v in out.items()}


def queries_to_reach(curve: Sequence[float]) -> dict[str, int | None]:
    """Per target: the first round r (1-based) with curve[r:] ≤ target throughout, ``None`` if the last is above."""
    curve = np.asarray(curve)
    out = {}
    for t in TARGETS:
        above = np.flatnonzero(curve > t)
        out[str(t)] = (1 if len(above) == 0 else int(above[-1]) + 2) if curve[-1] <= t else None
    return out


def summarize(curves: dict[str, torch.Tensor]) -> dict[str, Any]:
    """Mean ± sem over problems: cumulative and final weak and strong regret, recommendation regret at the
    budgets and its mean curve, and the first round reaching each target."""
    rec = curves["recommendation"].numpy()
    out: dict[str, Any] = {}
    for regret in ("weak", "strong"):
        values = curves[regret].numpy()
        for key, per_problem in ((f"cumulative_{regret}_regret", values.sum(1)),
                                 (f"final_{regret}_regret", values[:, -1])):
            out[key], out[f"{key}_sem"] = mean_sem(per_problem)
    budgets = [b for b in BUDGETS if b <= rec.shape[1]]
    out["recommendation_regret"] = {str(b): dict(zip(("mean", "sem"), mean_sem(rec[:, b - 1]), strict=True))
                                    for b in budgets}
    mean_curve = rec.mean(0)
    out["recommendation_curve"] = [round(float(v), 5) for v in mean_curve]
    out["queries_to_reach"] = queries_to_reach(mean_curve)
    return out


def over_checkpoints(per_ckpt: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean ± sem over training seeds of every scalar of ``summarize`` (budgets included; sem ``None`` for one)."""
    out: dict[str, Any] = {}
    for key in REGRET_KEYS:
        out[key], out[f"{key}_sem"] = mean_sem_or_none([s[key] for s in per_ckpt])
    budgets = per_ckpt[0]["recommendation_regret"]
    out["recommendation_regret"] = {b: dict(zip(("mean", "sem"), mean_sem_or_none(
        [s["recommendation_regret"][b]["mean"] for s in per_ckpt]), strict=True)) for b in budgets}
    curve = np.mean([s["recommendation_curve"] for s in per_ckpt], 0)
    out["recommendation_curve"] = [round(float(v), 5) for v in curve]
    out["queries_to_reach"] = queries_to_reach(out["recommendation_curve"])
    out["queries_to_reach_per_seed"] = {str(t): [s["queries_to_reach"][str(t)] for s in per_ckpt] for t in TARGETS}
    return out


def evaluate_online_bandit(dm: Any, checkpoints: Sequence[str], rules: Sequence[str] = ("action_uniform",),
                           labels: str = "own", seeds: Sequence[int] = (0,), rounds: int = 200,
                           n_problems: int | None = None, ad_checkpoints: Sequence[str] = ()) -> dict[str, Any]:
    """ICPO's online regrets per pair rule (per checkpoint and over checkpoints) and those of DTS and the
    ``ONLINE_BASELINES`` (keys ``dts``, ``maxinp``, ``bt_thompson``), on ``dm``'s held-out problems (the first
    ``n_problems``, default all); with ``ad_checkpoints`` (AD on DTS's duels, one per training seed) also the row
    ``ad`` (``mean`` over them and ``per_checkpoint``). ``dm`` is a prepared DataModule of a
    ``LinearDuelingBanditFamily``. Returns the JSON-ready result (module docstring)."""
    if labels not in LABELS:
        raise ValueError(f"--labels must be one of {', '.join(LABELS)}, got {labels!r}")
    unknown = sorted(set(rules) - set(PAIR_RULES))
    if unknown:
        raise ValueError(f"--rule {unknown[0]!r} is not a pair rule; choose from {', '.join(sorted(PAIR_RULES))}")
    family = dm.family
    if not isinstance(family, LinearDuelingBanditFamily):
        raise ValueError(f"the config's family is {type(family).__name__}, not a LinearDuelingBanditFamily")
    if n_problems is not None and n_problems < 1:
        raise ValueError(f"--n-problems must be >= 1, got {n_problems}")
    started = time.perf_counter()
    theta = np.asarray(dm.load()["tasks"]["test_theta"])[:n_problems]
    loaded = {c: OnlineAgent.load(c) for c in checkpoints}  # read once; each seed below reuses the policy
    for checkpoint, probe in loaded.items():
        policy = probe.policy
        if policy.state_dim != 0 or policy.action_spec != family.action_spec:
            raise ValueError(f"{checkpoint} is not a policy of this bandit (state_dim {policy.state_dim}, actions "
                             f"{policy.action_spec}; the family has state_dim 0 and {family.action_spec})")
        if not 1 <= rounds <= policy.transformer.max_context:
            raise ValueError(f"--rounds must be in [1, {policy.transformer.max_context}] (the model's max_context), "
                             f"got {rounds}")
    ad_loaded = {c: load_ad_agent(c, family, rounds) for c in ad_checkpoints}
    rewards = torch.from_numpy(family.expected_rewards(theta))

    def seed_mean(play) -> dict[str, torch.Tensor]:
        per_seed = [regrets(rewards, play(seed)) for seed in seeds]
        return {k: torch.stack([c[k] for c in per_seed]).mean(0) for k in per_seed[0]}

    icpo = {}
    for rule in rules if checkpoints else ():  # AD and the baselines alone: no ICPO rows
        per_ckpt = []
        for checkpoint in checkpoints:
            def play(seed: int, checkpoint: str = checkpoint, rule: str = rule) -> dict[str, torch.Tensor]:
                probe = loaded[checkpoint]
                agent = OnlineAgent(probe.policy, greedy=probe.greedy, seed=seed, pair_rule=PAIR_RULES[rule]())
                return icpo_online(agent, family, theta, rounds, seed_streams(seed)[0], labels)
            per_ckpt.append(summarize(seed_mean(play)))
        icpo[rule] = {"mean": over_checkpoints(per_ckpt), "per_checkpoint": per_ckpt}
    ad = {}
    if ad_loaded:
        per_ckpt = []
        for probe in ad_loaded.values():
            def play_ad(seed: int, probe: DuelHistoryAgent = probe) -> dict[str, torch.Tensor]:
                agent = DuelHistoryAgent(probe.policy, greedy=probe.greedy, seed=seed)
                return ad_online(agent, family, theta, rounds, seed_streams(seed)[0], labels)
            per_ckpt.append(summarize(seed_mean(play_ad)))
        ad = {"ad": {"checkpoints": [str(c) for c in ad_checkpoints], "mean": over_checkpoints(per_ckpt),
                     "per_checkpoint": per_ckpt}}
    dts = summarize(seed_mean(lambda seed: dts_online(family, theta, rounds, seed_streams(seed)[1])))
    baselines = {name: summarize(seed_mean(
        lambda seed, name=name: linear_online(family, theta, rounds, name, baseline_seeds(seed)[name])))
        for name in ONLINE_BASELINES}
    return {"checkpoints": [str(c) for c in checkpoints], "dataset": str(dm.path), "problems": len(theta),
            "rounds": rounds, "seeds": list(seeds), "labels": labels, "icpo": icpo, **ad, "dts": dts, **baselines,
            "seconds": round(time.perf_counter() - started, 1)}


def load_ad_agent(checkpoint: str, family: LinearDuelingBanditFamily, rounds: int) -> DuelHistoryAgent:
    """An AD-on-duels checkpoint as its ``DuelHistoryAgent``, checked against the family and ``rounds``."""
    agent = load_agent(checkpoint)
    if not isinstance(agent, DuelHistoryAgent):
        raise ValueError(f"--ad-ckpt {checkpoint} is not AD on duels (ADModule with context_kind step_preference); "
                         f"it deploys as a {type(agent).__name__}")
    if agent.obs_dim != 0 or agent.action_spec != family.action_spec:
        raise ValueError(f"--ad-ckpt {checkpoint} is not a model of this bandit (state_dim {agent.obs_dim}, actions "
                         f"{agent.action_spec}; the family has state_dim 0 and {family.action_spec})")
    if not 1 <= rounds <= agent.max_context - 1:
        raise ValueError(f"--rounds must be in [1, {agent.max_context - 1}] for --ad-ckpt {checkpoint}: AD proposes "
                         f"rounds + 1 duels (the last one's first arm is its recommendation), got {rounds}")
    return agent


def is_online_bandit_payload(payload: Any) -> bool:
    """The JSON ``evaluate_online_bandit`` returns (``icprl evaluate online`` on a dueling bandit)."""
    return isinstance(payload, dict) and {"rounds", "problems", "icpo", "dts"} <= set(payload)


def online_bandit_markdown(out: dict[str, Any]) -> str:
    """The table of an online bandit evaluation: per row, cumulative and final weak and strong regret and the
    recommendation regret at the budgets, each mean ± sem as the JSON holds it (over training seeds for the
    trained rows, over problems for the baselines)."""
    rows = [(f"ICPO ({rule} pairs)", result["mean"]) for rule, result in out["icpo"].items()]
    if "ad" in out:
        rows.append(("AD on DTS's duels", out["ad"]["mean"]))
    rows += [(name, out[key]) for key, name in (("dts", "DTS"), ("maxinp", "MaxInP"),
                                                  ("bt_thompson", "BT Thompson sampling")) if key in out]
    budgets = list(rows[0][1]["recommendation_regret"])

    def cell(mean: float, sem: float | None) -> str:
        return f"{mean:.3g}" if sem is None else f"{mean:.3g} ± {sem:.2g}"

    labels = out["labels"] if out["labels"] == "own" else (
        f"{out['labels']} for the trained rows (the baselines are answered truly)")
    lines = [f"Asked online: {out['rounds']} rounds on {out['problems']} held-out problems, labels {labels}, "
             f"episode seeds {out['seeds']}. Lower is better.", "",
             "| row | cumulative weak regret | cumulative strong regret | final weak regret | final strong regret | "
             + " | ".join(f"recommendation regret at {b}" for b in budgets) + " |",
             "|---" * (5 + len(budgets)) + "|"]
    for name, stats in rows:
        cells = [cell(stats[k], stats.get(f"{k}_sem")) for k in REGRET_KEYS[0::2] + REGRET_KEYS[1::2]]
        cells += [cell(stats["recommendation_regret"][b]["mean"], stats["recommendation_regret"][b]["sem"])
                  for b in budgets]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    seeds = [f"ICPO {len(result['per_checkpoint'])}" for result in list(out["icpo"].values())[:1]]
    seeds += [f"AD {len(out['ad']['per_checkpoint'])}"] if "ad" in out else []
    lines += ["", f"Trained rows: mean ± sem over training seeds ({', '.join(seeds)}; one seed: no ±) of each "
                  "seed's mean over problems and episode seeds; DTS, MaxInP and BT Thompson sampling: mean ± sem over "
                  "problems. Weak regret min(R* − R(a), R* − R(a')), strong the mean of the two gaps; recommendation "
                  "regret: the gap of the arm recommended after that many answers.", ""]
    return "\n".join(lines)


def online_bandit_figure(out: dict[str, Any], path: str | Path) -> None:
    """Recommendation regret vs answered queries, one line per pair rule (mean over training seeds), DTS and
    the feature-aware baselines dashed."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.6), layout="tight")
    ax = fig.subplots()
    for i, (rule, result) in enumerate(out["icpo"].items()):
        curve = result["mean"]["recommendation_curve"]
        ax.plot(range(1, len(curve) + 1), curve, color=f"C{i}", label=f"ICPO, {rule} pairs")
    if "ad" in out:
        curve = out["ad"]["mean"]["recommendation_curve"]
        ax.plot(range(1, len(curve) + 1), curve, color="C9", label="AD on DTS's duels")
    references = [("dts", "DTS", "k"), ("maxinp", "MaxInP", "0.45"), ("bt_thompson", "BT Thompson sampling", "0.7")]
    for key, label, color in references:
        if key in out:  # results written before the feature-aware baselines have DTS only
            curve = out[key]["recommendation_curve"]
            ax.plot(range(1, len(curve) + 1), curve, color=color, linestyle="--", label=label)
    ax.set_xlabel("answered queries")
    ax.set_ylabel("regret of the recommended arm")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"online dueling bandits, {out['problems']} held-out problems, labels: {out['labels']} "
                 f"({len(out['checkpoints'])} training seeds)", fontsize=8)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=120)


class OnlineBandit(HeldOutEvaluation):
    """A dueling bandit's held-out problems played online (the module docstring), one run's checkpoints (its training
    seeds); the options are ``icprl evaluate online``'s: ``rules``, ``labels``, ``rounds``, ``n_problems`` and
    ``ad_checkpoints`` (the ``ad`` row)."""

    name: ClassVar[str] = "online_duels"

    def __init__(self, rules: Sequence[str] = ("action_uniform",), labels: str = "own", rounds: int = 200,
                 n_problems: int | None = None, ad_checkpoints: Sequence[str] = ()) -> None:
        self.options = {"rules": list(rules), "labels": labels, "rounds": rounds, "n_problems": n_problems,
                        "ad_checkpoints": [str(c) for c in ad_checkpoints]}

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        return super().recognizes(payload) or is_online_bandit_payload(payload)

    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        if len(runs) != 1:
            raise ValueError(f"the online evaluation plays one run (its checkpoints: training seeds), got {len(runs)}")
        (run,) = runs
        return {"configs": [run.config], **evaluate_online_bandit(run.data, run.checkpoints, seeds=seeds,
                                                                  **self.options)}

    markdown = staticmethod(online_bandit_markdown)
    figure = staticmethod(online_bandit_figure)
