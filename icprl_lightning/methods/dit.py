"""Decision Importance Transformer (DIT): paper appendix "Decision Importance Transformer", Algorithm DIT.

In-context estimators Q̂(s, a | D) and V̂(s | D) regress the discounted return-to-go
G_h = Σ_{h' ≥ h} γ^{h'−h} r_{h'} (eq. dit-loss; scaled by 1 − γ so that targets stay O(1), which changes
nothing else since Â is normalized below); the policy T^R(a | s, D) then maximizes the
exp(Â/η)-weighted log-likelihood of the behavior's actions with Â = Q̂ − V̂ (eqs. dit-advantage and
dit-optimization). No optimal-action labels.

Data: a sample is two trajectories of one task with per-step rewards, ξ_a and ξ_b, and each is the
context D = {s_h, a_h, r_h} for the other's transitions (both directions in one batch). The model is
thus trained as it is deployed: conditioned on one reward-labeled trajectory of the task, scoring and
acting in states of another episode. (The paper's D_Q^h, the first h tuples of the *same* trajectory
with their returns, lets Q̂ and V̂ read G_h off G_{h−1} without using the action, and Â collapses to
noise; conditioning on the other trajectory removes that shortcut.) Every query sees the whole context.

Two phases, as Algorithm DIT: for the first ``value_epochs`` epochs only Q̂ and V̂ learn (``loss`` is
eq. dit-loss); afterwards only the policy does (``loss`` is eq. dit-optimization), with Q̂ and V̂ frozen.
Advantages are centred on their batch mean and divided by their batch standard deviation before exp(Â/η)
(AWR's normalization; ``losses.standardized_advantages``), so η means the same for true rewards and
RewardGen's estimates; the weight is clipped at ``max_weight``. Without the centring
(``center_advantages: false``, the behavior before issue 17) an offset of Q̂ over V̂ of a few standard
deviations clips every weight and DIT becomes behavior cloning. Logged in the policy phase:
``advantage_offset`` (the raw batch mean of Q̂ − V̂ in units of its std: what centring removes),
``clipped_fraction``, ``mean_weight`` and ``weight_std`` (the spread of exp(Â/η)).

``advantage: td`` replaces the paper's Q̂ − V̂ by V̂'s one-step TD error (1 − γ) r_h + γ V̂(s_{h+1}) − V̂(s_h)
(``losses.td_advantages``; Q̂ is still fitted, unused). On DarkRoom the paper's form does not tell the
behavior's good actions from its bad ones (AUC ≈ 0.5, ``scripts/dit_weight_quality.py``): Q̂ and V̂ are two
regressions of the same noisy return whose difference is mostly their errors, while the TD error sees the
action's effect in the next state.

``advantage: return_to_go`` is AWR's Monte Carlo advantage (1 − γ) G_h − V̂(s_h): the return this trajectory
actually collected after the action, against V̂'s estimate for the state (``losses.return_to_go_advantages``).
V̂ only serves as a baseline here, so its errors shift every action of a state alike and cannot reorder them;
the TD error instead needs V̂(s_{h+1}) − V̂(s_h) to resolve one action's effect, which on Reach (a 1 cm move
per step) is below V̂'s error. Measured (docs/RESULTS.md): on Reach it is within noise of Q̂ − V̂; on DarkRoom it
ranks single actions worse than the TD error but makes greedy ICRG on bounded rewards steadier.

This module is DIT on true rewards, the reward-supervised baseline (``reward_trajectory`` data); ICRG
(``methods/icrg.py``) is the same on rewards labeled by RewardGen.
"""

from __future__ import annotations

import torch
from torch import Tensor

from icprl_lightning.contexts import RewardTrajectoryContext
from icprl_lightning.methods.base import InContextModule
from icprl_lightning.methods.losses import (
    advantage_weighted_loss,
    discounted_returns,
    dit_value_loss,
    return_to_go_advantages,
    standardized_advantages,
    td_advantages,
)
from icprl_lightning.models.estimator import InContextEstimator
from icprl_lightning.validation import check_choice, check_int, check_interval, check_positive

# Â = Q̂ − V̂ (paper eq. dit-advantage); "td": r_h + γ V̂(s_{h+1}) − V̂(s_h) (losses.td_advantages);
# "return_to_go": (1 − γ) G_h − V̂(s_h) (losses.return_to_go_advantages)
ADVANTAGES = ("q_minus_v", "td", "return_to_go")


def swap_roles(a: RewardTrajectoryContext, b: RewardTrajectoryContext
               ) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
    """(contexts, scored): ξ_a is the context of ξ_b's transitions and ξ_b of ξ_a's, stacked on the batch axis."""
    def cat(x: RewardTrajectoryContext, y: RewardTrajectoryContext) -> RewardTrajectoryContext:
        return RewardTrajectoryContext(*(torch.cat([u, v]) for u, v in
                                         ((x.states, y.states), (x.actions, y.actions), (x.rewards, y.rewards))))
    return cat(a, b), cat(b, a)


class DITModule(InContextModule):
    """DIT: Q̂, V̂ and the policy T^R(a | s, D^R), all conditioned on a reward trajectory (see module docstring)."""

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, gamma: float = 0.95,
                 eta: float = 1.0, max_weight: float = 20.0, value_epochs: int = 2, n_layer: int = 3,
                 n_embd: int = 64, n_head: int = 4, dropout: float = 0.0, lr: float = 3e-4,
                 weight_decay: float = 0.0, center_advantages: bool = True, advantage: str = "q_minus_v") -> None:
        owner = type(self).__name__
        check_interval(owner, "gamma", gamma, 0.0, 1.0)
        check_positive(owner, "eta", eta)
        check_positive(owner, "max_weight", max_weight)
        check_int(owner, "value_epochs", value_epochs, 0)
        check_choice(owner, "center_advantages", center_advantages, (True, False))
        check_choice(owner, "advantage", advantage, ADVANTAGES)
        super().__init__("reward_trajectory", state_dim, action_dim, discrete, max_context, n_layer, n_embd, n_head,
                         dropout, lr, weight_decay)
        estimator = dict(context_kind="reward_trajectory", state_dim=state_dim, action_spec=self.action_spec,
                         n_layer=n_layer, n_embd=n_embd, n_head=n_head, max_context=max_context, dropout=dropout)
        self.q_value = InContextEstimator(with_action=True, **estimator)
        self.v_value = InContextEstimator(with_action=False, **estimator)

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None, compile: bool = False):
        """Samples a ~ T^R(· | s, D) by default, the paper's deployment: an advantage-weighted clone of the behavior
        is a distribution over its actions, whose argmax can get stuck (e.g. staying put away from the goal)."""
        return super().make_agent(greedy=greedy, use_cache=use_cache, seed=seed, compile=compile)

    def labeled_trajectories(self, batch: dict[str, Tensor]) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
        """The sample's two trajectories with their rewards (here the true ones)."""
        if "rewards_a" not in batch:
            raise KeyError(f"{type(self).__name__} trains on reward-labeled trajectories: use context_kind "
                           "reward_trajectory data (ICRGModule labels preference data with RewardGen)")
        return (RewardTrajectoryContext(batch["states_a"], batch["actions_a"], batch["rewards_a"]),
                RewardTrajectoryContext(batch["states_b"], batch["actions_b"], batch["rewards_b"]))

    @property
    def policy_phase(self) -> bool:
        return self.current_epoch >= self.hparams.value_epochs

    def values(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> tuple[Tensor, Tensor]:
        """Q̂(s_h, a_h | D) and V̂(s_h | D) for every step of ``scored`` -> (B, H) each."""
        return self.q_value(context, scored.states, scored.actions), self.v_value(context, scored.states)

    def advantages(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> Tensor:
        """Â for every step of ``scored`` before normalization -> (B, H): Q̂ − V̂, V̂'s one-step TD error, or the
        return-to-go over V̂."""
        if self.hparams.advantage == "td":
            return td_advantages(self.v_value(context, scored.states), scored.rewards, self.hparams.gamma)
        if self.hparams.advantage == "return_to_go":
            return return_to_go_advantages(self.v_value(context, scored.states), scored.rewards, self.hparams.gamma)
        q, v = self.values(context, scored)
        return q - v

    def log_likelihood(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> Tensor:
        """log T^R(a_h | s_h, D) for each step of ``scored`` -> (B, H); −‖a − μ‖² (Gaussian mean) if continuous."""
        t = context.states.shape[1]
        visible = torch.full((scored.states.shape[1],), t, device=scored.states.device)
        out = self.policy(context, scored.states, visible)
        if self.action_spec.discrete:
            return out.log_softmax(-1).gather(-1, scored.actions.long()[..., None]).squeeze(-1)
        return -(out - scored.actions).pow(2).sum(-1)

    def loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, Tensor]]:
        hp = self.hparams
        context, scored = swap_roles(*self.labeled_trajectories(batch))
        if not self.policy_phase:
            q, v = self.values(context, scored)
            loss = dit_value_loss(q, v, (1 - hp.gamma) * discounted_returns(scored.rewards, hp.gamma))
            return loss, {"value_loss": loss, "advantage_std": (q - v).detach().std()}
        with torch.no_grad():
            raw = self.advantages(context, scored)
            advantage = standardized_advantages(raw, center=hp.center_advantages)
        loss = advantage_weighted_loss(self.log_likelihood(context, scored), advantage, hp.eta, hp.max_weight)
        weight = torch.exp(advantage / hp.eta).clamp(max=hp.max_weight)
        offset = raw.mean() / (raw.std() + 1e-6)
        return loss, {"policy_loss": loss, "mean_weight": weight.mean(), "weight_std": weight.std(),
                      "clipped_fraction": (weight >= hp.max_weight).float().mean(), "advantage_offset": offset}
