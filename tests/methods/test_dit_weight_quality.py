"""scripts/dit_weight_quality.py: which actions DarkRoom's DIT weights up, by hand on its pieces and end to end on
a tiny fitted checkpoint."""

import itertools
import pathlib
import sys

import numpy as np
import pytest
from factories import cli_data_args

from icprl_lightning.cli import run_cli

REPO = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))
import dit_weight_quality  # noqa: E402


def test_good_actions_move_closer_or_stay_on_the_goal():
    # up, down, left, right, no-op from (2, 2) towards the goal (2, 4); then the no-op and "up" on the goal (2, 4)
    states = np.array([[[2, 2]] * 5 + [[2, 4]] * 2], dtype=np.float32)
    actions = np.array([[0, 1, 2, 3, 4, 4, 0]])
    rewards = np.array([[0, 0, 0, 0, 0, 1, 1]], dtype=np.float32)  # "up" on (2, 4) of a 5 × 5 grid hits the wall
    good = dit_weight_quality.good_actions(states, actions, np.array([[2, 4]]), size=5, rewards=rewards)
    assert good.tolist() == [[True, False, False, False, False, True, True]]
    with pytest.raises(ValueError, match="rewards do not match"):
        dit_weight_quality.good_actions(states, actions, np.array([[2, 4]]), size=5, rewards=np.zeros((1, 7)))


def test_auc_counts_pairs_and_halves_ties():
    rng = np.random.default_rng(0)
    scores = rng.integers(0, 4, size=40).astype(float)  # many ties
    positive = rng.random(40) < 0.4
    pairs = [1.0 if p > n else 0.5 if p == n else 0.0
             for p, n in itertools.product(scores[positive], scores[~positive])]
    assert dit_weight_quality.auc(scores, positive) == pytest.approx(np.mean(pairs))


def test_measure_reads_a_fitted_dit_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    tiny = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2,
                calibration_episodes=2)
    run_cli(["fit", "--config", str(REPO / "configs/dit_darkroom.yaml"), "--trainer.logger", "false",
             "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "0",
             "--trainer.default_root_dir", str(tmp_path / "run"), "--data.init_args.root_dir", str(tmp_path / "data"),
             "--data.init_args.progress", "false", *cli_data_args("darkroom", **tiny),
             "--model.init_args.n_layer", "1", "--model.init_args.n_embd", "16", "--model.init_args.n_head", "2",
             "--model.init_args.value_epochs", "0"])
    (checkpoint,) = (tmp_path / "run").glob("*/checkpoints/last.ckpt")  # runs/<model>-<time>-<hex>/
    out = dit_weight_quality.measure(checkpoint)
    assert out and set(out) <= {"low", "medium", "high"}  # the qualities the validation rows hold
    for row in out.values():
        assert 0 <= row["good_fraction"] <= 1 and 0 <= row["policy_good_mass"] <= 1 and row["steps"] > 0
        for key in ("weighted_good_fraction", "auc", "td_weighted_good_fraction", "td_auc",
                    "rtg_weighted_good_fraction", "rtg_auc"):
            assert row[key] is None if key.endswith("auc") and row["good_fraction"] in (0, 1) else 0 <= row[key] <= 1
    assert dit_weight_quality.auc(np.arange(3.0), np.ones(3, bool)) is None  # no bad action to rank against
