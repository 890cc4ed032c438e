"""One T-PRL config's trajectories twice: with their preference labels, and with their latent per-step rewards.

The reward-model measures (``reward_quality``, ``reward_bayes``, ``icrg_labels``) score labels r̂ against the
latent rewards of the very trajectories they label. ``TrajectoryPairs`` and ``RewardTrajectories`` generate
the same trajectories from one family, setting arguments and seed (they differ only in what they store
beside them), so the config's own setting and the other one built from its ``setting.init_args`` (without
the annotator, which changes labels, not trajectories) give two datasets over the same bytes of states and
actions. Each measure checks that it does (a ``ValueError`` otherwise), and scores by ``correlation``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import yaml

from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.config import datamodule_from_config
from icprl_lightning.data.settings import RewardTrajectories, TrajectoryPairs

KINDS = {"trajectory_preference": TrajectoryPairs, "reward_trajectory": RewardTrajectories}


def correlation(x: torch.Tensor, y: torch.Tensor) -> float:
    """Pearson correlation of two equally shaped tensors, pooled over every entry."""
    return float(np.corrcoef(x.flatten().numpy(), y.flatten().numpy())[0, 1])


def tprl_datamodule(config: str | Path, kind: str, root_dir: str | None = None) -> PreferenceDataModule:
    """The config's T-PRL data as ``kind`` (a key of ``KINDS``): the same trajectories with labels
    (``trajectory_preference``) or with their latent rewards (``reward_trajectory``). Not prepared yet: the
    caller checks what it needs of the family and setting before any dataset is generated."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    overrides = {"progress": False, "pairs": False, "query_labels": False}
    if root_dir is not None:
        overrides["root_dir"] = root_dir
    dm = datamodule_from_config(config, **overrides)
    setting = dm.setting
    if type(setting) is not KINDS[kind]:
        section = (yaml.safe_load(Path(config).read_text()) or {}).get("data", {}).get("init_args", {})
        setting_args = dict((section.get("setting") or {}).get("init_args", {}))
        if kind == "reward_trajectory":
            setting_args.pop("annotator", None)  # who labels the pairs does not change the trajectories
        setting = KINDS[kind](**setting_args)
    return PreferenceDataModule(dm.family, setting, **overrides,
                                **({} if root_dir is not None else {"root_dir": dm.root_dir}))
