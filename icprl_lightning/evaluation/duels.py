"""Weak and strong regret of in-context dueling-bandit policies vs context size (paper, appendix "Dueling
Bandit Experiments"; the baselines: docs/baselines_bandit.md).

On a held-out problem τ with context D^I = {(a_h, a'_h, y_h)}_{h ≤ H}, each method plays one duel after
seeing the first h comparisons, for every h = 1..H, scored by

    reg(a, a') = min(R*_τ − R_τ(a), R*_τ − R_τ(a'))                      (``metrics.weak_regret``, the paper's),
    reg_strong(a, a') = ((R*_τ − R_τ(a)) + (R*_τ − R_τ(a'))) / 2         (``metrics.strong_regret``, ≥ the weak).

Rows: the trained method through ``Agent.act_each_prefix`` (argmax_ã T_θ(ã | D_{1:h}) when greedy, as in the
paper), a' uniform over the other arms; DTS fed the same prefixes (paper: "DTS also utilizes the same
bandit preferences in D^I"); the behaviour policy's own duel h + 1; and, given the family, the feature-aware
``LINEAR_BASELINES`` (``linear_baselines.prefix_duels``) with the knobs ``tuning.TUNED`` chose on training
problems only (MaxInP β = 0.1, v = 0.01; BT Thompson v = 1.0, s = 0.1; 5 warm-started Newton steps per
prefix). ``bayes`` is a floor per regret, not one learner (the Bayes-optimal pair for weak regret, the
Bayes-optimal arm against itself for strong, under the prior N(0, I/d), 256 Laplace draws): a learner goes
below it only by chance, within the standard error.

Duels are ``(first, second)`` int64 ``[B, H]``, column h − 1 after h comparisons. Regret curves ``[B, H]`` are
summarized over problems as mean ± sem at h = H (``weak_regret``), averaged over h (``weak_regret_auc``) and at
``CONTEXT_SIZES`` (``weak_regret_h10``, ...); likewise ``strong_*``. Rows are keyed by ``method_name``
(``ICPOModule`` -> ``icpo``) beside the ``BASELINES``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.suites import BanditSuite
from icprl_lightning.deploy import Agent
from icprl_lightning.families.dueling_bandit.bayes import BayesReference
from icprl_lightning.families.dueling_bandit.bt_thompson import BTThompsonSampling
from icprl_lightning.families.dueling_bandit.dts import DoubleThompsonSampling
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.linear_baselines import LinearDuelingLearner, prefix_duels
from icprl_lightning.families.dueling_bandit.maxinp import MaxInP
from icprl_lightning.families.dueling_bandit.tuning import TUNED
from icprl_lightning.metrics import mean_sem, strong_regret, weak_regret
from icprl_lightning.progress import track

Duels = tuple[Tensor, Tensor]
LINEAR_BASELINES = ("maxinp", "bt_thompson", "bayes")
BASELINES = ("dts", *LINEAR_BASELINES, "behavior")
REGRETS = {"weak": weak_regret, "strong": strong_regret}
CONTEXT_SIZES = (10, 50, 100, 200)


def method_name(method: type | str) -> str:
    """A method's name in metric keys, from its class or class path: ``ICPOModule`` -> ``icpo``."""
    name = method if isinstance(method, str) else method.__name__
    return name.rpartition(".")[2].removesuffix("Module").lower()


def seed_streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators for the method's random second arm and for DTS's sampling."""
    method_seed, dts_seed = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(method_seed), np.random.default_rng(dts_seed)


def baseline_seeds(seed: int) -> dict[str, np.random.SeedSequence]:
    """One seed per feature-aware baseline, independent of ``seed_streams``'s two (the next children of the
    same ``SeedSequence``), so adding the baselines leaves the method's and DTS's draws unchanged."""
    children = np.random.SeedSequence(seed).spawn(2 + len(LINEAR_BASELINES))[2:]
    return dict(zip(LINEAR_BASELINES, children, strict=True))


def linear_learner(name: str, family: LinearDuelingBanditFamily, n_problems: int, rng: np.random.Generator,
                   rule: str = "weak") -> LinearDuelingLearner:
    """The baseline ``name`` of ``LINEAR_BASELINES`` for ``n_problems`` problems of ``family``, with the tuned
    knobs (``tuning.TUNED``); ``rule``: the Bayes reference's pair rule (``bayes.PAIR_RULES``)."""
    if name == "bayes":
        return BayesReference.for_family(family, n_problems, rng=rng, rule=rule)
    learners = {"maxinp": MaxInP, "bt_thompson": BTThompsonSampling}
    if name not in learners:
        raise ValueError(f"baseline must be one of {', '.join(LINEAR_BASELINES)}, got {name!r}")
    return learners[name](family.features, n_problems, temperature=family.bt_temperature, rng=rng, **TUNED[name])


@torch.no_grad()
def agent_duels(agent: Agent, context: StepPreferenceContext, rng: np.random.Generator, batch_chunk: int = 32) -> Duels:
    """First arm: the agent's action after D_{1:h}, h = 1..H (``act_each_prefix``); second uniform over the rest."""
    policy = agent.policy
    if policy.state_dim != 0 or not policy.action_spec.discrete:
        raise ValueError("a dueling-bandit policy has state_dim 0 and discrete arms, got "
                         f"state_dim={policy.state_dim}, discrete={policy.action_spec.discrete}")
    agent.reset(context)
    b, h = context.preferred.shape
    first = agent.act_each_prefix(torch.zeros(b, 0), batch_chunk=batch_chunk).cpu()  # (B, H)
    n_arms = policy.action_spec.size
    # A uniform non-zero offset makes the second arm uniform over the other A − 1 arms.
    offset = torch.from_numpy(rng.integers(1, n_arms, size=(b, h)))
    return first, (first + offset) % n_arms


def dts_duels(context: StepPreferenceContext, n_arms: int, rng: np.random.Generator, alpha: float = 0.51,
              progress: bool = True) -> Duels:
    """DTS's duel after each prefix D_{1:h}, h = 1..H: observe comparison h, then select (``progress``: the
    prefixes are counted, ``progress.track``)."""
    actions, alt_actions = context.actions.cpu().numpy(), context.alt_actions.cpu().numpy()
    preferred = (context.preferred.cpu().numpy() > 0.5).astype(np.uint8)
    b, h = preferred.shape
    dts = DoubleThompsonSampling(n_arms, b, alpha, rng=rng)
    first = np.empty((b, h), dtype=np.int64)
    second = np.empty((b, h), dtype=np.int64)
    for t in track(range(h), "DTS duels", unit="prefix", enabled=progress):
        dts.update(actions[:, t], alt_actions[:, t], preferred[:, t])
        first[:, t], second[:, t] = dts.select()
    return torch.from_numpy(first), torch.from_numpy(second)


def behavior_duels(suite: BanditSuite) -> Duels:
    """The context's own behaviour policy: its duel h + 1 after h comparisons."""
    return suite.behavior_first.long(), suite.behavior_second.long()


def linear_duels(context: StepPreferenceContext, family: LinearDuelingBanditFamily, name: str,
                 rng: np.random.Generator, rule: str = "weak") -> Duels:
    """The feature-aware baseline ``name``'s duel after each prefix D_{1:h}, h = 1..H (``prefix_duels``: observe
    comparison h, then select, as ``dts_duels``); ``rule``: the Bayes reference's pair rule."""
    arms_first, arms_second = context.actions.cpu().numpy(), context.alt_actions.cpu().numpy()
    preferred = (context.preferred.cpu().numpy() > 0.5).astype(np.uint8)
    learner = linear_learner(name, family, len(preferred), rng, rule)
    first, second = prefix_duels(learner, arms_first, arms_second, preferred)
    return torch.from_numpy(first), torch.from_numpy(second)


def baseline_curves(suite: BanditSuite, family: LinearDuelingBanditFamily, seed: int = 0
                    ) -> dict[str, dict[str, Tensor]]:
    """Weak and strong regret curves ``[B, H]`` of every ``LINEAR_BASELINES`` row on ``suite``'s contexts, each
    learner drawing from its ``baseline_seeds(seed)`` stream. The ``bayes`` row scores each regret by the Bayes
    rule for it: weak regret of rule ``"weak"``'s pair, strong regret of rule ``"strong"``'s self-duel."""
    n_arms = suite.expected_rewards.shape[1]
    if family.n_arms != n_arms:
        raise ValueError(f"family has n_arms={family.n_arms}, but the suite's problems have {n_arms} arms")
    seeds = baseline_seeds(seed)
    out = {name: regret_curves(suite.expected_rewards,
                               linear_duels(suite.context, family, name, np.random.default_rng(seeds[name])))
           for name in LINEAR_BASELINES if name != "bayes"}
    bayes_rng = np.random.default_rng(seeds["bayes"])  # rule "strong" takes the posterior mean: no draws
    out["bayes"] = {regret: regret_curve(suite.expected_rewards,
                                         linear_duels(suite.context, family, "bayes", bayes_rng, rule), regret)
                    for regret, rule in (("weak", "weak"), ("strong", "strong"))}
    return out


def evaluate_duels(agent: Agent, suite: BanditSuite, method: str, seed: int = 0, batch_chunk: int = 32,
                   baselines: bool = True) -> dict[str, Duels]:
    """The duels of ``method`` (the agent) and, with ``baselines``, of DTS and the behaviour policy (the
    feature-aware baselines: ``baseline_curves``)."""
    if method in BASELINES:
        raise ValueError(f"method name {method!r} is taken by a baseline row ({', '.join(BASELINES)})")
    method_rng, dts_rng = seed_streams(seed)
    out = {method: agent_duels(agent, suite.context, method_rng, batch_chunk)}
    if baselines:
        n_arms = suite.expected_rewards.shape[1]
        out["dts"] = dts_duels(suite.context, n_arms, dts_rng, suite.dts_alpha)
        out["behavior"] = behavior_duels(suite)
    return out


def regret_curve(expected_rewards: Tensor, duels: Duels, regret: str = "weak") -> Tensor:
    """The ``regret`` (``REGRETS``: weak or strong) of every duel: ``expected_rewards [B, A]``, duels ``[B, H]`` ->
    ``[B, H]``."""
    if regret not in REGRETS:
        raise ValueError(f"regret must be one of {', '.join(REGRETS)}, got {regret!r}")
    first, second = duels
    b, h = first.shape
    rewards = expected_rewards.repeat_interleave(h, dim=0)  # (B·H, A), row-major like first.reshape(-1)
    return REGRETS[regret](rewards, first.reshape(-1), second.reshape(-1)).reshape(b, h)


def regret_curves(expected_rewards: Tensor, duels: Duels) -> dict[str, Tensor]:
    """``regret_curve`` of the same duels for every regret of ``REGRETS``."""
    return {regret: regret_curve(expected_rewards, duels, regret) for regret in REGRETS}


def seed_mean_curves(make_agent: Callable[[int], Agent], suite: BanditSuite, method: str, seeds: Sequence[int],
                     baselines: bool = True, batch_chunk: int = 32, family: LinearDuelingBanditFamily | None = None
                     ) -> dict[str, dict[str, Tensor]]:
    """Per row (``method``, then ``BASELINES`` in order) and regret, per-problem curves ``[B, H]`` averaged over
    seeds (random second arm, DTS's and the baselines' sampling). With ``baselines``: DTS and behaviour rows, and
    with the ``family`` also the feature-aware baselines (``baseline_curves``)."""
    curves: dict[str, dict[str, list[Tensor]]] = {}
    for seed in seeds:
        played = {name: regret_curves(suite.expected_rewards, pair)
                  for name, pair in evaluate_duels(make_agent(seed), suite, method, seed, batch_chunk,
                                                   baselines).items()}
        if baselines and family is not None:
            played.update(baseline_curves(suite, family, seed))
        for name, by_regret in played.items():
            for regret, curve in by_regret.items():
                curves.setdefault(name, {}).setdefault(regret, []).append(curve.double())
    order = [name for name in (method, *BASELINES) if name in curves]
    return {name: {regret: torch.stack(c).mean(0) for regret, c in curves[name].items()} for name in order}


def curve_mean_sem(curve: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over problems of a ``[B, H]`` curve, each ``[H]``."""
    values = curve.double().cpu().numpy()
    sem = values.std(axis=0, ddof=1) / np.sqrt(len(values)) if len(values) > 1 else np.full(values.shape[1], np.nan)
    return values.mean(axis=0), sem


def summarize_regret(curve: Tensor, with_tasks: bool = False, regret: str = "weak", sizes: Sequence[int] = ()
                     ) -> dict[str, Any]:
    """Final (h = H) and mean-over-h ``regret`` (keys ``<regret>_regret``, ``<regret>_regret_auc``) and, for each
    of ``sizes`` up to H, the regret after h comparisons (``<regret>_regret_h<h>``), each with its standard
    error over problems; ``with_tasks``: also, under ``per_task``, each problem's values (what the bootstrap
    confidence intervals resample)."""
    values = curve.double().cpu().numpy()
    key = f"{regret}_regret"
    per_problem = {key: values[:, -1], f"{key}_auc": values.mean(axis=1)}
    per_problem.update((f"{key}_h{h}", values[:, h - 1]) for h in sizes if 1 <= h <= values.shape[1])
    out: dict[str, Any] = {}
    for name, v in per_problem.items():
        out[name], out[f"{name}_sem"] = mean_sem(v)
    if with_tasks:
        out["per_task"] = {name: v.tolist() for name, v in per_problem.items()}
    return out


def summarize_regrets(curves: dict[str, Tensor], with_tasks: bool = False, sizes: Sequence[int] = CONTEXT_SIZES
                      ) -> dict[str, Any]:
    """``summarize_regret`` of each regret's curve (``{"weak": [B, H], "strong": [B, H]}``) in one row, at
    ``sizes``; ``per_task`` merged."""
    out: dict[str, Any] = {}
    for regret, curve in curves.items():
        summary = summarize_regret(curve, with_tasks, regret, sizes)
        if with_tasks:
            out.setdefault("per_task", {}).update(summary.pop("per_task"))
        out.update(summary)
    if with_tasks:
        out["per_task"] = out.pop("per_task")  # last, as summarize_regret's
    return out
