"""The declared data contract (``icprl_lightning/data_contract.py``): both DataModules implement ``PreferenceData``;
each setting declares what its data offers and the DataModule reads only those declarations; the pairing check
reads the callbacks' ``requires_data`` and the data's ``offers``; a method's input statistics come from what the
DataModule hands over, and the model checks itself against the data (the DataModule never reads the model)."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pytest
from factories import darkroom_data

from icprl_lightning.callbacks.bandit_regret import BanditRegretCallback
from icprl_lightning.callbacks.pair_accuracy import HeldOutPairAccuracyCallback
from icprl_lightning.callbacks.rollout import InContextRolloutCallback
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.importer import import_preferences
from icprl_lightning.data.recorded import RecordedPreferenceDataModule
from icprl_lightning.data.settings import (
    BanditDuels,
    RewardContexts,
    RewardTrajectories,
    StepPreferences,
    TrajectoryPairs,
)
from icprl_lightning.data.settings.base import Setting
from icprl_lightning.data_contract import EVALUATIONS, PreferenceData, ReadsData, missing_members
from icprl_lightning.evaluation.pairing import is_bandit_data
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.methods.dpt import DP2TModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError, check_pairing, pairing_errors

PACKAGE = Path(__file__).resolve().parents[2] / "icprl_lightning"
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=8, n_head=2))

# setting -> (kind, family type, has_folds, has_query_labels, evaluations, per-task argument names)
DECLARATIONS = {
    StepPreferences: ("step_preference", TaskFamily, True, True, {"rollouts"},
                      ("trajectories_per_task", "val_trajectories_per_task")),
    RewardContexts: ("reward", TaskFamily, True, True, {"rollouts"},
                     ("trajectories_per_task", "val_trajectories_per_task")),
    TrajectoryPairs: ("trajectory_preference", TaskFamily, True, True, {"rollouts", "pair_accuracy"},
                      ("trajectories_per_task", "val_trajectories_per_task")),
    RewardTrajectories: ("reward_trajectory", TaskFamily, True, True, {"rollouts"},
                         ("trajectories_per_task", "val_trajectories_per_task")),
    BanditDuels: ("step_preference", LinearDuelingBanditFamily, False, False, {"duels"},
                  ("contexts_per_problem", "val_contexts_per_problem")),
}


def _generated(setting_cls: type[Setting], tmp_path: Path, **kw: Any) -> PreferenceDataModule:
    family = LinearDuelingBanditFamily() if setting_cls is BanditDuels else DarkRoomFamily()
    return PreferenceDataModule(family, setting_cls(), root_dir=str(tmp_path / "data"), **kw)


def _recorded_steps(tmp_path: Path, n_tasks: int = 3, per_task: int = 2, steps: int = 4) -> Path:
    """A tiny recorded I-PRL dataset (2-D states, 3 actions), written by ``icprl import``."""
    rng = np.random.default_rng(0)
    n = n_tasks * per_task
    arrays = {"states": rng.normal(size=(n, steps, 2)), "actions": rng.integers(0, 3, (n, steps)),
              "alt_actions": rng.integers(0, 3, (n, steps)), "preferred": rng.integers(0, 2, (n, steps)),
              "task_index": np.repeat(np.arange(n_tasks), per_task)}
    import_preferences(arrays, tmp_path / "steps", kind="step_preference", n_actions=3, val_fraction=0.34)
    return tmp_path / "steps"


def _recorded_pairs(tmp_path: Path, n_tasks: int = 3, per_task: int = 2, steps: int = 4) -> Path:
    """A tiny recorded T-PRL dataset (3-D states, 2-D continuous actions), written by ``icprl import``."""
    rng = np.random.default_rng(1)
    n = n_tasks * per_task
    arrays = {"states_a": rng.normal(size=(n, steps, 3)), "actions_a": rng.uniform(-1, 1, (n, steps, 2)),
              "states_b": rng.normal(size=(n, steps, 3)), "actions_b": rng.uniform(-1, 1, (n, steps, 2)),
              "preferred": rng.integers(0, 2, n), "task_index": np.repeat(np.arange(n_tasks), per_task)}
    import_preferences(arrays, tmp_path / "pairs", kind="trajectory_preference", action_dim=2, val_fraction=0.34)
    return tmp_path / "pairs"


# ---- both DataModules implement the contract -----------------------------------------------------------

@pytest.mark.parametrize("setting_cls", list(DECLARATIONS), ids=lambda c: c.__name__)
def test_the_generated_datamodule_implements_the_contract_and_offers_what_its_setting_declares(setting_cls, tmp_path):
    dm = _generated(setting_cls, tmp_path)
    assert isinstance(dm, PreferenceData) and missing_members(dm) == []
    assert dm.offers == setting_cls.evaluations and dm.offers <= set(EVALUATIONS)
    assert dm.context_kind == setting_cls.kind
    assert is_bandit_data(dm) == (setting_cls is BanditDuels)
    assert not (tmp_path / "data").exists()  # building and reading the declarations generates nothing


def test_the_recorded_datamodule_implements_the_contract_and_offers_no_evaluation(tmp_path):
    dm = RecordedPreferenceDataModule(str(_recorded_steps(tmp_path)), batch_size=2, pairs=True)
    assert isinstance(dm, PreferenceData) and missing_members(dm) == []
    assert dm.offers == frozenset() and not is_bandit_data(dm)
    for evaluation in ("rollouts", "duels", "pair_accuracy"):
        with pytest.raises(ValueError, match=f"recorded data offers no {evaluation}"):
            dm.held_out(evaluation)


def test_an_object_outside_the_contract_is_named_with_what_it_lacks():
    class Incomplete:
        context_kind = "step_preference"
        pairs = query_labels = False

    assert not isinstance(Incomplete(), PreferenceData)
    lacks = missing_members(Incomplete())
    assert "context_kind" not in lacks and {"state_dim", "action_spec", "offers", "train_arrays"} <= set(lacks)
    (error,) = pairing_errors(ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=10, **SIZES),
                              Incomplete())
    assert "Incomplete does not implement the data contract" in error and "'train_arrays'" in error


# ---- settings declare; the DataModule reads the declarations ----------------------------------------------

@pytest.mark.parametrize("setting_cls", list(DECLARATIONS), ids=lambda c: c.__name__)
def test_each_setting_declares_what_its_data_offers(setting_cls):
    kind, family_type, folds, query_labels, evaluations, keys = DECLARATIONS[setting_cls]
    assert (setting_cls.kind, setting_cls.family_type, setting_cls.has_folds, setting_cls.has_query_labels,
            set(setting_cls.evaluations), setting_cls.per_task_keys) == (kind, family_type, folds, query_labels,
                                                                         evaluations, keys)


def test_the_datamodule_holds_no_family_or_setting_specific_branch():
    """``data/datamodule.py`` imports no family but the base classes, no setting but ``Setting``, asks no
    ``hasattr`` of a setting and tests a setting's type only against ``Setting``."""
    tree = ast.parse((PACKAGE / "data" / "datamodule.py").read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    assert {m for m in imported if ".families" in m} == {"icprl_lightning.families.base"}
    assert {m for m in imported if ".data.settings" in m} == {"icprl_lightning.data.settings.base"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "isinstance"):
            subject = ast.unparse(node.args[0])
            if "setting" in subject:
                assert node.func.id == "isinstance" and ast.unparse(node.args[1]) == "Setting", ast.unparse(node)


class GoalPairs(TrajectoryPairs):
    """A user's setting: T-PRL pairs for DarkRoom only, offering held-out pairs but no rollouts."""

    family_type = DarkRoomFamily
    evaluations = frozenset({"pair_accuracy"})


def test_a_new_settings_declarations_take_effect_without_touching_the_datamodule(tmp_path):
    dm = PreferenceDataModule(DarkRoomFamily(), GoalPairs(), root_dir=str(tmp_path / "data"))
    assert dm.offers == {"pair_accuracy"}
    with pytest.raises(ValueError, match="offers no rollouts"):
        dm.held_out("rollouts")
    assert pairing_errors(object(), dm, [HeldOutPairAccuracyCallback()]) == []
    (error,) = pairing_errors(object(), dm, [InContextRolloutCallback()])
    assert "InContextRolloutCallback reads the held-out rollouts" in error
    with pytest.raises(HyperparameterError, match="family must be a DarkRoomFamily for setting GoalPairs"):
        PreferenceDataModule(LinearDuelingBanditFamily(), GoalPairs(), root_dir=str(tmp_path / "data"))


def test_an_evaluation_the_setting_does_not_offer_is_refused_naming_what_offers_it(tmp_path):
    darkroom = _generated(StepPreferences, tmp_path)
    with pytest.raises(ValueError, match="StepPreferences data offers no duels .*BanditDuels"):
        darkroom.held_out("duels")
    with pytest.raises(ValueError, match="RewardTrajectories data offers no pair_accuracy .*trajectory_preference"):
        _generated(RewardTrajectories, tmp_path).held_out("pair_accuracy")
    with pytest.raises(ValueError, match="BanditDuels data offers no rollouts"):
        _generated(BanditDuels, tmp_path).held_out("rollouts")


@pytest.mark.parametrize(("kwargs", "words"), [
    (dict(query_labels=True), "query_labels must be false with BanditDuels"),
    (dict(folds=2, holdout_fold=0), "holdout_fold must be None with BanditDuels"),
])
def test_what_a_setting_does_not_declare_is_refused_by_name(kwargs, words, tmp_path):
    with pytest.raises(HyperparameterError, match=words):
        _generated(BanditDuels, tmp_path, **kwargs)


# ---- callbacks declare what they read ----------------------------------------------------------------------

@pytest.mark.parametrize(("callback", "evaluation"), [(InContextRolloutCallback(), "rollouts"),
                                                      (BanditRegretCallback(), "duels"),
                                                      (HeldOutPairAccuracyCallback(), "pair_accuracy")],
                         ids=lambda x: type(x).__name__ if not isinstance(x, str) else x)
def test_each_evaluation_callback_declares_what_it_reads(callback, evaluation, tmp_path):
    assert isinstance(callback, ReadsData) and callback.requires_data == (evaluation,)
    offering = {"rollouts": StepPreferences, "duels": BanditDuels,
                "pair_accuracy": TrajectoryPairs}[evaluation]
    for setting_cls in DECLARATIONS:
        errors = pairing_errors(object(), _generated(setting_cls, tmp_path), [callback])
        assert (errors == []) == (evaluation in setting_cls.evaluations), (setting_cls, errors)
    assert evaluation in offering.evaluations


def test_a_users_callback_is_checked_by_its_declaration_not_its_name(tmp_path):
    class MyRegretPlot(L.Callback):
        requires_data = ("duels",)

    darkroom = _generated(StepPreferences, tmp_path)
    (error,) = pairing_errors(object(), darkroom, [MyRegretPlot(), L.Callback()])
    assert error.startswith("MyRegretPlot reads the held-out duels of the data") and "BanditDuels" in error
    assert pairing_errors(object(), _generated(BanditDuels, tmp_path), [MyRegretPlot()]) == []


# ---- input statistics are handed over; the model checks itself against the data ----------------------------

def test_train_arrays_are_the_served_fields_of_the_training_split(data_root):
    dm = darkroom_data("reward", root_dir=data_root, query_labels=True, trajectories_per_task=3,
                       val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2, progress=False)
    dm.prepare_data()
    arrays = dm.train_arrays()
    assert tuple(arrays) == dm.batch_fields() and "rewards" in arrays and "query_states" in arrays
    np.testing.assert_array_equal(arrays["states"], dm.load()["train"]["states"])
    plain = darkroom_data("trajectory_preference", root_dir=data_root, trajectories_per_task=3,
                          val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2,
                          progress=False)
    plain.prepare_data()
    assert set(plain.train_arrays()) == {"states_a", "actions_a", "states_b", "actions_b", "preferred"}


def test_the_recorded_train_arrays_are_its_batch_fields(tmp_path):
    dm = RecordedPreferenceDataModule(str(_recorded_steps(tmp_path)), batch_size=2)
    arrays = dm.train_arrays()
    assert tuple(arrays) == dm.batch_fields() == ("states", "actions", "alt_actions", "preferred")
    np.testing.assert_array_equal(arrays["states"], dm.dataset["train"]["states"])


def test_a_fit_without_the_cli_is_checked_by_the_model_not_by_the_datamodule(tmp_path):
    """A step-preference DP²T on recorded T-PRL pairs: the model's ``on_fit_start`` refuses it, before a step."""
    dm = RecordedPreferenceDataModule(str(_recorded_pairs(tmp_path)), batch_size=2, pairs=True)
    dm.setup("fit")  # the DataModule needs no trainer and no model
    model = DP2TModule(state_dim=3, action_dim=2, discrete=False, max_context=8, **SIZES)
    trainer = L.Trainer(max_steps=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, num_sanity_val_steps=0)
    with pytest.raises(HyperparameterError, match="step_preference contexts but .* holds trajectory_preference"):
        trainer.fit(model, datamodule=dm)
    assert trainer.global_step == 0
    with pytest.raises(HyperparameterError, match="needs RecordedPreferenceDataModule with query_labels"):
        check_pairing(DP2TModule(state_dim=3, action_dim=2, discrete=False, max_context=8,
                                 context_kind="trajectory_preference", **SIZES), dm)
