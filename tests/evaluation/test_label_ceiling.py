"""``icprl analyze label-ceiling`` (``evaluation/label_ceiling.py``): the exact goal posterior of DarkRoom I-PRL
labels, by hand on a small grid and end to end on a tiny dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from icprl_lightning.commands import main
from icprl_lightning.evaluation.label_ceiling import READERS, ceiling_page, goal_posterior, pair_posterior
from icprl_lightning.families.darkroom.family import DarkRoomFamily
from icprl_lightning.families.darkroom.oracle import optimal_actions, optimal_advantage

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


def test_the_pair_reader_finds_the_goal_in_behavior_pairs_and_nothing_in_uniform_ones():
    """One side uniform, the other the mixed policy at p = 0.9 for the goal: the unlabeled pairs point to it. Both
    sides uniform: every goal is equally likely (the posterior is the prior exactly)."""
    rng = np.random.default_rng(0)
    goal, n = np.array([1, 2]), 60
    states = rng.integers(0, FAMILY.size, size=(1, n, 2))
    best = optimal_actions(states, np.broadcast_to(goal, states.shape))
    behavior = np.where(rng.random((1, n)) < 0.9, best, rng.integers(0, 5, size=(1, n)))
    uniform = rng.integers(0, 5, size=(2, 1, n))
    true = 1 * FAMILY.size + 2
    logp = pair_posterior(FAMILY, states, uniform[0], behavior, (0.0, 0.9))
    assert int(logp.argmax(1)[0]) == true and np.exp(logp[0, true]) > 0.5
    swapped = pair_posterior(FAMILY, states, behavior, uniform[0], (0.0, 0.9))  # the slots are shuffled
    np.testing.assert_allclose(swapped, logp)
    np.testing.assert_allclose(np.exp(pair_posterior(FAMILY, states, uniform[0], uniform[1], (0.0, 0.0))),
                               1 / FAMILY.size**2)


def _config(tmp_path, name: str, **knobs) -> str:
    config = tmp_path / f"{name}.yaml"
    config.write_text(yaml.safe_dump({"data": {
        "class_path": "icprl_lightning.data.PreferenceDataModule",
        "init_args": {"family": {"class_path": "icprl_lightning.families.darkroom.DarkRoomFamily"},
                      "setting": {"class_path": "icprl_lightning.data.settings.StepPreferences",
                                  "init_args": {"trajectories_per_task": 2, "val_trajectories_per_task": 1,
                                                "eval_contexts_per_task": 1, "calibration_episodes": 2,
                                                "reference_episodes": 2, **knobs}},
                      "root_dir": str(tmp_path / "data")}}}))
    return str(config)


def test_command_end_to_end(tmp_path, capsys):
    main(["analyze", "label-ceiling", "--config", _config(tmp_path, "ipref"), "--json", str(tmp_path / "ceiling.json")])
    out = json.loads(capsys.readouterr().out)
    assert out == json.loads((tmp_path / "ceiling.json").read_text()) and out["bt_temperature"] == 1.0
    for q in ("low", "medium", "high"):
        assert out[q]["contexts"] == 20
        for reader in READERS:
            row = out[q][reader]
            assert 0 <= row["map_is_true_goal"] <= 1 and 0 < row["posterior_on_true_goal"] <= 1
            # walking to the MAP goal earns the optimal return exactly on the contexts whose MAP goal is right
            assert row["return_walking_to_map_goal"] <= out[q]["optimal_return"]
            if row["map_is_true_goal"] == 1.0:
                assert row["return_walking_to_map_goal"] == pytest.approx(out[q]["optimal_return"])
    # the page the docs include, from the JSON
    page = ceiling_page(tmp_path)
    pair_return = out["high"]["pair"]["return_walking_to_map_goal"]
    assert page.count("| `ceiling` |") == len(READERS) + 1 and f"{pair_return:.1f}" in page


def test_in_the_label_only_recipe_nothing_but_the_labels_points_to_the_goal(tmp_path, capsys):
    """Uniform states and both sides of every pair uniform: the pair-only reader is at chance exactly and reading
    everything is reading the labels. With the uniform-state recipe's behavior side (high quality, p ≈ 0.8), the
    unlabeled pairs alone put more than chance on the goal."""
    main(["analyze", "label-ceiling", "--config", _config(tmp_path, "only", state_source="uniform",
                                                          second_policy="uniform")])
    only = json.loads(capsys.readouterr().out)
    assert only["setting"]["second_policy"] == "uniform"
    main(["analyze", "label-ceiling", "--config", _config(tmp_path, "behavior", state_source="uniform")])
    behavior = json.loads(capsys.readouterr().out)
    assert "second_policy" not in behavior["setting"]  # the paper's choice keeps its config (and dataset directory)
    for q in ("low", "medium", "high"):
        assert only[q]["pair_mixing"] == [0.0, 0.0] and only[q]["pair"]["posterior_on_true_goal"] == pytest.approx(0.01)
        assert only[q]["everything"] == pytest.approx(only[q]["labels"])
        assert behavior[q]["pair_mixing"][1] > 0
        # reading the pairs beside the labels puts more on the goal than either alone
        mass = {r: behavior[q][r]["posterior_on_true_goal"] for r in READERS}
        assert mass["everything"] > max(mass["labels"], mass["pair"]), (q, mass)
    assert behavior["high"]["pair"]["posterior_on_true_goal"] > 0.05
    # in the data themselves, not only in the reader's model: the share of pair actions optimal for the true goal
    assert abs(_optimal_share(only["dataset"]) - 0.2) < 0.03  # uniform over 5 actions
    assert _optimal_share(behavior["dataset"]) > 0.4


def _optimal_share(dataset: str) -> float:
    """Share of the high-quality eval contexts' actions (both slots) that are optimal for the context's goal."""
    from icprl_lightning.data.store import load_dataset

    data = load_dataset(dataset)
    split = data["eval_high"]
    goals = np.asarray(data["tasks"]["test_goals"])[np.asarray(split["task_index"])][:, None, :]
    states = np.asarray(split["states"]).astype(np.int64)
    best = optimal_actions(states, np.broadcast_to(goals, states.shape))
    return float(np.mean([np.asarray(split[k]) == best for k in ("actions", "alt_actions")]))


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
