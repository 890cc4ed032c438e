"""Weak regret of in-context dueling-bandit policies vs context size (paper, appendix "Dueling Bandit Experiments").

On a held-out problem τ with context D^I = {(a_h, a'_h, y_h)}_{h ≤ H}, each method plays one duel after
seeing the first h comparisons, for every context size h = 1..H, scored by the weak regret

    reg(a, a') = min(R*_τ − R_τ(a), R*_τ − R_τ(a'))                      (``metrics.weak_regret``).

* The trained method (ICPO, or any policy on ``StepPreferenceContext`` with ``state_dim = 0``), through
  the public ``Agent``: a = its action after D_{1:h} (``Agent.act_each_prefix``: argmax_ã T_θ(ã | D_{1:h})
  for a greedy agent, as in the paper) and a' uniform over the other arms.
* DTS: Double Thompson Sampling fed the same first h comparisons (incrementally over h), then asked for
  its duel (paper: "DTS also utilizes the same bandit preferences in D^I").
* Behaviour: the duel the context's own behaviour policy played next, i.e. its duel h + 1.

Duels are ``(first, second)`` int64 tensors ``[B, H]``; column h − 1 is the duel after h comparisons.
Per-problem regret curves ``[B, H]`` are summarized over problems as mean ± standard error, at h = H
(``weak_regret``) and averaged over h = 1..H (``weak_regret_auc``). Results are keyed by the method's own
name (``method_name``: ``ICPOModule`` -> ``icpo``) beside ``dts`` and ``behavior``.
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
from icprl_lightning.families.dueling_bandit.dts import DoubleThompsonSampling
from icprl_lightning.metrics import mean_sem, weak_regret
from icprl_lightning.progress import track

Duels = tuple[Tensor, Tensor]
BASELINES = ("dts", "behavior")


def method_name(method: type | str) -> str:
    """A method's name in metric keys, from its class or class path: ``ICPOModule`` -> ``icpo``."""
    name = method if isinstance(method, str) else method.__name__
    return name.rpartition(".")[2].removesuffix("Module").lower()


def seed_streams(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Independent generators for the method's random second arm and for DTS's sampling."""
    method_seed, dts_seed = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(method_seed), np.random.default_rng(dts_seed)


@torch.no_grad()
def agent_duels(agent: Agent, context: StepPreferenceContext, rng: np.random.Generator, batch_chunk: int = 32
                ) -> Duels:
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


def evaluate_duels(agent: Agent, suite: BanditSuite, method: str, seed: int = 0, batch_chunk: int = 32,
                   baselines: bool = True) -> dict[str, Duels]:
    """The duels of ``method`` (the agent) and, with ``baselines``, of DTS and the behaviour policy."""
    if method in BASELINES:
        raise ValueError(f"method name {method!r} is taken by a baseline row ({', '.join(BASELINES)})")
    method_rng, dts_rng = seed_streams(seed)
    out = {method: agent_duels(agent, suite.context, method_rng, batch_chunk)}
    if baselines:
        n_arms = suite.expected_rewards.shape[1]
        out["dts"] = dts_duels(suite.context, n_arms, dts_rng, suite.dts_alpha)
        out["behavior"] = behavior_duels(suite)
    return out


def regret_curve(expected_rewards: Tensor, duels: Duels) -> Tensor:
    """Weak regret of every duel: ``expected_rewards [B, A]``, duels ``[B, H]`` -> ``[B, H]``."""
    first, second = duels
    b, h = first.shape
    rewards = expected_rewards.repeat_interleave(h, dim=0)  # (B·H, A), row-major like first.reshape(-1)
    return weak_regret(rewards, first.reshape(-1), second.reshape(-1)).reshape(b, h)


def seed_mean_curves(make_agent: Callable[[int], Agent], suite: BanditSuite, method: str, seeds: Sequence[int],
                     baselines: bool = True, batch_chunk: int = 32) -> dict[str, Tensor]:
    """Per-problem regret curves ``[B, H]`` averaged over seeds (random second arm, DTS sampling)."""
    curves: dict[str, list[Tensor]] = {}
    for seed in seeds:
        duels = evaluate_duels(make_agent(seed), suite, method, seed, batch_chunk, baselines)
        for name, pair in duels.items():
            curves.setdefault(name, []).append(regret_curve(suite.expected_rewards, pair).double())
    return {name: torch.stack(c).mean(0) for name, c in curves.items()}


def curve_mean_sem(curve: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over problems of a ``[B, H]`` curve, each ``[H]``."""
    values = curve.double().cpu().numpy()
    sem = values.std(axis=0, ddof=1) / np.sqrt(len(values)) if len(values) > 1 else np.full(values.shape[1], np.nan)
    return values.mean(axis=0), sem


def summarize_regret(curve: Tensor, with_tasks: bool = False) -> dict[str, Any]:
    """Final (h = H) and mean-over-h weak regret, each with its standard error over problems; ``with_tasks``:
    also, under ``per_task``, each problem's two values (what the bootstrap confidence intervals resample)."""
    values = curve.double().cpu().numpy()
    final, final_sem = mean_sem(values[:, -1])
    auc, auc_sem = mean_sem(values.mean(axis=1))
    out: dict[str, Any] = {"weak_regret": final, "weak_regret_sem": final_sem, "weak_regret_auc": auc,
                           "weak_regret_auc_sem": auc_sem}
    if with_tasks:
        out["per_task"] = {"weak_regret": values[:, -1].tolist(), "weak_regret_auc": values.mean(axis=1).tolist()}
    return out
