"""Do DIT's in-context advantages tell good actions from bad ones? (paper, appendix "Decision Importance
Transformer", eq. dit-advantage: Â = Q̂ − V̂, the weight of each behavior action in the policy loss.)

    icprl analyze dit-advantages \
        --dit configs/dit_metaworld.yaml:runs/dit_metaworld/checkpoints/last.ckpt \
        --icrg configs/icrg_metaworld.yaml:runs/icrg_metaworld/checkpoints/last.ckpt   # optional

On the validation pairs of the training goals (never trained on), both trajectories of each pair are
scored with the other as context, exactly as in training (``swap_roles``). An action's measured quality
is its *progress*: r_h − r_{h−1}, how much closer step h brought the hand to the goal (Reach's latent
reward is −‖tcp − goal‖ after the step). DIT on true rewards reads its context's rewards; ICRG reads
RewardGen's labels r̂ of the same trajectories (the two datasets hold the same states and actions, same
seed). It prints JSON: the Pearson correlation of progress with Â (each model's Q̂ − V̂, the one-step TD
error of its V̂: ``advantage: td``, and the return-to-go over its V̂: ``advantage: return_to_go``) and with
r̂ (ICRG's), and of r̂ with the true per-step reward.
Advantages that do not correlate with progress make the exp(Â/η)-weighted loss a plain behavior clone.

``--oracle`` (Meta-World Reach on the SAC recipe only) also scores every behavior action by the converged SAC
oracle's critic, A*(s_h, a_h) = Q̂*(s_h, a_h) − Q̂*(s_h, π*(s_h)) with π*'s mean action: the paper's A* up to a
per-state constant, what the I-PRL labels compare. Its correlation with each advantage form says whether DIT's
weights rank the behavior's actions as the optimal advantage does. Progress is a noisy proxy (the arm lags its
mocap target, and the progress of a step mixes the state's distance with the action); A* is the action's value.
This reads the privileged oracle and the goals, as a diagnostic may; no learner does.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from icprl_lightning.checkpoints import load_module
from icprl_lightning.data.batches import ContextBatches, other_rows, stored_context
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.evaluation.trajectory_data import correlation
from icprl_lightning.families.metaworld_reach.env import GOAL_SLICE
from icprl_lightning.families.metaworld_reach.sac_family import ReachSACTaskFamily
from icprl_lightning.methods.dit import DITModule, swap_roles
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.losses import discounted_returns, gae_advantages, return_to_go_advantages, td_advantages
from icprl_lightning.samples import ContextSamples, Samples

TRAJECTORY = ("states_a", "actions_a", "states_b", "actions_b")
GAE_LAMBDAS = (0.5, 0.8, 0.9, 0.95)  # between the TD error (λ = 0) and the return-to-go (λ = 1)


def advantages(module: DITModule, batch: Samples) -> dict[str, torch.Tensor]:
    """Q̂ − V̂, V̂'s one-step TD error, the return-to-go over V̂ and the rewards the module saw, for every step of
    the scored trajectories ([ξ_b; ξ_a] rows)."""
    with torch.no_grad():
        context, scored = swap_roles(*module.labeled_trajectories(batch))
        q, v = module.values(context, scored)
    gamma = module.hparams.gamma
    return {"q_minus_v": q - v, "td": td_advantages(v, scored.rewards, gamma),
            "return_to_go": return_to_go_advantages(v, scored.rewards, gamma), "rewards": scored.rewards,
            **{f"gae{lam}": gae_advantages(v, scored.rewards, gamma, lam) for lam in GAE_LAMBDAS}}


def dit_correlations(prefix: str, a: dict[str, torch.Tensor], progress: torch.Tensor) -> dict[str, float]:
    """Correlation of progress (step h ≥ 1) and of the next step's progress with each advantage form."""
    lagged = progress[:, 1:]  # the arm follows its mocap target with a lag: also the progress of the next step
    return {f"corr_progress_vs_{prefix}_advantage": correlation(progress, a["q_minus_v"][:, 1:]),
            f"corr_next_progress_vs_{prefix}_advantage": correlation(lagged, a["q_minus_v"][:, 1:-1]),
            f"corr_progress_vs_{prefix}_td_advantage": correlation(progress, a["td"][:, 1:]),
            f"corr_progress_vs_{prefix}_return_to_go_advantage": correlation(progress, a["return_to_go"][:, 1:]),
            **{f"corr_progress_vs_{prefix}_gae{lam}_advantage": correlation(progress, a[f"gae{lam}"][:, 1:])
               for lam in GAE_LAMBDAS}}


def oracle_advantages(family: ReachSACTaskFamily, split: dict, side: str) -> torch.Tensor:
    """A*(s_h, a_h) = Q̂*(s_h, a_h) − Q̂*(s_h, π*(s_h)) for trajectory ``side`` ("a" or "b") of every row -> (N, H)."""
    states = np.asarray(split[f"states_{side}"], dtype=np.float32)
    actions = np.asarray(split[f"actions_{side}"], dtype=np.float32)
    n, h, _ = states.shape
    obs = states.reshape(n * h, -1).copy()
    obs[:, GOAL_SLICE] = np.repeat(family.tasks("train")[np.asarray(split["task_index"])], h, axis=0)
    weights = family.weights
    greedy = weights.mean_actions(obs)
    q = weights.q_values(obs, np.stack([actions.reshape(n * h, -1), greedy]))
    return torch.as_tensor((q[0] - q[1]).reshape(n, h))


def oracle_correlations(prefix: str, a: dict[str, torch.Tensor], optimal: torch.Tensor) -> dict[str, float]:
    """Correlation of A* with each advantage form, over every scored step."""
    forms = ("q_minus_v", "td", "return_to_go", *(f"gae{lam}" for lam in GAE_LAMBDAS))
    return {f"corr_oracle_advantage_vs_{prefix}_{form}": correlation(optimal, a[form]) for form in forms}


def split_run(option: str, spec: str) -> tuple[str, str]:
    """``CONFIG:CHECKPOINT`` -> (config, checkpoint); a ``ValueError`` naming ``option`` otherwise."""
    config, _, checkpoint = spec.partition(":")
    if not (config and checkpoint):
        raise ValueError(f"{option} {spec!r} is not CONFIG:CHECKPOINT")
    return config, checkpoint


def dit_advantages(dit: str, icrg: str | None = None, oracle: bool = False) -> dict[str, Any]:
    """The correlations of the module docstring for ``dit`` (and ``icrg``), each ``CONFIG:CHECKPOINT``."""
    dit_config, dit_ckpt = split_run("--dit", dit)
    icrg_config, icrg_ckpt = split_run("--icrg", icrg) if icrg else (None, None)
    rewarded = datamodule_from_config(dit_config)
    if oracle and not isinstance(rewarded.family, ReachSACTaskFamily):
        raise ValueError(f"--oracle needs the Reach SAC family, got {type(rewarded.family).__name__}")
    rewarded.prepare_data()
    true = rewarded.load()["val"]
    dit_batch = ContextBatches(true, (*TRAJECTORY, "rewards_a", "rewards_b"), 1, False, False,
                               kind="reward_trajectory")[np.arange(len(true["states_a"]))]
    dit_module = load_module(dit_ckpt).eval()
    if not isinstance(dit_module, DITModule) or isinstance(dit_module, ICRGModule):
        raise ValueError(f"--dit must be a DIT checkpoint, got {type(dit_module).__name__}")
    dit_a = advantages(dit_module, dit_batch)
    reward = dit_a["rewards"]
    progress = reward[:, 1:] - reward[:, :-1]  # step h ≥ 1: distance before it minus distance after it
    out = {"pairs": len(true["states_a"]), "steps_scored": int(progress.numel()),
           **dit_correlations("dit", dit_a, progress)}
    optimal = None
    if oracle:
        # scored rows are [ξ_b; ξ_a] (swap_roles)
        optimal = torch.cat([oracle_advantages(rewarded.family, true, side) for side in "ba"])
        returns = (1 - dit_module.hparams.gamma) * discounted_returns(reward, dit_module.hparams.gamma)
        out.update({"oracle_advantage_std": float(optimal.std()),
                    "corr_oracle_advantage_vs_progress": correlation(optimal[:, 1:], progress),
                    "corr_oracle_advantage_vs_return_to_go": correlation(optimal, returns),
                    **oracle_correlations("dit", dit_a, optimal)})
    if icrg_config is not None:
        preferences = datamodule_from_config(icrg_config)
        preferences.prepare_data()
        pref = preferences.load()["val"]
        for k in TRAJECTORY:
            if not np.array_equal(true[k], pref[k]):
                raise ValueError(f"{dit_config} and {icrg_config} do not hold the same trajectories ({k} differs)")
        rows = np.arange(len(pref["preferred"]))
        other = other_rows(rows, preferences.trajectories_per_task[1], 1)  # the next validation pair of the same goal
        icrg_batch = ContextSamples(stored_context("trajectory_preference", pref, rows),
                                    stored_context("trajectory_preference", pref, other))
        icrg_module = load_module(icrg_ckpt).eval()
        if not isinstance(icrg_module, ICRGModule):
            raise ValueError(f"--icrg must be an ICRG checkpoint, got {type(icrg_module).__name__}")
        icrg_a = advantages(icrg_module, icrg_batch)
        out.update(dit_correlations("icrg", icrg_a, progress))
        out["corr_progress_vs_reward_hat"] = correlation(progress, icrg_a["rewards"][:, 1:])
        out["corr_true_reward_vs_reward_hat"] = correlation(reward, icrg_a["rewards"])
        if optimal is not None:
            out.update(oracle_correlations("icrg", icrg_a, optimal))
    return out
