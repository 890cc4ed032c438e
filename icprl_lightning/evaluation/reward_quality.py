r"""RewardGen's reward quality on the held-out tasks, per context quality (``icprl analyze reward-quality``).

    icprl analyze reward-quality --data-config configs/reward_gen_darkroom.yaml \
        --ckpt runs/icprl/<seed 0>/checkpoints/best.ckpt [--ckpt <seed 1> ...] [--json quality.json]

Several ``--ckpt`` are training seeds of one configuration (one ``pair_source``): mean ± sem over them of each
measure's mean over held-out pairs. The measures of R_ψ(s, a | ξ⁺, ξ⁻) (paper section 5.3, eq. (L_R^T)):

* ``other_pair_accuracy``: R_ψ conditioned on another pair of the same held-out task orders the scored
  pair as its label does (``held_out("pair_accuracy")``): the scored transitions are not in view, the fair test.
* ``own_pair_accuracy``: R_ψ scores the context's own pair (the paper's form) under the checkpoint's
  reading rule: causal for ``pair_source=context_causal`` (step h sees the context's steps < h; still
  leaky through the states, see ``models/estimator.py``), the whole context otherwise. Leaky by
  construction for ``pair_source=context`` models (trained to read the scored transitions' winner/loser
  slot); an ``other_pair`` model was never trained on this form.
* ``reward_correlation``: Pearson correlation, pooled over steps and tasks, of R_ψ's per-step labels r̂
  with the latent per-step rewards on the held-out unlabeled behavior trajectories, each labeled with its
  evaluation pair as context (``InContextRewardModel.label``, as ICRG deploys; read by the same rule); the
  latent rewards from the ``RewardTrajectories`` dataset over the same trajectories (``trajectory_data``).

Chance accuracy is 0.5; tied returns carry coin-flip labels, so the ceiling is the manifest's label
agreement (``eval_label_statistics`` in the JSON).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from icprl_lightning.checkpoints import load_module
from icprl_lightning.contexts import TrajectoryPreferenceContext
from icprl_lightning.evaluation.trajectory_data import correlation, tprl_datamodule
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.metrics import mean_sem_or_none
from icprl_lightning.samples import ContextSamples

MEASURES = {"other_pair_accuracy": "accuracy, other pair (fair)", "own_pair_accuracy": "accuracy, own pair",
            "reward_correlation": "corr(r̂, latent r)"}
ROWS = 64  # held-out pairs per forward pass: bounds the attention's memory on long Meta-World horizons


def own_pair_note(pair_source: str) -> str:
    """What the own-pair accuracy means for a checkpoint trained with ``pair_source``."""
    return {"other_pair": "whole context; this model was trained on other pairs, not on its context's own",
            "context": "whole context: LEAKY, the model reads the scored transitions' winner/loser slot",
            "context_causal": "causal (step h sees the context's steps < h); still leaky through the states"
            }[pair_source]


def rows(context: TrajectoryPreferenceContext, start: int) -> TrajectoryPreferenceContext:
    """Contexts [start, start + ROWS) of a batch."""
    return context.map(lambda x: x[start:start + ROWS])


@torch.no_grad()
def pair_accuracy(model: RewardGenModule, context: TrajectoryPreferenceContext,
                  scored: TrajectoryPreferenceContext) -> float:
    """Share of ``scored``'s pairs whose summed r̂ under R_ψ(· | context) order them as their labels do."""
    correct = []
    for start in range(0, scored.batch_size, ROWS):
        chunk = rows(scored, start)
        ret_a, ret_b, _ = model.score_pair(rows(context, start), chunk)
        correct.append((ret_a > ret_b) == (chunk.preferred > 0.5))
    return float(torch.cat(correct).float().mean())


@torch.no_grad()
def label_correlation(model: RewardGenModule, context: TrajectoryPreferenceContext, rewards: torch.Tensor) -> float:
    """Pearson correlation of r̂ on the behavior trajectories (labeled with their pair) with the latent rewards."""
    labels = torch.cat([model.reward.label(c, c.behavior_states, c.behavior_actions)
                        for c in (rows(context, start) for start in range(0, context.batch_size, ROWS))])
    return correlation(labels, rewards)


def evaluate(model: RewardGenModule, pairs: dict[str, ContextSamples],
             suites: dict[str, TrajectoryPreferenceContext], rewards: dict[str, torch.Tensor]
             ) -> dict[str, dict[str, float]]:
    """The three measures of one checkpoint, per quality."""
    out = {}
    for q in QUALITIES:
        scored, other = pairs[q].context, pairs[q].pair
        out[q] = {"other_pair_accuracy": pair_accuracy(model, other, scored),
                  "own_pair_accuracy": pair_accuracy(model, scored, scored),
                  "reward_correlation": label_correlation(model, suites[q], rewards[q])}
    return out


def load_reward_gen(path: str | Path) -> RewardGenModule:
    """A RewardGen checkpoint, read as untrusted (allow-listed class, checksum verified)."""
    model = load_module(path)
    if not isinstance(model, RewardGenModule):
        raise ValueError(f"--ckpt {path} is a {type(model).__name__} checkpoint, not RewardGen's")
    return model.eval()


def reward_quality(data_config: str | Path, checkpoints: Sequence[str | Path], data_root: str | None = None
                   ) -> dict[str, Any]:
    """The measures of every checkpoint on ``data_config``'s held-out pairs and their mean ± sem over checkpoints."""
    models = [(str(path), load_reward_gen(path)) for path in checkpoints]
    sources = {m.hparams.pair_source for _, m in models}
    if len(sources) != 1:
        raise ValueError(f"--ckpt: the checkpoints mix pair_source values {sorted(sources)}; pass the training "
                         "seeds of one configuration per run")
    pair_source = sources.pop()
    labeled = tprl_datamodule(data_config, "trajectory_preference", data_root)
    if labeled.setting.eval_contexts_per_task < 2:
        raise ValueError(f"--data-config {data_config}: setting eval_contexts_per_task must be >= 2 for another pair "
                         f"of each held-out task, got {labeled.setting.eval_contexts_per_task}")
    rewarded = tprl_datamodule(data_config, "reward_trajectory", data_root)
    labeled.prepare_data()
    rewarded.prepare_data()
    suites = {s.quality: s.context for s in labeled.held_out("rollouts")}
    rewards = {}
    for oracle in rewarded.held_out("rollouts"):
        if not torch.equal(oracle.context.states, suites[oracle.quality].behavior_states):
            raise ValueError(f"--data-config {data_config}: the reward and preference datasets' {oracle.quality} "
                             "behavior trajectories differ (regenerate both from one config)")
        rewards[oracle.quality] = oracle.context.rewards
    pairs = labeled.held_out("pair_accuracy")
    per_checkpoint = [{"checkpoint": path, **evaluate(model, pairs, suites, rewards)} for path, model in models]
    summary: dict[str, dict[str, dict[str, float | None]]] = {}
    for q in QUALITIES:
        summary[q] = {}
        for k in MEASURES:
            mean, sem = mean_sem_or_none([r[q][k] for r in per_checkpoint])
            summary[q][k] = {"mean": mean, "sem": sem}
    info = labeled.load().manifest["info"]
    return {"data_config": str(data_config), "pair_source": pair_source, "causal": models[0][1].reward.causal,
            "own_pair_reading": own_pair_note(pair_source), "checkpoints": [path for path, _ in models],
            "mean": summary, "per_checkpoint": per_checkpoint, "eval_label_statistics": info["eval_statistics"]}


def table(summary: dict[str, dict[str, dict[str, float | None]]]) -> str:
    """The mean ± sem of each measure, one row per quality (markdown)."""
    def cell(m: dict[str, float | None]) -> str:
        return f"{m['mean']:.3f}" + ("" if m["sem"] is None else f" ± {m['sem']:.3f}")

    lines = ["| quality | " + " | ".join(MEASURES.values()) + " |", "|---|" + "---|" * len(MEASURES)]
    lines += [f"| {q} | " + " | ".join(cell(summary[q][k]) for k in MEASURES) + " |" for q in QUALITIES]
    return "\n".join(lines)
