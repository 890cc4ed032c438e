"""A method given data its loss cannot read is refused by the pairing check (``validation.check_pairing``, run by
``icprl fit|validate|test`` and by a method's ``on_fit_start``), before any data is generated, with one sentence
naming the flag or the setting to change; the losses read their typed samples without guards of their own."""

from __future__ import annotations

import pytest

from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.data.settings import RewardContexts, RewardTrajectories, StepPreferences, TrajectoryPairs
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.dpt import DP2TModule, DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.icrg import ICRGModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.validation import HyperparameterError, check_pairing

ENV = dict(state_dim=2, action_dim=5, discrete=True, max_context=100, backbone=TransformerConfig(1, 8, 2))
STAGE1 = {"backbone": {"n_layer": 1, "n_embd": 8, "n_head": 2}, "max_context": 100}
PAIRS = r"\(as configured\) needs PreferenceDataModule with pairs: true; set --data.init_args.pairs true"
LABELS = r"\(as configured\) needs PreferenceDataModule with query_labels: true; set --data.init_args.query_labels true"

CASES = {  # the model, the data that does not serve what its loss reads (setting, flags), the one that does
    "icpo_other_trajectory": (lambda: ICPOModule(**ENV), (StepPreferences(), {}), (StepPreferences(), {"pairs": True}),
                              f"ICPOModule {PAIRS}"),
    "dpt_labels": (lambda: DPTModule(**ENV), (RewardContexts(), {}), (RewardContexts(), {"query_labels": True}),
                   f"DPTModule {LABELS}"),
    "dp2t_labels": (lambda: DP2TModule(**ENV), (StepPreferences(), {}), (StepPreferences(), {"query_labels": True}),
                    f"DP2TModule {LABELS}"),
    "reward_gen_other_pair": (lambda: RewardGenModule(**ENV), (TrajectoryPairs(), {}),
                              (TrajectoryPairs(), {"pairs": True}), f"RewardGenModule {PAIRS}"),
    "icrg_pairs": (lambda: ICRGModule(**ENV, reward_gen_hparams=STAGE1), (TrajectoryPairs(), {}),
                   (TrajectoryPairs(), {"pairs": True}), f"ICRGModule {PAIRS}"),
    "dit_rewards": (lambda: DITModule(**ENV), (TrajectoryPairs(), {"pairs": True}), (RewardTrajectories(), {}),
                    "DITModule trains on reward_trajectory contexts but PreferenceDataModule .* holds "
                    "trajectory_preference contexts"),
    "dit_oracle_advantages": (lambda: DITModule(**ENV, advantage="oracle", value_epochs=0),
                              (RewardTrajectories(), {}), (RewardTrajectories(oracle_advantages=True), {}),
                              r"DITModule \(as configured\) reads the batch fields \['advantages_a', 'advantages_b'\]"
                              ".*oracle_advantages true"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_data_a_loss_cannot_read_is_refused_before_generation(case, tmp_path):
    make_model, (setting, flags), _, message = CASES[case]
    data = PreferenceDataModule(DarkRoomFamily(), setting, root_dir=str(tmp_path / "data"), **flags)
    with pytest.raises(HyperparameterError, match=message) as err:
        check_pairing(make_model(), data)
    assert str(err.value).count("\n  - ") == 1  # this one mismatch, one line
    assert not (tmp_path / "data").exists()


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_same_model_fits_the_data_that_serves_what_it_reads(case, tmp_path):
    make_model, _, (setting, flags), _ = CASES[case]
    check_pairing(make_model(), PreferenceDataModule(DarkRoomFamily(), setting, root_dir=str(tmp_path), **flags))
