"""``icprl analyze label-ceiling`` (``evaluation/label_ceiling.py``): the exact goal posterior of DarkRoom I-PRL
labels, by hand on a small grid and end to end on a tiny dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from icprl_lightning.commands import main
from icprl_lightning.evaluation.label_ceiling import goal_posterior
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_advantage

FAMILY = DarkRoomFamily(size=4, horizon=40, n_train_tasks=10, n_test_tasks=4)


def _contexts(goal: tuple[int, int], n_steps: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Random states and action pairs on the grid, labeled by the sign of A* for ``goal`` (ties: first wins)."""
    rng = np.random.default_rng(seed)
    states = rng.integers(0, FAMILY.size, size=(1, n_steps, 2))
    first, second = rng.integers(0, 5, size=(2, 1, n_steps))
    goals = np.broadcast_to(np.array(goal), states.shape)
    steps_left = FAMILY.horizon - np.arange(n_steps)
    diff = (optimal_advantage(states, first, goals, steps_left, FAMILY)
            - optimal_advantage(states, second, goals, steps_left, FAMILY))
    return states, first, second, (diff >= 0).astype(np.uint8)


def test_decisive_labels_put_the_posterior_on_the_goal_and_flipped_ones_take_it_away():
    states, first, second, preferred = _contexts((2, 3), n_steps=30)
    true = 2 * FAMILY.size + 3  # cell (i, j) has index i·size + j
    logp, cells = goal_posterior(FAMILY, states, first, second, preferred, temperature=0.05)
    assert cells.shape == (FAMILY.size**2, 2) and cells[true].tolist() == [2, 3]
    np.testing.assert_allclose(np.exp(logp).sum(1), 1.0)
    assert int(logp.argmax(1)[0]) == true and np.exp(logp[0, true]) > 0.5
    flipped, _ = goal_posterior(FAMILY, states, first, second, 1 - preferred, temperature=0.05)
    assert np.exp(flipped[0, true]) < 1e-3
    # a lukewarm teacher says less: the posterior on the goal is smaller but still above the prior
    warm, _ = goal_posterior(FAMILY, states, first, second, preferred, temperature=5.0)
    assert 1 / FAMILY.size**2 < np.exp(warm[0, true]) < np.exp(logp[0, true])


def test_command_end_to_end(tmp_path, capsys):
    config = tmp_path / "ipref.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.StepPreferences",
                                  "init_args": {"trajectories_per_task": 2, "val_trajectories_per_task": 1,
                                                "eval_contexts_per_task": 1, "calibration_episodes": 2,
                                                "reference_episodes": 2}},
                      "root_dir": str(tmp_path / "data")}}}))
    main(["analyze", "label-ceiling", "--config", str(config), "--json", str(tmp_path / "ceiling.json")])
    out = json.loads(capsys.readouterr().out)
    assert out == json.loads((tmp_path / "ceiling.json").read_text()) and out["bt_temperature"] == 1.0
    for q in ("low", "medium", "high"):
        row = out[q]
        assert row["contexts"] == 20 and 0 <= row["map_is_true_goal"] <= 1 and 0 < row["posterior_on_true_goal"] <= 1
        # walking to the MAP goal earns the optimal return exactly on the contexts whose MAP goal is right
        assert row["return_walking_to_map_goal"] <= row["optimal_return"]
        if row["map_is_true_goal"] == 1.0:
            assert row["return_walking_to_map_goal"] == pytest.approx(row["optimal_return"])


def test_a_setting_without_step_labels_is_one_line(tmp_path, capsys):
    config = tmp_path / "dpt.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.RewardContexts"},
                      "root_dir": str(tmp_path / "data")}}}))
    with pytest.raises(SystemExit) as info:
        main(["analyze", "label-ceiling", "--config", str(config)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("icprl analyze label-ceiling: error: --config") and "step preferences" in err, err
    assert not (tmp_path / "data").exists()
