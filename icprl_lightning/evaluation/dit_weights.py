"""What does DIT's weighted clone imitate on DarkRoom? (paper, appendix "Decision Importance Transformer", eqs.
dit-advantage and dit-optimization: the policy clones the behavior's actions with weights exp(Â/η).)

    icprl analyze dit-weights \
        --ckpt runs/reproduce/darkroom_tprl/runs/DIT_true_rewards-seed0/version_0/checkpoints/last.ckpt \
        [--ckpt ...seed1...] [--json PATH]

A DIT checkpoint (true rewards) or an ICRG one (rewards labeled by its RewardGen, as in its training).

An advantage-weighted clone can only beat the behavior if its weights put more mass on good actions than
the behavior does. On DarkRoom an action is *good* when it moves the agent closer to the goal (Manhattan
distance), or stays on it. On the validation trajectories of the training goals (never trained on),
each trajectory of a pair scored with the other as context, exactly as in training (``swap_roles``),
it measures per context quality:

* ``good_fraction``: the behavior's share of good actions (what plain behavior cloning imitates);
* ``weighted_good_fraction``: Σ w·good / Σ w with w = min(exp(Â/η), max_weight) and Â standardized over
  all scored steps as in training (batch-wise there): the share of good actions in DIT's weighted target;
* ``auc``: P(Â of a good action > Â of a bad one), 0.5 = the advantages do not tell them apart;
* ``policy_good_mass``: the trained policy's probability of a good action at the same states: what the clone
  achieved, against the target it was given;
* the weighted fraction and the AUC with ``td_``: Â = V̂'s one-step TD error (``advantage: td``,
  ``losses.td_advantages``), and with ``rtg_``: Â = the return-to-go over V̂ (``advantage: return_to_go``,
  ``losses.return_to_go_advantages``), each from the checkpoint's own V̂, whichever form it was trained with.

Each checkpoint reads its own run's data (``config.yaml`` beside ``checkpoints/``: a table's overrides hold).
Several ``--ckpt`` are training seeds: mean ± sem over them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from icprl_lightning.checkpoints import load_module
from icprl_lightning.data.batches import ContextBatches
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.families.base import QUALITIES
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import step_reward, transition
from icprl_lightning.methods.dit import DITModule, swap_roles
from icprl_lightning.methods.losses import return_to_go_advantages, standardized_advantages, td_advantages
from icprl_lightning.metrics import mean_sem_or_none
from icprl_lightning.samples import Samples


def good_actions(states: np.ndarray, actions: np.ndarray, goals: np.ndarray, size: int,
                 rewards: np.ndarray | None = None) -> np.ndarray:
    """[N, H] bool: the action brings the agent closer to its goal (or keeps it there). ``rewards`` (when the data
    hold them) check the reconstruction: the stored reward must be 1 exactly when the move lands on the goal."""
    cells = states.astype(np.int64)
    nxt = transition(cells, actions.astype(np.int64), size)
    if rewards is not None and not np.array_equal(step_reward(nxt, goals[:, None]), np.asarray(rewards)):
        raise ValueError("the stored rewards do not match DarkRoom's transitions for these goals")
    before = np.abs(cells - goals[:, None]).sum(-1)
    after = np.abs(nxt - goals[:, None]).sum(-1)
    return (after < before) | ((before == 0) & (after == 0))


def auc(scores: np.ndarray, positive: np.ndarray) -> float | None:
    """P(score of a positive > score of a negative), ties counted half (Mann–Whitney); None without both kinds."""
    n_pos, n_neg = positive.sum(), (~positive).sum()
    if n_pos == 0 or n_neg == 0:
        return None
    _, group, counts = np.unique(scores, return_inverse=True, return_counts=True)
    last = np.cumsum(counts)  # 1-based rank of each tie group's last member
    ranks = (last - (counts - 1) / 2)[group]  # every member gets its group's average rank
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def validation_batch(dm) -> tuple[Samples, dict[str, np.ndarray]]:
    """Every validation row as one batch, as the run's loaders build them (ICRG: another pair of the task
    conditions RewardGen, drawn with a fixed seed), and the stored arrays."""
    val = dm.load()["val"]
    data = ContextBatches(val, dm.setting.batch_fields(), dm.trajectories_per_task[1], dm.pairs, False,
                          dm.setting.pair_fields, tasks=True, kind=dm.context_kind)
    torch.manual_seed(0)
    return data[np.arange(len(data))], val


def measure(checkpoint: str | Path) -> dict[str, dict[str, float]]:
    """Every measure of one DIT or ICRG checkpoint, per quality present in its run's validation rows."""
    checkpoint = Path(checkpoint)
    module = load_module(checkpoint).eval()
    if not isinstance(module, DITModule):
        raise ValueError(f"{checkpoint} is a {type(module).__name__}, not a DIT or ICRG checkpoint")
    config = checkpoint.parent.parent / "config.yaml"
    if not config.is_file():
        raise FileNotFoundError(f"{checkpoint}: no config.yaml in its run directory ({config.parent}); this measure "
                                "reads the run's own data")
    dm = datamodule_from_config(config)
    if not isinstance(dm.family, DarkRoomFamily):
        raise ValueError(f"{checkpoint}: this measure is DarkRoom's (good = closer to the goal); "
                         f"the run's family is {type(dm.family).__name__}")
    dm.prepare_data()
    batch, val = validation_batch(dm)
    hp = module.hparams
    with torch.no_grad():  # ICRG: the rewards are RewardGen's labels
        context, scored = swap_roles(*module.labeled_trajectories(batch))  # rows [ξ_b; ξ_a]
        q, v = module.values(context, scored)
        visible = torch.full((scored.states.shape[1],), context.states.shape[1])
        policy = module.policy(context, scored.states, visible).softmax(-1).numpy()  # T^R(· | s_h, D), (2N, H, A)
    forms = {"": q - v, "td_": td_advantages(v, scored.rewards, hp.gamma),  # the paper's Q̂ − V̂; V̂'s TD error;
             "rtg_": return_to_go_advantages(v, scored.rewards, hp.gamma)}  # the return-to-go over V̂
    goals = dm.family.train_goals[np.asarray(val["task_index"])].astype(np.int64)
    good = np.concatenate([good_actions(np.asarray(val[f"states_{s}"]), np.asarray(val[f"actions_{s}"]), goals,
                                        dm.family.size, val.get(f"rewards_{s}")) for s in "ba"])
    states = np.concatenate([np.asarray(val[f"states_{s}"]) for s in "ba"])
    every = np.stack([good_actions(states, np.full(states.shape[:2], a), np.tile(goals, (2, 1)), dm.family.size)
                      for a in range(policy.shape[-1])], -1)  # (2N, H, A): which actions are good at each state
    policy_good = (policy * every).sum(-1)
    quality = np.tile(np.asarray(val["quality"]), 2)
    present = [(i, name) for i, name in enumerate(QUALITIES) if (quality == i).any()]
    out = {name: {"good_fraction": float(good[quality == i].mean()),
                  "policy_good_mass": float(policy_good[quality == i].mean()), "steps": int(good[quality == i].size)}
           for i, name in present}
    for prefix, raw in forms.items():
        advantage = standardized_advantages(raw, center=hp.center_advantages)
        weight = torch.exp(advantage / hp.eta).clamp(max=hp.max_weight).numpy()
        for i, name in present:
            rows = quality == i
            g, w, a = good[rows].ravel(), weight[rows].ravel(), advantage.numpy()[rows].ravel()
            out[name][f"{prefix}weighted_good_fraction"] = float((w * g).sum() / w.sum())
            out[name][f"{prefix}auc"] = auc(a, g)
    return out


MEASURES = ("good_fraction", "weighted_good_fraction", "td_weighted_good_fraction", "rtg_weighted_good_fraction",
            "policy_good_mass", "auc", "td_auc", "rtg_auc")


def dit_weights(checkpoints: Sequence[str | Path]) -> dict[str, Any]:
    """``measure`` of every checkpoint and, per quality and measure, the mean ± sem over them."""
    per_ckpt = {str(c): measure(c) for c in checkpoints}
    summary: dict[str, dict[str, tuple[float | None, float | None]]] = {}
    for q in QUALITIES:
        for m in MEASURES:
            values = [r[q][m] for r in per_ckpt.values() if r.get(q, {}).get(m) is not None]
            summary.setdefault(q, {})[m] = mean_sem_or_none(values) if values else (None, None)
    return {"checkpoints": per_ckpt, "summary": summary}
