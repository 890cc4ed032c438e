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
(``center_advantages: false``) an offset of Q̂ over V̂ of a few standard
deviations clips every weight and DIT becomes behavior cloning. Logged in the policy phase:
``advantage_offset`` (the raw batch mean of Q̂ − V̂ in units of its std: what centring removes),
``clipped_fraction``, ``mean_weight`` and ``weight_std`` (the spread of exp(Â/η)).

``advantage: td`` replaces the paper's Q̂ − V̂ by V̂'s one-step TD error (1 − γ) r_h + γ V̂(s_{h+1}) − V̂(s_h)
(``losses.td_advantages``; Q̂ is still fitted, unused). On DarkRoom the paper's form does not tell the
behavior's good actions from its bad ones (AUC ≈ 0.5, ``icprl analyze dit-weights``): Q̂ and V̂ are two
regressions of the same noisy return whose difference is mostly their errors, while the TD error sees the
action's effect in the next state.

``advantage: return_to_go`` is AWR's Monte Carlo advantage (1 − γ) G_h − V̂(s_h): the return this trajectory
actually collected after the action, against V̂'s estimate for the state (``losses.return_to_go_advantages``).
V̂ only serves as a baseline here, so its errors shift every action of a state alike and cannot reorder them;
the TD error instead needs V̂(s_{h+1}) − V̂(s_h) to resolve one action's effect, which on Reach (a 1 cm move
per step) is below V̂'s error. Measured (``icprl reproduce metaworld_dit_advantages``, ``darkroom_return_to_go``):
on Reach it is within noise of Q̂ − V̂; on DarkRoom it ranks single actions worse than the TD error but makes
greedy ICRG on bounded rewards steadier.

``value_auxiliary`` c > 0 (our change, not the paper's) adds c · mean((v_θ(s_h | D) − (1 − γ) G_h)²) / var((1 − γ) G)
(the batch's unexplained fraction of the return's variance, 1 − R², so that c weighs it against the policy loss at
any reward scale) to every epoch's loss, v_θ a linear head on the *policy's* transformer outputs at its query
tokens (``policy_value_head``, unused at deployment). On Reach the behavior's actions hardly depend on the goal, so
imitating them, however weighted, gives the policy no reason to read its context (``icprl reproduce
metaworld_dit_goal_signal``: the same return with another goal's context); predicting the return-to-go does,
since the reward is the distance to the goal. The auxiliary regression is meant to make the policy's own features
carry the goal for its action head; the policy trains from the first epoch. Measured on Reach (the same table):
the head ends at 1 − R² = 0.58 (validation, last epoch) and the policy still returns the same with another goal's
context.

``advantage: oracle`` (an oracle baseline, like the true rewards themselves) weights each behavior action by the
family oracle's optimal advantage A*(s_h, a_h), served with the data (``RewardTrajectories(oracle_advantages=True)``,
fields ``advantages_a``/``advantages_b``) and standardized as the others. Q̂ and V̂ are then unused (set
``value_epochs: 0``). It swaps DIT's advantage stage for its oracle: if this policy does not beat the behavior
either, the weighted clone of the data is what limits DIT, not its advantage estimate.

``normalize_inputs`` standardizes states and rewards for the policy, Q̂ and V̂ with the training split's statistics
(``models/normalization.py``; not the paper's).

Validation also logs the value loss with the own context and with another task's in its place
(``value_loss_own_context``, ``value_loss_other_task``; rows whose task is the same are left out) and the policy's
log-likelihood of the behavior's actions under both (``log_likelihood_own_context``, ``log_likelihood_other_task``):
how much of what Q̂, V̂ and T^R predict they read off the context.

This module is DIT on true rewards, the reward-supervised baseline (``reward_trajectory`` data); ICRG
(``methods/icrg.py``) is the same on rewards labeled by RewardGen.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

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
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.estimator import InContextEstimator
from icprl_lightning.samples import Samples
from icprl_lightning.validation import check_choice, check_int, check_interval, check_nonnegative, check_positive

# Â = Q̂ − V̂ (paper eq. dit-advantage); "td": r_h + γ V̂(s_{h+1}) − V̂(s_h) (losses.td_advantages);
# "return_to_go": (1 − γ) G_h − V̂(s_h) (losses.return_to_go_advantages); "oracle": the family oracle's A*(s_h, a_h)
# served with the data (RewardTrajectories(oracle_advantages=True)), the advantage stage's oracle
ADVANTAGES = ("q_minus_v", "td", "return_to_go", "oracle")
ORACLE_FIELDS = ("advantages_a", "advantages_b")


def swap_roles(a: RewardTrajectoryContext, b: RewardTrajectoryContext
               ) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
    """(contexts, scored): ξ_a is the context of ξ_b's transitions and ξ_b of ξ_a's, stacked on the batch axis."""
    def cat(x: RewardTrajectoryContext, y: RewardTrajectoryContext) -> RewardTrajectoryContext:
        return RewardTrajectoryContext(*(torch.cat([u, v]) for u, v in
                                         ((x.states, y.states), (x.actions, y.actions), (x.rewards, y.rewards))))
    return cat(a, b), cat(b, a)


def unexplained_variance(predictions: Tensor, targets: Tensor) -> Tensor:
    """mean (prediction − target)² / var(target) over the batch: 1 − R², 1 for predicting the mean."""
    return (predictions - targets).pow(2).mean() / (targets.var(unbiased=False).detach() + 1e-12)


class DITModule(InContextModule):
    """DIT: Q̂, V̂ and the policy T^R(a | s, D^R), all conditioned on a reward trajectory (see module docstring)."""

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *, gamma: float = 0.95,
                 eta: float = 1.0, max_weight: float = 20.0, value_epochs: int = 2,
                 backbone: TransformerConfig = DEFAULT_BACKBONE, optimizer: OptimizerConfig = DEFAULT_OPTIMIZER,
                 center_advantages: bool = True, advantage: str = "q_minus_v", value_auxiliary: float = 0.0,
                 normalize_inputs: bool = False) -> None:
        owner = type(self).__name__
        check_interval(owner, "gamma", gamma, 0.0, 1.0)
        check_positive(owner, "eta", eta)
        check_positive(owner, "max_weight", max_weight)
        check_int(owner, "value_epochs", value_epochs, 0)
        check_choice(owner, "center_advantages", center_advantages, (True, False))
        check_choice(owner, "advantage", advantage, ADVANTAGES)
        check_nonnegative(owner, "value_auxiliary", value_auxiliary)
        super().__init__("reward_trajectory", state_dim, action_dim, discrete, max_context, backbone=backbone,
                         optimizer=optimizer, normalize_inputs=normalize_inputs)
        estimator = dict(context_kind="reward_trajectory", state_dim=state_dim, action_spec=self.action_spec,
                         backbone=self.backbone, max_context=max_context, normalize_inputs=normalize_inputs)
        self.q_value = InContextEstimator(with_action=True, **estimator)
        self.v_value = InContextEstimator(with_action=False, **estimator)
        self.policy_value_head = nn.Linear(self.backbone.n_embd, 1) if value_auxiliary > 0 else None

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None, compile: bool = False):
        """Samples a ~ T^R(· | s, D) by default, the paper's deployment: an advantage-weighted clone of the behavior
        is a distribution over its actions, whose argmax can get stuck (e.g. staying put away from the goal)."""
        return super().make_agent(greedy=greedy, use_cache=use_cache, seed=seed, compile=compile)

    def labeled_trajectories(self, batch: Samples) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
        """The sample's two trajectories with their rewards (here the true ones, ``RewardTrajectorySamples``)."""
        return batch.trajectory_a, batch.trajectory_b

    @property
    def policy_phase(self) -> bool:
        return self.current_epoch >= self.hparams.value_epochs

    def values(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> tuple[Tensor, Tensor]:
        """Q̂(s_h, a_h | D) and V̂(s_h | D) for every step of ``scored`` -> (B, H) each."""
        return self.q_value(context, scored.states, scored.actions), self.v_value(context, scored.states)

    def advantages(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> Tensor:
        """Â for every step of ``scored`` before normalization -> (B, H): Q̂ − V̂, V̂'s one-step TD error, or the
        return-to-go over V̂ (under ``advantage: oracle`` the policy reads A* from the batch instead,
        ``policy_advantages``; this then gives Q̂ − V̂)."""
        if self.hparams.advantage == "td":
            return td_advantages(self.v_value(context, scored.states), scored.rewards, self.hparams.gamma)
        if self.hparams.advantage == "return_to_go":
            return return_to_go_advantages(self.v_value(context, scored.states), scored.rewards, self.hparams.gamma)
        q, v = self.values(context, scored)
        return q - v

    @property
    def needs_batch_fields(self) -> tuple[str, ...]:
        """Fields beyond the reward trajectories that the loss reads (checked against the data before a fit)."""
        return ORACLE_FIELDS if self.hparams.advantage == "oracle" else ()

    def policy_advantages(self, batch: Samples, context: RewardTrajectoryContext,
                          scored: RewardTrajectoryContext) -> Tensor:
        """The raw advantage of every step of ``scored`` ([ξ_b; ξ_a] rows, ``swap_roles``) for the policy loss."""
        if self.hparams.advantage != "oracle":
            return self.advantages(context, scored)
        return torch.cat([batch.advantages_b, batch.advantages_a]).to(scored.rewards.dtype)

    def policy_outputs(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext
                       ) -> tuple[Tensor, Tensor | None]:
        """log T^R(a_h | s_h, D) for each step of ``scored`` -> (B, H), −‖a − μ‖² (Gaussian mean) if continuous;
        and the policy's own return-to-go estimate v_θ(s_h | D) -> (B, H), or None without ``value_auxiliary``."""
        t = context.states.shape[1]
        visible = torch.full((scored.states.shape[1],), t, device=scored.states.device)
        features = self.policy.features(context, scored.states, visible)
        out = self.policy.head(features)
        if self.action_spec.discrete:
            log_likelihood = out.log_softmax(-1).gather(-1, scored.actions.long()[..., None]).squeeze(-1)
        else:
            log_likelihood = -(out - scored.actions).pow(2).sum(-1)
        value = None if self.policy_value_head is None else self.policy_value_head(features).squeeze(-1)
        return log_likelihood, value

    def log_likelihood(self, context: RewardTrajectoryContext, scored: RewardTrajectoryContext) -> Tensor:
        """log T^R(a_h | s_h, D) for each step of ``scored`` -> (B, H); −‖a − μ‖² (Gaussian mean) if continuous."""
        return self.policy_outputs(context, scored)[0]

    def loss(self, batch: Samples) -> tuple[Tensor, dict[str, Tensor]]:
        hp = self.hparams
        context, scored = swap_roles(*self.labeled_trajectories(batch))
        returns = (1 - hp.gamma) * discounted_returns(scored.rewards, hp.gamma)
        auxiliary = self.policy_value_head is not None
        if not self.policy_phase:
            q, v = self.values(context, scored)
            loss = dit_value_loss(q, v, returns)
            metrics = {"value_loss": loss, "advantage_std": (q - v).detach().std()}
            if auxiliary:
                policy_value = self.policy_outputs(context, scored)[1]
                metrics["policy_value_loss"] = unexplained_variance(policy_value, returns)
                loss = loss + hp.value_auxiliary * metrics["policy_value_loss"]
            return loss, metrics
        with torch.no_grad():
            raw = self.policy_advantages(batch, context, scored)
            advantage = standardized_advantages(raw, center=hp.center_advantages)
        log_likelihood, policy_value = self.policy_outputs(context, scored)
        loss = advantage_weighted_loss(log_likelihood, advantage, hp.eta, hp.max_weight)
        weight = torch.exp(advantage / hp.eta).clamp(max=hp.max_weight)
        offset = raw.mean() / (raw.std() + 1e-6)
        metrics = {"policy_loss": loss, "mean_weight": weight.mean(), "weight_std": weight.std(),
                   "clipped_fraction": (weight >= hp.max_weight).float().mean(), "advantage_offset": offset}
        if auxiliary:
            metrics["policy_value_loss"] = unexplained_variance(policy_value, returns)
            loss = loss + hp.value_auxiliary * metrics["policy_value_loss"]
        return loss, metrics

    def validation_step(self, batch: Samples, batch_idx: int) -> None:
        super().validation_step(batch, batch_idx)
        if batch.task is not None:
            self.log_dict({f"val/{k}": v for k, v in self.context_reading(batch).items()}, sync_dist=True,
                          batch_size=batch.batch_size)

    @torch.no_grad()
    def context_reading(self, batch: Samples) -> dict[str, Tensor]:
        """Value loss and log-likelihood of the behavior's actions with the own context and with another task's
        (each row's context taken from the previous row, rows of the same task left out; empty dict if none)."""
        context, scored = swap_roles(*self.labeled_trajectories(batch))
        task = torch.cat([batch.task, batch.task])
        previous = torch.roll(torch.arange(len(task), device=task.device), 1)
        keep = task[previous] != task
        if not keep.any():
            return {}
        other = RewardTrajectoryContext(context.states[previous], context.actions[previous],
                                        context.rewards[previous])
        returns = (1 - self.hparams.gamma) * discounted_returns(scored.rewards, self.hparams.gamma)
        out = {}
        for name, ctx in (("_own_context", context), ("_other_task", other)):
            q, v = self.values(ctx, scored)
            out[f"value_loss{name}"] = dit_value_loss(q[keep], v[keep], returns[keep])
            out[f"log_likelihood{name}"] = self.log_likelihood(ctx, scored)[keep].mean()
        return out
