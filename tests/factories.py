"""Test shorthands: a PreferenceDataModule from one flat list of keyword arguments.

Each keyword goes where it belongs (the family, the setting or the DataModule), with the settings each
family's configs use (configs/*.yaml), so a test names only what it changes.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.settings import (
    BanditDuels,
    RewardContexts,
    RewardTrajectories,
    StepPreferences,
    TrajectoryPairs,
)
from icprl_lightning.data.settings.base import rollout_behavior
from icprl_lightning.data.settings.trajectory_pairs import label_trajectory_pairs
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily

REPO = Path(__file__).resolve().parents[1]
# the smallest DarkRoom data and model a CLI run can train, validate and roll out (override a shipped config)
TINY_DATA = ["--data.init_args.setting.init_args.trajectories_per_task", "3",
             "--data.init_args.setting.init_args.val_trajectories_per_task", "2",
             "--data.init_args.setting.init_args.eval_contexts_per_task", "2",
             "--data.init_args.setting.init_args.calibration_episodes", "2",
             "--data.init_args.setting.init_args.reference_episodes", "2",
             "--data.init_args.progress", "false"]
TINY_MODEL = ["--model.init_args.backbone", "{n_layer: 1, n_embd: 16, n_head: 2}"]
SETTINGS = {"step_preference": StepPreferences, "reward": RewardContexts, "trajectory_preference": TrajectoryPairs,
            "reward_trajectory": RewardTrajectories}
REACH_SETTING = {"val_trajectories_per_task": 2, "eval_contexts_per_task": 4, "calibration_episodes": 8,
                 "reference_episodes": 6}


def _params(cls: type) -> set[str]:
    names = set()
    for klass in cls.__mro__:
        if "__init__" in vars(klass):
            names |= {p for p in inspect.signature(klass.__init__).parameters if p not in ("self", "kwargs")}
    return names


def build(family_cls: type, setting_cls: type, defaults: dict[str, Any], kw: dict[str, Any],
          renames: dict[str, str] | None = None) -> PreferenceDataModule:
    kw = {(renames or {}).get(k, k): v for k, v in {**defaults, **kw}.items()}
    fam = {k: kw.pop(k) for k in list(kw) if k in _params(family_cls)}
    setting = {k: kw.pop(k) for k in list(kw) if k in _params(setting_cls)}
    return PreferenceDataModule(family=family_cls(**fam), setting=setting_cls(**setting), **kw)


def darkroom_data(context_kind: str = "step_preference", **kw: Any) -> PreferenceDataModule:
    defaults = {"trajectories_per_task": 60} if context_kind in ("trajectory_preference", "reward_trajectory") else {}
    kw.setdefault("reference_episodes", kw.get("calibration_episodes", 25))  # DarkRoom's configs: the same count
    return build(DarkRoomFamily, SETTINGS[context_kind], defaults, kw)


def reach_data(context_kind: str = "step_preference", **kw: Any) -> PreferenceDataModule:
    from icprl_lightning.families.metaworld_reach import ReachTaskFamily

    defaults = dict(REACH_SETTING)
    if context_kind == "step_preference":
        defaults.update(first_policy="low", train_policy="high", bt_temperature=0.02, trajectories_per_task=20)
    elif context_kind == "reward":
        defaults.update(trajectories_per_task=20)
    else:
        defaults.update(train_policy="pretraining", trajectories_per_task=10)
    return build(ReachTaskFamily, SETTINGS[context_kind], defaults, kw, RENAMES["reach"])


def bandit_data(**kw: Any) -> PreferenceDataModule:
    return build(LinearDuelingBanditFamily, BanditDuels, {"pairs": True}, kw)


def step_contexts(family, goals, p_second, bt_temperature, rng, p_first=None, **setting_kw):
    """I-PRL contexts of ``StepPreferences`` with one mixing level per row (``p_second`` [N]); the first
    side is uniform, or the mixture at ``p_first`` (one level for all rows)."""
    n = len(goals)
    setting = StepPreferences(first_policy="uniform" if p_first is None else "low", bt_temperature=bt_temperature,
                              **setting_kw)
    mixing = np.array([0.0 if p_first is None else p_first, *np.broadcast_to(p_second, (n,))])
    return setting.contexts(family, goals, 1 + np.arange(n), mixing, rng, False, False, "")


def reward_contexts(family, goals, p, rng):
    """DPT reward contexts of ``RewardContexts`` with one mixing level per row."""
    return RewardContexts().contexts(family, goals, np.arange(len(goals)), np.asarray(p, dtype=float), rng, False,
                                     False, "")


def trajectory_pairs(family, goals, p, bt_temperature, rng, behavior=False, queries=False):
    """T-PRL pairs with their latent rewards kept apart: ``(arrays, rewards, stats)``, one mixing level per row."""
    n, k = len(goals), 3 if behavior else 2
    roll = rollout_behavior(family, np.tile(goals, (k, 1)), np.tile(p, k), rng, episodes=True, progress=False,
                            description="")
    arrays, rewards, stats = label_trajectory_pairs(roll["states"], roll["actions"], roll["rewards"], n,
                                                    bt_temperature, rng, behavior)
    if queries:
        visited = np.concatenate([roll["states"][:n], roll["states"][n:2 * n]], axis=1)
        optimal = np.concatenate([roll["optimal"][:n], roll["optimal"][n:2 * n]], axis=1)
        arrays.update(family.oracle.query_labels(goals, visited, optimal, family.horizon, rng))
    return arrays, rewards, stats


RENAMES = {"reach": {"n_train_tasks": "n_train", "n_test_tasks": "n_test", "tprl_quality": "pretraining_target"}}


def _family_class(family: str) -> type:
    if family == "reach":
        from icprl_lightning.families.metaworld_reach import ReachTaskFamily

        return ReachTaskFamily
    return {"darkroom": DarkRoomFamily, "bandit": LinearDuelingBanditFamily}[family]


DATAMODULE_PARAMS = set(inspect.signature(PreferenceDataModule.__init__).parameters) - {"self", "family", "setting"}


def cli_data_args(family: str, **kw: Any) -> list[str]:
    """``--data.init_args...`` command-line arguments, each routed to the family, the setting or the DataModule."""
    params, renames = _params(_family_class(family)), RENAMES.get(family, {})
    out = []
    for key, value in kw.items():
        key = renames.get(key, key)
        where = "" if key in DATAMODULE_PARAMS else "family.init_args." if key in params else "setting.init_args."
        text = str(value).lower() if isinstance(value, bool) else str(value)
        if isinstance(value, list | tuple):
            text = "[" + ", ".join(map(str, value)) + "]"
        out += [f"--data.init_args.{where}{key}", text]
    return out


def tiny_darkroom_args(root: str | Path) -> list[str]:
    """``--data.init_args...`` of the smallest DarkRoom dataset a CLI run can train and evaluate on, under ``root``."""
    return cli_data_args("darkroom", root_dir=str(root), trajectories_per_task=3, val_trajectories_per_task=2,
                         eval_contexts_per_task=1, calibration_episodes=2, reference_episodes=2, progress=False)


def config_args(config: str | Path) -> list[str]:
    """``--config`` arguments for a config; an overlay (``configs/paper/``) is stacked on its ``# base:``."""
    path = Path(config)
    base = re.search(r"^# base: (\S+)$", path.read_text(), re.M)
    if base is None:
        return ["--config", str(path)]
    return ["--config", str(REPO / base.group(1)), "--config", str(path)]


def darkroom_tprl_config(path: Path, data_root: str, setting: dict[str, Any]) -> Path:
    """A data-only config of DarkRoom T-PRL pairs at ``path`` (what ``icprl analyze``'s ``--data-config`` reads)."""
    path.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.TrajectoryPairs", "init_args": setting},
                      "root_dir": data_root, "pairs": True}}}))
    return path


def save_untrained(module, path: Path) -> Path:
    """Save ``module`` as training does (Lightning's checkpoint dict, our on_save_checkpoint), without a fit."""
    import lightning as L

    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, accelerator="cpu", default_root_dir=path.parent)
    trainer.strategy.connect(module)
    trainer.save_checkpoint(path)
    return path


def served_fields(batch) -> set[str]:
    """The fields a typed training batch (``icprl_lightning.samples``) serves: its members that are not None, a
    context's own fields dotted (``context.states``, ``pair.preferred``, ``trajectory_a.rewards``, ``task``)."""
    import dataclasses

    out = set()
    for name, value in batch._asdict().items():
        if dataclasses.is_dataclass(value):
            out |= {f"{name}.{f.name}" for f in dataclasses.fields(value) if getattr(value, f.name) is not None}
        elif value is not None:
            out.add(name)
    return out


# tiny DarkRoom T-PRL data (the tprl / tprl_rewards fixtures of conftest.py, and CLI runs on the same sizes)
TPRL_TINY = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2,
                 calibration_episodes=2, progress=False, batch_size=8)
