"""Pure loss functions of every method, each tested against hand-computed values.

* ``supervised_action_loss`` — DPT / DP²T, paper eq. (1): −log T_θ(a* | s_query, D) for discrete
  actions; for continuous actions the Gaussian-mean policy N(a; T_θ(s, D), γI) makes it the squared
  error ‖a* − T_θ(s, D)‖² (up to constants).
* ``icpo_loss`` — ICPO, paper eq. (final I-PRL objective):
  −log σ(β (log T_θ(a⁺ | s, D) − λ log T_θ(a⁻ | s, D))).
* ``icpo_continuous_loss`` — ICPO for continuous control (appendix "ICPO for Continuous Control"):
  −log σ(β (‖a⁻ − μ‖ − ‖a⁺ − μ‖)) with μ = T_θ(s, D); the derivation's squared norms via
  ``squared=True``; λ scales the non-preferred distance, or the preferred one with
  ``lambda_on_preferred=True`` (the paper's Meta-World ablation).
* ``soft_label_loss`` — a comparison whose label y lies between 0 and 1 (a person's tie: y = 1/2, as B-Pref
  trains on an "equal" answer): y ℓ(first won) + (1 − y) ℓ(second won), the expected loss under the label; for
  y ∈ {0, 1} it is the loss of the order the label names. ICPO's losses take ``reduce=False`` for it.
* ``trajectory_preference_loss`` — RewardGen, paper eq. (L_R^T):
  −log σ(Σ_h R_ψ(s⁺_h, a⁺_h | D^T) − Σ_h R_ψ(s⁻_h, a⁻_h | D^T)), written for a labeled pair (ξ_a, ξ_b, y).
* ``dit_value_loss`` — DIT's in-context Q̂ and V̂, paper eq. (dit-loss): (Q̂ − G)² + (V̂ − G)² on discounted
  returns G (the paper's second term lacks its square; the regression is meant).
* ``td_advantages`` — an alternative to the paper's Â = Q̂ − V̂ (eq. dit-advantage): the one-step TD error
  r_h + γ V̂(s_{h+1}) − V̂(s_h) of the same V̂, which reads the action's effect off the next state instead of
  asking a second network to resolve it (AWR's estimator, at one step).
* ``standardized_advantages`` — DIT's Â, centred and divided by its batch standard deviation, so that η
  means the same for any reward scale and an offset between Q̂ and V̂ does not push every weight onto its clip.
* ``advantage_weighted_loss`` — DIT's policy, paper eq. (dit-optimization): −exp(Â/η) log T^R(a | s, D),
  the weight clipped at ``max_weight`` (as in AWR/IQL: one large advantage must not dominate a batch).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor


def supervised_action_loss(outputs: Tensor, optimal_actions: Tensor, discrete: bool) -> Tensor:
    """outputs (..., A) logits or means; optimal_actions (...) indices or (..., A) vectors -> scalar."""
    if discrete:
        return F.cross_entropy(outputs.reshape(-1, outputs.shape[-1]), optimal_actions.reshape(-1).long())
    return (outputs - optimal_actions).pow(2).sum(-1).mean()


def icpo_loss(logp_preferred: Tensor, logp_rejected: Tensor, beta: float, lam: float, reduce: bool = True) -> Tensor:
    """Mean of −log σ(β (log T(a⁺) − λ log T(a⁻))) over all comparisons (each one's with ``reduce=False``)."""
    loss = -F.logsigmoid(beta * (logp_preferred - lam * logp_rejected))
    return loss.mean() if reduce else loss


def icpo_continuous_loss(mean: Tensor, preferred: Tensor, rejected: Tensor, beta: float, lam: float = 1.0,
                         lambda_on_preferred: bool = False, squared: bool = False, reduce: bool = True) -> Tensor:
    """mean, preferred, rejected (..., A) -> mean of −log σ(β (λ⁻ d(a⁻, μ) − λ⁺ d(a⁺, μ)))."""
    d_plus = (preferred - mean).pow(2).sum(-1)
    d_minus = (rejected - mean).pow(2).sum(-1)
    if not squared:
        d_plus, d_minus = d_plus.clamp_min(1e-12).sqrt(), d_minus.clamp_min(1e-12).sqrt()
    margin = d_minus - lam * d_plus if lambda_on_preferred else lam * d_minus - d_plus
    loss = -F.logsigmoid(beta * margin)
    return loss.mean() if reduce else loss


def soft_label_loss(loss_first: Tensor, loss_second: Tensor, preferred: Tensor) -> Tensor:
    """Mean of y ℓ₁ + (1 − y) ℓ₂: ℓ₁ / ℓ₂ each comparison's loss if the first / second of its pair won, y its
    label in [0, 1] (1/2: a tie weighs both orders equally). All shaped alike."""
    return (preferred * loss_first + (1 - preferred) * loss_second).mean()


def trajectory_preference_loss(returns_a: Tensor, returns_b: Tensor, preferred: Tensor) -> Tensor:
    """Mean Bradley–Terry NLL of labels y (1 = ξ_a won) given summed rewards R(ξ_a), R(ξ_b), all shaped (B,)."""
    return F.binary_cross_entropy_with_logits(returns_a - returns_b, preferred.float())


def dit_value_loss(q_values: Tensor, v_values: Tensor, returns: Tensor) -> Tensor:
    """mean (Q̂ − G)² + mean (V̂ − G)² over all (trajectory, step) entries."""
    return (q_values - returns).pow(2).mean() + (v_values - returns).pow(2).mean()


def discounted_returns(rewards: Tensor, gamma: float) -> Tensor:
    """G_h = Σ_{h' ≥ h} γ^{h'−h} r_{h'} along the last axis: rewards (..., H) -> (..., H)."""
    steps = torch.arange(rewards.shape[-1], device=rewards.device)
    lag = (steps[:, None] - steps[None, :]).to(rewards.dtype)  # (h', h) -> h' − h
    return rewards @ torch.where(lag >= 0, gamma ** lag.clamp(min=0), 0.0)


def gae_advantages(v_values: Tensor, rewards: Tensor, gamma: float, lam: float) -> Tensor:
    """Generalized advantage estimation along the last axis, (..., H) -> (..., H): Σ_k (γλ)^k δ_{h+k} with the TD
    errors δ_h = (1 − γ) r_h + γ V̂(s_{h+1}) − V̂(s_h), V̂ = 0 after the last step (the returns are truncated there).
    V̂ is in the value loss's (1 − γ)-scaled units, hence the (1 − γ) r_h. λ = 0 is the one-step TD error, λ = 1
    telescopes to the Monte Carlo advantage (1 − γ) G_h − V̂(s_h); in between, the return of the next ≈ 1/(1 − γλ)
    steps is taken as collected and the rest from V̂ (Schulman et al., 2016)."""
    following = torch.cat([v_values[..., 1:], torch.zeros_like(v_values[..., :1])], dim=-1)
    deltas = (1 - gamma) * rewards + gamma * following - v_values
    return discounted_returns(deltas, gamma * lam).detach()


def return_to_go_advantages(v_values: Tensor, rewards: Tensor, gamma: float) -> Tensor:
    """(1 − γ) G_h − V̂(s_h) along the last axis, (..., H) -> (..., H): AWR's Monte Carlo advantage, with G_h the
    discounted return-to-go truncated at the horizon, in the value loss's (1 − γ)-scaled units (GAE at λ = 1)."""
    return ((1 - gamma) * discounted_returns(rewards, gamma) - v_values).detach()


def td_advantages(v_values: Tensor, rewards: Tensor, gamma: float) -> Tensor:
    """(1 − γ) r_h + γ V̂(s_{h+1}) − V̂(s_h) along the last axis, (..., H) -> (..., H), V̂ = 0 after the last step
    (the returns are truncated there): GAE at λ = 0."""
    return gae_advantages(v_values, rewards, gamma, 0.0)


def standardized_advantages(advantage: Tensor, center: bool = True) -> Tensor:
    """(Â − mean) / std over the whole batch (the mean only with ``center``); no gradient flows."""
    advantage = advantage.detach()
    if center:
        advantage = advantage - advantage.mean()
    return advantage / (advantage.std() + 1e-6)


def advantage_weighted_loss(log_likelihood: Tensor, advantages: Tensor, eta: float, max_weight: float) -> Tensor:
    """−mean(min(exp(Â / η), max_weight) · log T(a | s, D)); the weights carry no gradient."""
    weights = torch.exp((advantages.detach() / eta).clamp(max=math.log(max_weight)))
    return -(weights * log_likelihood).mean()
