"""Do DIT's in-context advantages tell good actions from bad ones? (paper, appendix "Decision Importance
Transformer", eq. dit-advantage: Â = Q̂ − V̂, the weight of each behavior action in the policy loss.)

    python scripts/dit_advantage_check.py \
        --dit configs/dit_metaworld.yaml:runs/dit_metaworld/checkpoints/last.ckpt \
        --icrg configs/icrg_metaworld.yaml:runs/icrg_metaworld/checkpoints/last.ckpt

On the validation pairs of the training goals (never trained on), both trajectories of each pair are
scored with the other as context, exactly as in training (``swap_roles``). An action's measured quality
is its *progress*: r_h − r_{h−1}, how much closer step h brought the hand to the goal (Reach's latent
reward is −‖tcp − goal‖ after the step). DIT on true rewards reads its context's rewards; ICRG reads
RewardGen's labels r̂ of the same trajectories (the two datasets hold the same states and actions, same
seed). Prints JSON: the Pearson correlation of progress with Â (each model's Q̂ − V̂, the one-step TD
error of its V̂: ``advantage: td``, and the return-to-go over its V̂: ``advantage: return_to_go``) and with
r̂ (ICRG's), and of r̂ with the true per-step reward.
Advantages that do not correlate with progress make the exp(Â/η)-weighted loss a plain behavior clone.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from icprl_lightning.checkpoints import load_module  # noqa: E402
from icprl_lightning.data.batches import other_rows, to_tensor
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.methods.dit import DITModule, swap_roles
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.losses import return_to_go_advantages, td_advantages

TRAJECTORY = ("states_a", "actions_a", "states_b", "actions_b")


def correlation(x: torch.Tensor, y: torch.Tensor) -> float:
    return float(np.corrcoef(x.flatten().numpy(), y.flatten().numpy())[0, 1])


def advantages(module: DITModule, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Q̂ − V̂, V̂'s one-step TD error, the return-to-go over V̂ and the rewards the module saw, for every step of
    the scored trajectories ([ξ_b; ξ_a] rows)."""
    with torch.no_grad():
        context, scored = swap_roles(*module.labeled_trajectories(batch))
        q, v = module.values(context, scored)
    gamma = module.hparams.gamma
    return {"q_minus_v": q - v, "td": td_advantages(v, scored.rewards, gamma),
            "return_to_go": return_to_go_advantages(v, scored.rewards, gamma), "rewards": scored.rewards}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dit", required=True, help="CONFIG:CHECKPOINT of DIT on true rewards")
    parser.add_argument("--icrg", required=True, help="CONFIG:CHECKPOINT of ICRG")
    args = parser.parse_args()
    (dit_config, _, dit_ckpt), (icrg_config, _, icrg_ckpt) = (s.partition(":") for s in (args.dit, args.icrg))
    rewarded, preferences = datamodule_from_config(dit_config), datamodule_from_config(icrg_config)
    rewarded.prepare_data()
    preferences.prepare_data()
    true, pref = rewarded.load()["val"], preferences.load()["val"]
    for k in TRAJECTORY:
        if not np.array_equal(true[k], pref[k]):
            raise ValueError(f"{dit_config} and {icrg_config} do not hold the same trajectories ({k} differs)")
    rows = np.arange(len(pref["preferred"]))
    other = other_rows(rows, preferences.trajectories_per_task[1], 1)  # the next validation pair of the same goal
    dit_batch = {k: to_tensor(np.asarray(true[k])) for k in (*TRAJECTORY, "rewards_a", "rewards_b")}
    icrg_batch = {k: to_tensor(np.asarray(pref[k])) for k in (*TRAJECTORY, "preferred")}
    icrg_batch.update({f"pair_{k}": to_tensor(np.asarray(pref[k])[other]) for k in (*TRAJECTORY, "preferred")})

    dit, icrg = load_module(dit_ckpt).eval(), load_module(icrg_ckpt).eval()
    if not (isinstance(dit, DITModule) and isinstance(icrg, ICRGModule)):
        raise ValueError(f"--dit must be a DIT and --icrg an ICRG checkpoint, got {type(dit).__name__} and "
                         f"{type(icrg).__name__}")
    dit_a, icrg_a = advantages(dit, dit_batch), advantages(icrg, icrg_batch)
    dit_adv, icrg_adv, reward, reward_hat = dit_a["q_minus_v"], icrg_a["q_minus_v"], dit_a["rewards"], icrg_a["rewards"]
    progress = reward[:, 1:] - reward[:, :-1]  # step h ≥ 1: distance before it minus distance after it
    # the arm follows its mocap target with a lag: also the progress of the step after the action
    lagged = progress[:, 1:]
    print(json.dumps({
        "pairs": len(rows), "steps_scored": int(progress.numel()),
        "corr_progress_vs_dit_advantage": correlation(progress, dit_adv[:, 1:]),
        "corr_progress_vs_icrg_advantage": correlation(progress, icrg_adv[:, 1:]),
        "corr_next_progress_vs_dit_advantage": correlation(lagged, dit_adv[:, 1:-1]),
        "corr_next_progress_vs_icrg_advantage": correlation(lagged, icrg_adv[:, 1:-1]),
        "corr_progress_vs_dit_td_advantage": correlation(progress, dit_a["td"][:, 1:]),
        "corr_progress_vs_icrg_td_advantage": correlation(progress, icrg_a["td"][:, 1:]),
        "corr_progress_vs_dit_return_to_go_advantage": correlation(progress, dit_a["return_to_go"][:, 1:]),
        "corr_progress_vs_icrg_return_to_go_advantage": correlation(progress, icrg_a["return_to_go"][:, 1:]),
        "corr_progress_vs_reward_hat": correlation(progress, reward_hat[:, 1:]),
        "corr_true_reward_vs_reward_hat": correlation(reward, reward_hat),
    }, indent=2))


if __name__ == "__main__":
    main()
