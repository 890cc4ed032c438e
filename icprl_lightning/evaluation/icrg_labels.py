r"""ICRG's reward labels against the latent reward: in pretraining (what DIT learns from) and at deployment.

    icprl analyze icrg-labels --config <icrg run>/config.yaml \
        --ckpt <in-sample ICRG>/checkpoints/last.ckpt --ckpt <cross-fitted ICRG>/checkpoints/last.ckpt

The relabeling stage of ICRG (paper section 5.3) in numbers. For each ICRG checkpoint:

* ``training``: the labels ICRG's DIT stage learned from, made exactly as in training
  (``ICRGModule.labeled_trajectories``: R_ψ conditioned on another pair of the same training goal; with
  cross-fitting, by the RewardGen that left that goal's fold out), on ``--rows`` training rows drawn with
  ``--seed``;
* ``deployment``: the labels ICRG's agent gives the held-out goals' unlabeled behavior trajectories,
  per context quality (``ICRGAgent.reset``).

Each is the Pearson correlation, pooled over steps and trajectories, of the standardized labels r̂ with the
latent per-step rewards of the same trajectories (the ``RewardTrajectories`` dataset over the same bytes,
``trajectory_data``). In-sample labels on the training goals beside deployment labels on unseen goals show
how much sharper the labels DIT learned from were than those it acts on; cross-fitted labels should sit
closer to the deployment ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from icprl_lightning.checkpoints import load_module
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.deploy import load_agent
from icprl_lightning.evaluation.trajectory_data import correlation, tprl_datamodule
from icprl_lightning.methods.icrg import ICRGModule


@torch.no_grad()
def training_labels(model: ICRGModule, pairs: PreferenceDataModule, rewards: PreferenceDataModule, rows: int,
                    seed: int) -> float:
    """Correlation of the labels ICRG trains on (``rows`` training rows) with their latent rewards."""
    train = pairs.train_dataloader().dataset  # ContextBatches: a whole batch per list of rows
    generator = torch.Generator().manual_seed(seed)
    index = torch.randperm(len(train), generator=generator)[:rows].sort().values.tolist()
    torch.manual_seed(seed)  # the other pair of each row's task
    batch = train[index]
    true = rewards.load()["train"]
    if not np.array_equal(true["states_a"][index], batch.context.states_a.numpy()):
        raise ValueError("the reward and preference datasets hold different training trajectories")
    a, b = model.labeled_trajectories(batch)
    return correlation(torch.cat([a.rewards, b.rewards], 1),
                       torch.from_numpy(np.concatenate([true["rewards_a"][index], true["rewards_b"][index]], 1)))


@torch.no_grad()
def deployment_labels(checkpoint: str | Path, pairs: PreferenceDataModule, rewards: PreferenceDataModule
                      ) -> dict[str, float]:
    """Per quality, the correlation of the agent's labels of the held-out behavior trajectories with the latent ones."""
    agent = load_agent(checkpoint)
    out = {}
    for suite, oracle in zip(pairs.held_out("rollouts"), rewards.held_out("rollouts"), strict=True):
        agent.reset(suite.context)
        out[suite.quality] = correlation(agent.labeled_context.rewards, oracle.context.rewards)
    return out


def icrg_labels(config: str | Path, checkpoints: Sequence[str | Path], rows: int = 2000, seed: int = 0,
                data_root: str | None = None) -> dict[str, Any]:
    """Both correlations of every ICRG checkpoint, on ``config``'s data."""
    pairs = tprl_datamodule(config, "trajectory_preference", data_root)
    rewards = tprl_datamodule(config, "reward_trajectory", data_root)
    pairs.prepare_data()
    rewards.prepare_data()
    pairs.pairs = True  # ICRG labels each pair conditioned on another pair of its goal
    pairs.setup("fit")
    results = {}
    for path in checkpoints:
        model = load_module(path)  # weights_only, allow-listed class, checksum verified
        if not isinstance(model, ICRGModule):
            raise ValueError(f"--ckpt {path} is a {type(model).__name__} checkpoint, not ICRG's")
        results[str(path)] = {"cross_fitted": model.cross_fit is not None,
                              "training": training_labels(model.eval(), pairs, rewards, rows, seed),
                              "deployment": deployment_labels(path, pairs, rewards)}
    return {"config": str(config), "rows": rows, "seed": seed, "correlation": results}
