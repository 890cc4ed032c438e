"""RewardGen: ICRG's in-context reward estimator R_ψ(s, a | D^T) (paper section 5.3, eq. (L_R^T)).

R_ψ, conditioned on a T-PRL pair (ξ⁺, ξ⁻), is trained with the Bradley–Terry likelihood of a pair's
label over the per-step sums of its rewards, −log σ(Σ_h R_ψ(s⁺_h, a⁺_h | D^T) − Σ_h R_ψ(s⁻_h, a⁻_h | D^T)).
Which pair is scored (``pair_source``):

* ``"other_pair"`` (default): another pair of the same task (the samples' ``pair``, ``data.pairs: true``) is
  the context. The scored transitions are not in view, so their rewards must come from the task the
  model infers from the context. This is how R_ψ is used: ICRG labels trajectories that are not in its
  context (another pair's in pretraining, the unlabeled behavior trajectory at deployment).
* ``"context"``: the paper's literal form, the context pair's own transitions, every query seeing the
  whole context. The label is then part of the context of the pair it scores, and matching each query to
  the winner's tokens fits the loss without inferring the task: copyable, not a fair test of the form.
* ``"context_causal"``: the paper's form read causally: the query for step h of either trajectory sees
  only the context's tokens of steps < h (step 0 sees none), neither the scored transition nor anything
  later. The rule belongs to R_ψ (``InContextRewardModel(causal=True)``, saved as the hyperparameter
  ``causal`` that ICRG copies), so ICRG's relabeling and deployment read their pair context the same way:
  step h of a labeled trajectory sees the context's steps < h. Still not leak-free: s_h continues one of
  the two trajectories whose steps < h are in view, in their winner/loser slots (``models/estimator.py``).

``reward_range`` [low, high] (default: unbounded) bounds every per-step reward, r̂ = low + (high − low) σ(f):
the Bradley–Terry sums then live on the latent returns' scale (the labels' temperature is 1), and a
transition can only carry reward in proportion to how much it may (DarkRoom: [0, 1]). ICRG copies it.

All 2H transitions of the scored pair are queries in one pass; without the causal rule each sees the
whole context (the paper's "read out at the last time step", see ``models/estimator.py``). Logged:
``loss`` and ``pair_accuracy`` (summed rewards order the pair as its label does); the held-out tasks'
accuracy comes from ``HeldOutPairAccuracyCallback``. Each validation epoch stores the mean and std of R_ψ's outputs on
the validation pairs in the model, for ICRG's standardized labels.

RewardGen is not a policy: deploy it through an ICRG checkpoint (``methods/icrg.py``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from icprl_lightning.contexts import ActionSpec, TrajectoryPreferenceContext
from icprl_lightning.methods.base import MethodModule, save_groups
from icprl_lightning.methods.losses import trajectory_preference_loss
from icprl_lightning.models.config import DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.estimator import InContextRewardModel
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import (
    check_choice,
    check_int,
    check_range,
    check_sizes,
)

PAIR_SOURCES = ("other_pair", "context", "context_causal")
REWARD_GEN_BACKBONE = TransformerConfig(n_layer=4, n_embd=32, n_head=4)  # R_ψ's default: deeper and narrower


class RewardGenModule(MethodModule):
    consumes = ("trajectory_preference",)  # the data kind it trains on (checked by the CLI)
    soft_labels = True  # its Bradley–Terry cross-entropy takes a label in [0, 1]: a tie (1/2) as it is
    needs_query_labels = False

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 pair_source: str = "other_pair", reward_range: list[float] | None = None,
                 backbone: TransformerConfig = REWARD_GEN_BACKBONE, optimizer: OptimizerConfig = DEFAULT_OPTIMIZER,
                 normalize_inputs: bool = False) -> None:
        owner = "RewardGenModule"
        check_choice(owner, "pair_source", pair_source, PAIR_SOURCES)
        check_choice(owner, "normalize_inputs", normalize_inputs, (True, False))
        bounds = check_range(owner, "reward_range", reward_range)
        check_sizes(owner, state_dim, action_dim)
        check_int(owner, "max_context", max_context, 1)
        super().__init__()
        self.backbone, self.optimizer_config = save_groups(self, backbone, optimizer)
        causal = pair_source == "context_causal"
        self.hparams["causal"] = causal  # R_ψ's reading rule, saved for ICRG to copy (icrg.ARCHITECTURE)
        self.action_spec = ActionSpec(discrete=discrete, size=action_dim)
        self.reward = InContextRewardModel(state_dim, self.action_spec, self.backbone, max_context, causal=causal,
                                           reward_range=bounds, normalize_inputs=normalize_inputs)
        self._moments = torch.zeros(3, dtype=torch.float64)  # count, sum, sum of squares of val outputs

    @property
    def needs_pairs(self) -> bool:
        """pair_source other_pair conditions on another pair of the same task: the data's ``pairs``."""
        return self.hparams.pair_source == "other_pair"

    def forward(self, context: TrajectoryPreferenceContext, states: Tensor, actions: Tensor) -> Tensor:
        """Raw rewards R_ψ(s, a | context) for states (B, Q, S), actions (B, Q) -> (B, Q)."""
        return self.reward(context, states, actions)

    def pair_rewards(self, batch: ContextSamples) -> tuple[Tensor, Tensor, Tensor]:
        """(Σ_h r̂(ξ_a), Σ_h r̂(ξ_b), r̂ (B, 2H)) of the scored pair ``batch.context``, conditioned per
        ``pair_source`` (on ``batch.pair`` for ``other_pair``)."""
        scored = batch.context
        return self.score_pair(batch.pair if self.hparams.pair_source == "other_pair" else scored, scored)

    def score_pair(self, context: TrajectoryPreferenceContext, scored: TrajectoryPreferenceContext
                   ) -> tuple[Tensor, Tensor, Tensor]:
        """(Σ_h r̂(ξ_a), Σ_h r̂(ξ_b), r̂ (B, 2H)) of ``scored``'s trajectories under R_ψ(· | context), read by
        R_ψ's rule (causally: step h of either trajectory sees the context's steps < h)."""
        h = scored.states_a.shape[1]
        r = self(context, torch.cat([scored.states_a, scored.states_b], 1),
                 torch.cat([scored.actions_a, scored.actions_b], 1))
        return r[:, :h].sum(1), r[:, h:].sum(1), r

    @torch.no_grad()
    def pair_correct(self, batch: ContextSamples) -> Tensor:
        """(B,) bool: the summed rewards order each scored pair as its label does."""
        ret_a, ret_b, _ = self.pair_rewards(batch)
        return (ret_a > ret_b) == (batch.context.preferred > 0.5)

    def loss(self, batch: ContextSamples) -> tuple[Tensor, dict[str, Tensor], Tensor]:
        ret_a, ret_b, r = self.pair_rewards(batch)
        preferred = batch.context.preferred
        loss = trajectory_preference_loss(ret_a, ret_b, preferred)
        accuracy = ((ret_a > ret_b) == (preferred > 0.5)).float().mean()
        return loss, {"pair_accuracy": accuracy}, r

    def training_step(self, batch: ContextSamples, batch_idx: int) -> Tensor:
        loss, metrics, _ = self.loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.batch_size)
        self.log_dict({f"train/{k}": v for k, v in metrics.items()}, batch_size=batch.batch_size)
        return loss

    def on_validation_epoch_start(self) -> None:
        self._moments.zero_()

    def validation_step(self, batch: ContextSamples, batch_idx: int) -> None:
        loss, metrics, r = self.loss(batch)
        self.log("val/loss", loss, prog_bar=True, batch_size=batch.batch_size)
        self.log_dict({f"val/{k}": v for k, v in metrics.items()}, batch_size=batch.batch_size)
        r = r.detach().double().cpu()
        self._moments += torch.stack([torch.tensor(float(r.numel()), dtype=torch.float64), r.sum(), r.pow(2).sum()])

    def on_validation_epoch_end(self) -> None:
        n, total, squares = self._moments.tolist()
        if n > 1:
            mean = total / n
            std = max((squares / n - mean**2) ** 0.5, 1e-6)
            self.reward.reward_mean.fill_(mean)
            self.reward.reward_std.fill_(std)

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None, compile: bool = False):
        raise TypeError("a RewardGen checkpoint holds a reward model, not a policy: train ICRG on it (configs/"
                        "icrg_darkroom.yaml, model.init_args.reward_gen_checkpoint) and deploy that checkpoint")
