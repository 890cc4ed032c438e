"""Weak regret of in-context dueling-bandit policies vs context size (paper, appendix "Dueling Bandit Experiments").

On a held-out problem τ with context D^I = {(a_h, a'_h, y_h)}_{h ≤ H}, each method plays one duel after
seeing the first h comparisons, for every context size h = 1..H, scored by the weak regret

    reg(a, a') = min(R*_τ − R_τ(a), R*_τ − R_τ(a'))                      (``metrics.weak_regret``).

* ICPO: a = argmax_ã T_θ(ã | D_{1:h}) and a' uniform over the other arms, as in the paper. All H prefix
  predictions come from one forward pass in which query h sees the first h context tokens.
* DTS: Double Thompson Sampling fed the same first h comparisons (incrementally over h), then asked for
  its duel (paper: "DTS also utilizes the same bandit preferences in D^I").
* Behaviour: the duel the context's own behaviour policy played next, i.e. its duel h + 1.

Duels are ``(first, second)`` int64 tensors ``[B, H]``; column h − 1 is the duel after h comparisons.
Per-problem regret curves ``[B, H]`` are summarized over problems as mean ± standard error, at h = H
(``weak_regret``) and averaged over h = 1..H (``weak_regret_auc``).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import torch
from torch import Tensor

from icprl_lightning.baselines.dts import DoubleThompsonSampling
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.suites import BanditSuite
from icprl_lightning.metrics import mean_sem, weak_regret
from icprl_lightning.models.policy import InContextPolicy

Duels = tuple[Tensor, Tensor]
METHODS = ("icpo", "dts", "behavior")


def _rows(context: StepPreferenceContext, part: slice) -> StepPreferenceContext:
    return StepPreferenceContext(**{f.name: getattr(context, f.name)[part] for f in fields(context)})


@torch.no_grad()
def icpo_duels(policy: InContextPolicy, context: StepPreferenceContext, rng: np.random.Generator,
               chunk_size: int = 32) -> Duels:
    """First arm argmax_a T_θ(a | D_{1:h}) for h = 1..H from one pass per chunk; second arm uniform over the rest."""
    if policy.state_dim != 0 or not policy.action_spec.discrete:
        raise ValueError("a dueling-bandit policy has state_dim 0 and discrete arms, got "
                         f"state_dim={policy.state_dim}, discrete={policy.action_spec.discrete}")
    b, h = context.preferred.shape
    device = next(policy.parameters()).device
    visible = torch.arange(1, h + 1, device=device)  # query h sees D_{1:h}
    was_training = policy.training
    policy.eval()
    first = []
    for start in range(0, b, chunk_size):
        part = _rows(context, slice(start, start + chunk_size)).to(device)
        queries = torch.zeros(part.batch_size, h, 0, device=device)  # (b, H, 0): a bandit query has no state
        first.append(policy(part, queries, visible).argmax(-1).cpu())  # (b, H)
    policy.train(was_training)
    first_arm = torch.cat(first)
    n_arms = policy.action_spec.size
    # A uniform non-zero offset makes the second arm uniform over the other A − 1 arms.
    offset = torch.from_numpy(rng.integers(1, n_arms, size=(b, h)))
    return first_arm, (first_arm + offset) % n_arms


def dts_duels(context: StepPreferenceContext, n_arms: int, rng: np.random.Generator, alpha: float = 0.51) -> Duels:
    """DTS's duel after each prefix D_{1:h}, h = 1..H: observe comparison h, then select."""
    actions, alt_actions = context.actions.cpu().numpy(), context.alt_actions.cpu().numpy()
    preferred = (context.preferred.cpu().numpy() > 0.5).astype(np.uint8)
    b, h = preferred.shape
    dts = DoubleThompsonSampling(n_arms, b, alpha, rng=rng)
    first = np.empty((b, h), dtype=np.int64)
    second = np.empty((b, h), dtype=np.int64)
    for t in range(h):
        dts.update(actions[:, t], alt_actions[:, t], preferred[:, t])
        first[:, t], second[:, t] = dts.select()
    return torch.from_numpy(first), torch.from_numpy(second)


def evaluate_duels(policy: InContextPolicy, suite: BanditSuite, seed: int = 0, chunk_size: int = 32
                   ) -> dict[str, Duels]:
    """The duels of ICPO, DTS and the behaviour policy after every context size, keyed by ``METHODS``."""
    icpo_seed, dts_seed = np.random.SeedSequence(seed).spawn(2)
    n_arms = suite.expected_rewards.shape[1]
    return {"icpo": icpo_duels(policy, suite.context, np.random.default_rng(icpo_seed), chunk_size),
            "dts": dts_duels(suite.context, n_arms, np.random.default_rng(dts_seed), suite.dts_alpha),
            "behavior": (suite.behavior_first.long(), suite.behavior_second.long())}


def regret_curve(expected_rewards: Tensor, duels: Duels) -> Tensor:
    """Weak regret of every duel: ``expected_rewards [B, A]``, duels ``[B, H]`` -> ``[B, H]``."""
    first, second = duels
    b, h = first.shape
    rewards = expected_rewards.repeat_interleave(h, dim=0)  # (B·H, A), row-major like first.reshape(-1)
    return weak_regret(rewards, first.reshape(-1), second.reshape(-1)).reshape(b, h)


def curve_mean_sem(curve: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over problems of a ``[B, H]`` curve, each ``[H]``."""
    values = curve.double().cpu().numpy()
    sem = values.std(axis=0, ddof=1) / np.sqrt(len(values)) if len(values) > 1 else np.full(values.shape[1], np.nan)
    return values.mean(axis=0), sem


def summarize_regret(curve: Tensor) -> dict[str, float]:
    """Final (h = H) and mean-over-h weak regret, each with its standard error over problems."""
    values = curve.double().cpu().numpy()
    final, final_sem = mean_sem(values[:, -1])
    auc, auc_sem = mean_sem(values.mean(axis=1))
    return {"weak_regret": final, "weak_regret_sem": final_sem, "weak_regret_auc": auc, "weak_regret_auc_sem": auc_sem}
