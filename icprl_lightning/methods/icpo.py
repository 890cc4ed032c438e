"""In-Context Preference Optimization (ICPO), paper section 5.2.

Discrete actions (final I-PRL objective, uniform reference policy):
    max_θ Σ log σ(β (log T_θ(a⁺ | s, D) − λ log T_θ(a⁻ | s, D)))
Continuous actions (appendix "ICPO for Continuous Control"): the Gaussian-mean form, see
``losses.icpo_continuous_loss``.

No optimal-action labels, no rewards: only the comparisons. Where the scored comparisons come from
(``pair_source``):

* ``"other_trajectory"`` (default): comparisons of another trajectory of the same task. Query t sees
  the first t + 1 context comparisons (all H queries, or ``queries_per_context`` drawn ones in training).
  The comparison being scored is never in the context, so the model must infer the task from the
  context rather than copy a label it can see.

  Which of the other trajectory's comparisons query t scores (``pair_steps``):

  - ``"shuffled"`` (default): a random one, a fresh permutation of its H steps per sample and step, as
    DPT draws its query states. The number of visible context comparisons then says nothing about how
    far into an episode the scored state lies. Validation draws its permutation too (from the global
    seed), so ``val/loss`` carries that draw's noise.
  - ``"aligned"``: its step t. It teaches the model to
    read the context's length as a clock: query t always scores a state t steps into an episode, while a
    deployed agent sees the whole context at every step. On Meta-World Reach with the SAC oracle's
    behavior (which reaches the goal in ≈ 25 steps and then hovers past it) an aligned ICPO acts as if it
    were late in the episode from its first step, moving away from the goal;
    ``experiments/reach_action_probe.py`` shows it.
* ``"next"``: each context step's own comparison, scored before it is seen: query t sees the first t
  comparisons of D and scores comparison t + 1 (at its state s_{t+1}), for t = 0..H−1. With
  ``pair_steps: shuffled`` D's steps are put in a fresh random order per sample and step first, so
  "the first t" is a random subset and the scored step a random other one (no clock); ``aligned`` keeps
  the stored order. No second trajectory is read (``pairs: false``). It is what the ``merged`` layout
  (``models/policy.py``) computes in one causal pass of H tokens, and the only source that layout
  takes: its tokens hold each step's state ahead of the step's comparison.
* ``"context"``: the paper's literal form — the comparisons of D itself, each scored with the whole D
  in view (T_θ(a | s_h, D) with D ∋ (s_h, a_h, a'_h, y_h)).

Soft labels: a scored comparison labelled y ∈ (0, 1) (a person's tie, y = 1/2: ``icprl label --export``) is
scored in both orders, weighted y and 1 − y (``losses.soft_label_loss``); labels of 0 and 1 take the path
above unchanged.
"""

from __future__ import annotations

import torch
from torch import Tensor

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.methods.base import InContextModule
from icprl_lightning.methods.losses import icpo_continuous_loss, icpo_loss, soft_label_loss
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.tokenizers import preferred_first
from icprl_lightning.preferences import has_soft_labels
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_choice, check_nonnegative, check_positive

PAIR_SOURCES = ("other_trajectory", "next", "context")
PAIR_STEPS = ("shuffled", "aligned")


class ICPOModule(InContextModule):
    soft_labels = True  # trains on labels in [0, 1] (ties as 1/2), checked against the data by the CLI
    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *, beta: float = 1.0,
                 lam: float = 0.5, pair_source: str = "other_trajectory", lambda_on_preferred: bool = False,
                 squared_distance: bool = False, backbone: TransformerConfig = DEFAULT_BACKBONE,
                 optimizer: OptimizerConfig = DEFAULT_OPTIMIZER, queries_per_context: int | None = None,
                 pair_steps: str = "shuffled", normalize_inputs: bool = False, layout: str = "appended") -> None:
        check_choice("ICPOModule", "pair_source", pair_source, PAIR_SOURCES)
        check_choice("ICPOModule", "pair_steps", pair_steps, PAIR_STEPS)
        check_positive("ICPOModule", "beta", beta)
        check_nonnegative("ICPOModule", "lam", lam)  # λ = 0 drops the rejected term; λ > 1 is Meta-World's
        if discrete:
            for key, value in (("lambda_on_preferred", lambda_on_preferred), ("squared_distance", squared_distance)):
                if value:
                    raise HyperparameterError(f"ICPOModule: {key} applies to continuous actions only (the "
                                              f"Gaussian-mean loss), but this data's actions are discrete; got "
                                              f"{key}={value!r}, must be false")
        if layout == "merged" and pair_source != "next":
            raise HyperparameterError(f"ICPOModule: layout 'merged' scores each context step before its comparison "
                                      f"is seen, which is pair_source 'next'; got pair_source={pair_source!r}")
        if layout == "merged" and queries_per_context is not None:
            raise HyperparameterError(f"ICPOModule: layout 'merged' scores all H steps in one pass of H tokens, so "
                                      f"queries_per_context would not shorten it; got {queries_per_context!r}, "
                                      "must be null")
        super().__init__("step_preference", state_dim, action_dim, discrete, max_context, backbone=backbone,
                         optimizer=optimizer, queries_per_context=queries_per_context,
                         normalize_inputs=normalize_inputs, layout=layout)

    @property
    def needs_pairs(self) -> bool:  # type: ignore[override]
        """pair_source other_trajectory scores another row of the same task: the data's ``pairs``."""
        return self.hparams.pair_source == "other_trajectory"

    def scored_steps(self, batch_size: int, length: int, device: torch.device) -> Tensor:
        """[B, H]: the step of the other trajectory that query position t scores, per sample (``pair_steps``);
        for ``pair_source: next``, the order of the context's own steps."""
        if self.hparams.pair_steps == "aligned":
            return torch.arange(length, device=device).expand(batch_size, length)
        return torch.rand(batch_size, length, device=device).argsort(-1)

    def loss(self, batch: ContextSamples) -> tuple[Tensor, dict[str, Tensor]]:
        hp = self.hparams
        context = batch.context
        t = context.states.shape[1]
        if hp.pair_source == "other_trajectory":
            positions = self.query_positions(t, context.states.device)
            steps = self.scored_steps(context.states.shape[0], t, context.states.device)[:, positions]
            rows = torch.arange(len(steps), device=steps.device)[:, None]
            pairs = batch.pair.map(lambda x: x[rows, steps])
            outputs = self.policy(context, pairs.states, positions + 1)
        elif hp.pair_source == "next":
            order = self.scored_steps(context.states.shape[0], t, context.states.device)
            rows = torch.arange(len(order), device=order.device)[:, None]
            context = pairs = context.map(lambda x: x[rows, order])
            if self.policy.merged:
                outputs = self.policy.next_step_outputs(context)
            else:
                positions = self.query_positions(t, context.states.device)
                pairs = context.map(lambda x: x[:, positions])
                outputs = self.policy(context, pairs.states, positions)
        else:
            pairs = context
            outputs = self.policy(context, pairs.states, torch.full((t,), t, device=context.states.device))
        if has_soft_labels(pairs.preferred):
            return self._soft_loss(outputs, pairs)
        plus, minus = preferred_first(pairs)
        if self.action_spec.discrete:
            logp = outputs.log_softmax(-1)
            lp_plus = logp.gather(-1, plus[..., None]).squeeze(-1)
            lp_minus = logp.gather(-1, minus[..., None]).squeeze(-1)
            loss = icpo_loss(lp_plus, lp_minus, hp.beta, hp.lam)
            agree = (lp_plus > lp_minus).float().mean()
        else:
            loss = icpo_continuous_loss(outputs, plus, minus, hp.beta, hp.lam, hp.lambda_on_preferred,
                                        hp.squared_distance)
            agree = ((outputs - plus).norm(dim=-1) < (outputs - minus).norm(dim=-1)).float().mean()
        return loss, {"pair_agreement": agree}

    def _soft_loss(self, outputs: Tensor, pairs: StepPreferenceContext) -> tuple[Tensor, dict[str, Tensor]]:
        """y ℓ(a ≻ a') + (1 − y) ℓ(a' ≻ a) of each scored comparison (``losses.soft_label_loss``), and the
        agreement with the labels (a tie counts one half, whichever order the policy favours)."""
        hp, a, b, y = self.hparams, pairs.actions, pairs.alt_actions, pairs.preferred
        if self.action_spec.discrete:
            logp = outputs.log_softmax(-1)
            lp_a, lp_b = logp.gather(-1, a[..., None]).squeeze(-1), logp.gather(-1, b[..., None]).squeeze(-1)
            first, second = icpo_loss(lp_a, lp_b, hp.beta, hp.lam, False), icpo_loss(lp_b, lp_a, hp.beta, hp.lam, False)
            a_favoured = lp_a > lp_b
        else:
            args = (hp.beta, hp.lam, hp.lambda_on_preferred, hp.squared_distance, False)
            first, second = icpo_continuous_loss(outputs, a, b, *args), icpo_continuous_loss(outputs, b, a, *args)
            a_favoured = (outputs - a).norm(dim=-1) < (outputs - b).norm(dim=-1)
        agree = torch.where(a_favoured, y, 1 - y).mean()
        return soft_label_loss(first, second, y), {"pair_agreement": agree}
