"""Every user-set hyperparameter is range-checked at construction, and model/data/callback kinds are
checked by ``icprl fit|validate|test`` before any data is generated.

Each bad value raises a ``ValueError`` naming its key; data arguments given through the CLI leave the
data root empty. Method/data/callback mismatches fail in the CLI's ``before_<subcommand>`` hook, before
``prepare_data``.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from icprl_lightning.commands import run_cli
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.settings import (
    BanditDuels,
    RewardContexts,
    RewardTrajectories,
    StepPreferences,
    TrajectoryPairs,
)
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.dpt import DP2TModule, DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import OptimizerConfig, TransformerConfig
from icprl_lightning.validation import HyperparameterError, check_pairing, pairing_errors

SIZES = dict(state_dim=2, action_dim=5, discrete=True, max_context=10)
REWARD_GEN_HP = dict(backbone=dict(n_layer=1, n_embd=8, n_head=2, dropout=0.0), max_context=10)

# ---- the methods --------------------------------------------------------------------------------------

ARCHITECTURE_CASES = [("max_context", 0), ("state_dim", -1), ("action_dim", 0)]
# the groups (the backbone's sizes, the optimizer's settings): checked once, by their dataclass, however a method is
# given them
GROUP_CASES = [(TransformerConfig, key, value) for key, value in (
    ("n_layer", 0), ("n_embd", 0), ("n_head", 0), ("n_head", 3), ("dropout", -0.1), ("dropout", 1.0), ("n_layer", 1.5),
    ("n_embd", True), ("dropout", math.inf))] + [(OptimizerConfig, key, value) for key, value in (
    ("lr", 0.0), ("lr", -1e-3), ("lr", math.nan), ("weight_decay", -0.1), ("lr_schedule", "linear"),
    ("warmup_steps", -1), ("warmup_steps", 0.5))]
METHODS = {
    "ICPOModule": lambda **kw: ICPOModule(**{**SIZES, **kw}),
    "DPTModule": lambda **kw: DPTModule(**{**SIZES, **kw}),
    "DP2TModule": lambda **kw: DP2TModule(**{**SIZES, **kw}),
    "RewardGenModule": lambda **kw: RewardGenModule(**{**SIZES, **kw}),
    "DITModule": lambda **kw: DITModule(**{**SIZES, **kw}),
    "ICRGModule": lambda **kw: ICRGModule(**{**SIZES, "reward_gen_hparams": REWARD_GEN_HP, **kw}),
}
METHOD_CASES = (
    [(m, k, v) for m in METHODS for k, v in ARCHITECTURE_CASES]
    + [("ICPOModule", "beta", 0), ("ICPOModule", "beta", -1.0), ("ICPOModule", "lam", -1),
       ("ICPOModule", "pair_source", "elsewhere"),
       ("ICPOModule", "squared_distance", True), ("ICPOModule", "lambda_on_preferred", True),  # discrete actions
       ("DP2TModule", "context_kind", "reward"), ("DP2TModule", "context_kind", "reward_trajectory"),
       ("DP2TModule", "context_kind", "nonsense"), ("RewardGenModule", "pair_source", "elsewhere")]
    + [(m, k, v) for m in ("DITModule", "ICRGModule")
       for k, v in (("gamma", -0.1), ("gamma", 1.5), ("eta", 0.0), ("eta", -1.0), ("max_weight", 0.0),
                    ("value_epochs", -1), ("center_advantages", "yes"),
                    ("advantage", "q_plus_v"))]
)


@pytest.mark.parametrize(("method", "key", "value"), METHOD_CASES)
def test_method_rejects_bad_hyperparameter(method, key, value):
    with pytest.raises(ValueError, match=key) as err:
        METHODS[method](**{key: value})
    assert method in str(err.value)


@pytest.mark.parametrize(("group", "key", "value"), GROUP_CASES)
def test_a_group_rejects_a_bad_value(group, key, value):
    with pytest.raises(HyperparameterError, match=rf"^{group.group}\.{key}: must "):
        group(**{key: value})


@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.parametrize(("group", "key", "value"), GROUP_CASES[:4] + GROUP_CASES[-7:-3])
def test_method_rejects_a_bad_group_given_as_a_mapping(method, group, key, value):
    with pytest.raises(HyperparameterError, match=rf"^{group.group}\.{key}: must "):
        METHODS[method](**{group.group: {key: value}})


@pytest.mark.parametrize("method", sorted(METHODS))
@pytest.mark.parametrize(("group", "key", "first"),
                         [("backbone", "n_layers", "n_layer"), ("optimizer", "lr_rate", "lr")])
def test_method_rejects_an_unknown_group_key(method, group, key, first):
    with pytest.raises(HyperparameterError, match=rf"^{group}: has no key '{key}'; its keys are \['{first}'"):
        METHODS[method](**{group: {key: 2}})


@pytest.mark.parametrize("method", sorted(METHODS))
def test_methods_build_with_defaults(method):
    METHODS[method]()


def test_icpo_continuous_options_apply_to_continuous_actions():
    ICPOModule(state_dim=3, action_dim=4, discrete=False, max_context=10, lam=2.0, lambda_on_preferred=True,
               squared_distance=True)
    ICPOModule(**SIZES, lam=0.0)  # λ = 0 (the rejected term dropped) is a valid ablation


def test_message_names_owner_key_and_range():
    with pytest.raises(ValueError, match=r"^ICPOModule: beta must be > 0, got 0$"):
        ICPOModule(**SIZES, beta=0)


# ---- settings, families, the DataModule ---------------------------------------------------------------

MDP_SETTINGS = {"StepPreferences": StepPreferences, "TrajectoryPairs": TrajectoryPairs,
                "RewardContexts": RewardContexts, "RewardTrajectories": RewardTrajectories}
MDP_CASES = [("trajectories_per_task", 0), ("trajectories_per_task", -3), ("val_trajectories_per_task", 0),
             ("eval_contexts_per_task", 0), ("calibration_episodes", 0), ("reference_episodes", 0),
             ("quality_targets", (0.8, 0.4, 0.2)), ("quality_targets", (0.2, 0.2, 0.8)),
             ("quality_targets", (0.0, 0.4, 0.8)), ("quality_targets", (0.2, 0.4, 1.0)),
             ("quality_targets", (0.2, 0.4)), ("train_policy", "best"), ("trajectories_per_task", 2.5)]
SETTING_CASES = (
    [(s, k, v) for s in MDP_SETTINGS for k, v in MDP_CASES]
    + [("StepPreferences", "bt_temperature", 0.0), ("StepPreferences", "bt_temperature", -1.0),
       ("StepPreferences", "first_policy", "best"), ("StepPreferences", "next_state_follows", "random"),
       ("StepPreferences", "second_policy", "optimal"),
       ("TrajectoryPairs", "bt_temperature", 0.0), ("TrajectoryPairs", "pretraining_target", 0.0),
       ("TrajectoryPairs", "pretraining_target", 1.0), ("RewardTrajectories", "bt_temperature", -1.0)]
)


@pytest.mark.parametrize(("setting", "key", "value"), SETTING_CASES)
def test_setting_rejects_bad_value(setting, key, value):
    with pytest.raises(ValueError, match=key) as err:
        MDP_SETTINGS[setting](**{key: value})
    assert setting in str(err.value)


BANDIT_SETTING_CASES = [("n_train_problems", 0), ("contexts_per_problem", 0), ("n_val_problems", 0),
                        ("val_contexts_per_problem", 0), ("n_eval_problems", 0), ("eval_sources", ("oracle",)),
                        ("eval_sources", ())]


@pytest.mark.parametrize(("key", "value"), BANDIT_SETTING_CASES)
def test_bandit_setting_rejects_bad_value(key, value):
    with pytest.raises(ValueError, match=f"BanditDuels: {key}"):
        BanditDuels(**{key: value})


FAMILY_CASES = [
    ("DarkRoomFamily", "size", 1), ("DarkRoomFamily", "size", 0), ("DarkRoomFamily", "horizon", 0),
    ("DarkRoomFamily", "n_train_tasks", 0), ("DarkRoomFamily", "n_test_tasks", 0),
    ("DarkRoomFamily", "n_train_tasks", 99),  # 99 + 20 goals > 100 cells
    ("LinearDuelingBanditFamily", "n_arms", 1), ("LinearDuelingBanditFamily", "dim", 0),
    ("LinearDuelingBanditFamily", "horizon", 0), ("LinearDuelingBanditFamily", "bt_temperature", 0.0),
    ("LinearDuelingBanditFamily", "dts_alpha", 0.0),
]
FAMILIES = {"DarkRoomFamily": DarkRoomFamily, "LinearDuelingBanditFamily": LinearDuelingBanditFamily}


@pytest.mark.parametrize(("family", "key", "value"), FAMILY_CASES)
def test_family_rejects_bad_value(family, key, value):
    with pytest.raises(ValueError, match=key) as err:
        FAMILIES[family](**{key: value})
    assert family in str(err.value)


REACH_CASES = [("n_train", 0), ("n_test", 0), ("n_train", 48), ("horizon", 0), ("horizon", 501),
               ("num_workers", -1)]


@pytest.mark.parametrize(("key", "value"), REACH_CASES)
def test_reach_family_rejects_bad_value(key, value):
    pytest.importorskip("metaworld")
    from icprl_lightning.families.metaworld_reach import ReachTaskFamily

    with pytest.raises(ValueError, match=f"ReachTaskFamily: {key}"):
        ReachTaskFamily(**{key: value})


DATAMODULE_CASES = [
    ("batch_size", lambda: dict(batch_size=0)),
    ("trajectories_per_task", lambda: dict(setting=StepPreferences(trajectories_per_task=1), pairs=True)),
    ("val_trajectories_per_task", lambda: dict(setting=StepPreferences(val_trajectories_per_task=1), pairs=True)),
    ("contexts_per_problem", lambda: dict(family=LinearDuelingBanditFamily(),
                                          setting=BanditDuels(contexts_per_problem=1), pairs=True)),
    ("query_labels", lambda: dict(family=LinearDuelingBanditFamily(), setting=BanditDuels(), query_labels=True)),
    ("family", lambda: dict(family=LinearDuelingBanditFamily())),  # an MDP setting on a bandit
    ("family", lambda: dict(setting=BanditDuels())),  # the bandit setting on DarkRoom
    ("setting", lambda: dict(setting="StepPreferences")),
    ("folds", lambda: dict(folds=0)),
    ("holdout_fold", lambda: dict(folds=2, holdout_fold=2)),
]


@pytest.mark.parametrize(("key", "kwargs"), DATAMODULE_CASES)
def test_datamodule_rejects_bad_value(key, kwargs, tmp_path):
    args = dict(family=DarkRoomFamily(), setting=StepPreferences(), root_dir=str(tmp_path / "data"))
    with pytest.raises(ValueError, match=key) as err:
        PreferenceDataModule(**{**args, **kwargs()})
    assert "PreferenceDataModule" in str(err.value)
    assert not (tmp_path / "data").exists()


# ---- through the CLI: nothing generated ---------------------------------------------------------------

def _fit(config: str, root: Path, *extra: str):
    return run_cli(["fit", "--config", config, "--trainer.logger", "false", "--trainer.default_root_dir",
                    str(root), "--data.init_args.root_dir", str(root / "data"), "--data.init_args.progress", "false",
                    *extra])


def _nothing_generated(root: Path) -> bool:
    data = root / "data"
    return not data.exists() or not any(data.iterdir())


SETTING_ARG = "--data.init_args.setting.init_args."
CLI_VALUE_CASES = [
    ("configs/icpo_darkroom.yaml", "beta", ["--model.init_args.beta", "0"]),
    ("configs/icpo_darkroom.yaml", "lam", ["--model.init_args.lam", "-1"]),
    ("configs/icpo_darkroom.yaml", "squared_distance", ["--model.init_args.squared_distance", "true"]),
    ("configs/icpo_darkroom.yaml", "trajectories_per_task", [SETTING_ARG + "trajectories_per_task", "0"]),
    ("configs/icpo_darkroom.yaml", "trajectories_per_task", [SETTING_ARG + "trajectories_per_task", "1"]),  # pairs
    ("configs/icpo_darkroom.yaml", "quality_targets", [SETTING_ARG + "quality_targets", "[0.8, 0.4, 0.2]"]),
    ("configs/icpo_darkroom.yaml", "horizon", ["--data.init_args.family.init_args.horizon", "0"]),
    ("configs/icpo_darkroom.yaml", "batch_size", ["--data.init_args.batch_size", "0"]),
    ("configs/icpo_bandit.yaml", "n_arms", ["--data.init_args.family.init_args.n_arms", "1"]),
    ("configs/dit_darkroom.yaml", "gamma", ["--model.init_args.gamma", "1.5"]),
]


@pytest.mark.parametrize(("config", "key", "extra"), CLI_VALUE_CASES)
def test_cli_bad_value_fails_before_generation(config, key, extra, tmp_path):
    with pytest.raises(HyperparameterError) as err:  # the constructor's own error, not jsonargparse's wrapper
        _fit(config, tmp_path, *extra)
    assert f" {key} " in str(err.value) or f"'s {key} " in str(err.value)
    assert _nothing_generated(tmp_path)


@pytest.mark.parametrize("extra", [["--model.init_args.backbone.n_layer", "0"],
                                   ["--model.init_args.backbone", "{n_embd: 30, n_head: 4}"]])
def test_cli_bad_backbone_fails_before_generation(extra, tmp_path):
    with pytest.raises(HyperparameterError, match=r"^backbone\.n_(layer|head): must ") as err:
        _fit("configs/icpo_darkroom.yaml", tmp_path, *extra)
    assert "\n" not in str(err.value)
    assert _nothing_generated(tmp_path)


KIND_CASES = [
    # (config, overrides, words the message must hold)
    ("configs/icpo_darkroom.yaml", ["--model", "icprl_lightning.methods.dpt.DPTModule"],
     ["DPTModule", "PreferenceDataModule", "reward", "step_preference"]),
    ("configs/dpt_darkroom.yaml", ["--model", "icprl_lightning.methods.icpo.ICPOModule"],
     ["ICPOModule", "PreferenceDataModule", "step_preference", "reward"]),
    ("configs/icpo_darkroom.yaml", ["--model", "icprl_lightning.methods.dit.DITModule"],
     ["DITModule", "reward_trajectory", "step_preference"]),
    ("configs/dp2t_darkroom_tprl.yaml", ["--model", "icprl_lightning.methods.icpo.ICPOModule"],
     ["ICPOModule", "step_preference", "trajectory_preference"]),
    ("configs/icpo_darkroom.yaml", ["--data.init_args.setting", "icprl_lightning.data.settings.RewardContexts"],
     ["ICPOModule", "step_preference", "reward"]),
    ("configs/icpo_darkroom.yaml",
     ["--evaluation", "icprl_lightning.callbacks.bandit_regret.BanditRegretCallback"],
     ["BanditRegretCallback", "duels"]),
    ("configs/icpo_bandit.yaml",
     ["--evaluation", "icprl_lightning.callbacks.rollout.InContextRolloutCallback"],
     ["InContextRolloutCallback", "rollouts"]),
    ("configs/dp2t_darkroom_tprl.yaml",
     ["--evaluation", "icprl_lightning.callbacks.pair_accuracy.HeldOutPairAccuracyCallback",
      "--data.init_args.setting", "icprl_lightning.data.settings.StepPreferences",
      "--model.init_args.context_kind", "step_preference"],
     ["HeldOutPairAccuracyCallback", "pair_accuracy"]),
    ("configs/icpo_darkroom.yaml", ["--data.init_args.pairs", "false"], ["ICPOModule", "pairs"]),
    ("configs/dpt_darkroom.yaml", ["--data.init_args.query_labels", "false"], ["DPTModule", "query_labels"]),
]


@pytest.mark.parametrize(("config", "extra", "words"), KIND_CASES)
def test_cli_kind_mismatch_fails_before_generation(config, extra, words, tmp_path):
    with pytest.raises(ValueError) as err:
        _fit(config, tmp_path, *extra)
    for word in words:
        assert word in str(err.value)
    assert _nothing_generated(tmp_path)


def test_validate_checks_the_pairing_too(tmp_path):
    with pytest.raises(ValueError, match="DPTModule"):
        run_cli(["validate", "--config", "configs/icpo_darkroom.yaml", "--model",
                 "icprl_lightning.methods.dpt.DPTModule", "--trainer.logger", "false",
                 "--trainer.default_root_dir", str(tmp_path), "--data.init_args.root_dir", str(tmp_path / "data")])
    assert _nothing_generated(tmp_path)


def test_matching_pairs_pass():
    darkroom = PreferenceDataModule(DarkRoomFamily(), StepPreferences(), pairs=True, query_labels=True)
    assert pairing_errors(ICPOModule(**SIZES), darkroom) == []
    assert pairing_errors(DP2TModule(**SIZES), darkroom) == []
    tprl = PreferenceDataModule(DarkRoomFamily(), TrajectoryPairs(), pairs=True)
    assert pairing_errors(RewardGenModule(**SIZES), tprl) == []
    assert pairing_errors(ICRGModule(**SIZES, reward_gen_hparams=REWARD_GEN_HP), tprl) == []
    check_pairing(DITModule(**SIZES), PreferenceDataModule(DarkRoomFamily(), RewardTrajectories()))
    with pytest.raises(ValueError, match="DITModule"):
        check_pairing(DITModule(**SIZES), tprl)
