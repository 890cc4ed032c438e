"""``icprl analyze dit-weights`` and ``dit-advantages`` (``evaluation/dit_weights.py``, ``dit_advantages.py``): which
actions DarkRoom's DIT weights up, and how its advantages correlate with each step's progress, by hand on their
pieces and end to end on a tiny fitted checkpoint."""

import itertools
import json
import pathlib

import numpy as np
import pytest
import torch
from factories import cli_data_args

from icprl_lightning.commands import main, run_cli
from icprl_lightning.evaluation import dit_advantages, dit_weights

REPO = pathlib.Path(__file__).resolve().parents[2]


def test_good_actions_move_closer_or_stay_on_the_goal():
    # up, down, left, right, no-op from (2, 2) towards the goal (2, 4); then the no-op and "up" on the goal (2, 4)
    states = np.array([[[2, 2]] * 5 + [[2, 4]] * 2], dtype=np.float32)
    actions = np.array([[0, 1, 2, 3, 4, 4, 0]])
    rewards = np.array([[0, 0, 0, 0, 0, 1, 1]], dtype=np.float32)  # "up" on (2, 4) of a 5 × 5 grid hits the wall
    good = dit_weights.good_actions(states, actions, np.array([[2, 4]]), size=5, rewards=rewards)
    assert good.tolist() == [[True, False, False, False, False, True, True]]
    with pytest.raises(ValueError, match="rewards do not match"):
        dit_weights.good_actions(states, actions, np.array([[2, 4]]), size=5, rewards=np.zeros((1, 7)))


def test_auc_counts_pairs_and_halves_ties():
    rng = np.random.default_rng(0)
    scores = rng.integers(0, 4, size=40).astype(float)  # many ties
    positive = rng.random(40) < 0.4
    pairs = [1.0 if p > n else 0.5 if p == n else 0.0
             for p, n in itertools.product(scores[positive], scores[~positive])]
    assert dit_weights.auc(scores, positive) == pytest.approx(np.mean(pairs))


@pytest.fixture(scope="module")
def dit_run(tmp_path_factory) -> pathlib.Path:
    """A DIT fitted for two steps on tiny DarkRoom reward trajectories: its last checkpoint (``config.yaml`` two
    directories up, as ``icprl fit`` saves it)."""
    tmp_path = tmp_path_factory.mktemp("dit")
    tiny = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2,
                calibration_episodes=2)
    run_cli(["fit", "--config", str(REPO / "configs/dit_darkroom.yaml"), "--trainer.logger", "false",
             "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "0",
             "--trainer.default_root_dir", str(tmp_path / "run"), "--data.init_args.root_dir", str(tmp_path / "data"),
             "--data.init_args.progress", "false", *cli_data_args("darkroom", **tiny),
             "--model.init_args.backbone", "{n_layer: 1, n_embd: 16, n_head: 2}",
             "--model.init_args.value_epochs", "0"])
    (checkpoint,) = (tmp_path / "run").glob("*/checkpoints/last.ckpt")  # runs/<model>-<time>-<hex>/
    return checkpoint


def test_measure_reads_a_fitted_dit_run(dit_run, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    out = dit_weights.measure(dit_run)
    assert out and set(out) <= {"low", "medium", "high"}  # the qualities the validation rows hold
    for row in out.values():
        assert 0 <= row["good_fraction"] <= 1 and 0 <= row["policy_good_mass"] <= 1 and row["steps"] > 0
        for key in ("weighted_good_fraction", "auc", "td_weighted_good_fraction", "td_auc",
                    "rtg_weighted_good_fraction", "rtg_auc"):
            assert row[key] is None if key.endswith("auc") and row["good_fraction"] in (0, 1) else 0 <= row[key] <= 1
    assert dit_weights.auc(np.arange(3.0), np.ones(3, bool)) is None  # no bad action to rank against
    # the command: one checkpoint, so each summary is its value with no sem over training seeds
    main(["analyze", "dit-weights", "--ckpt", str(dit_run), "--json", str(tmp_path / "w.json")])
    saved = json.loads((tmp_path / "w.json").read_text())
    quality = next(iter(out))
    assert saved["summary"][quality]["good_fraction"] == [pytest.approx(out[quality]["good_fraction"]), None]
    assert set(saved["checkpoints"]) == {str(dit_run)}
    assert "| good_fraction |" in capsys.readouterr().out


def test_dit_weights_refuse_a_checkpoint_without_its_run_config(dit_run, tmp_path, capsys):
    alone = tmp_path / "alone.ckpt"
    alone.write_bytes(dit_run.read_bytes())
    with pytest.raises(SystemExit) as info:
        main(["analyze", "dit-weights", "--ckpt", str(alone)])
    assert info.value.code == 2
    assert "no config.yaml in its run directory" in capsys.readouterr().err


def test_progress_correlations_by_hand():
    progress = torch.tensor([[1.0, -1.0, 2.0, 0.0], [0.5, 1.5, -2.0, 1.0]])
    forms = {"q_minus_v": torch.cat([torch.zeros(2, 1), 3 * progress], 1)}  # step h ≥ 1's advantage ∝ its progress
    forms.update({k: forms["q_minus_v"] for k in ("td", "return_to_go",
                                                  *(f"gae{lam}" for lam in dit_advantages.GAE_LAMBDAS))})
    out = dit_advantages.dit_correlations("dit", forms, progress)
    assert out["corr_progress_vs_dit_advantage"] == pytest.approx(1.0)
    assert out["corr_progress_vs_dit_td_advantage"] == pytest.approx(1.0)
    # the next step's progress against this step's advantage: progress[:, 1:] vs advantage[:, 1:-1]
    expected = np.corrcoef(progress[:, 1:].flatten(), progress[:, :-1].flatten())[0, 1]
    assert out["corr_next_progress_vs_dit_advantage"] == pytest.approx(expected)


def test_dit_advantages_of_a_fitted_dit_run(dit_run, capsys):
    config = dit_run.parent.parent / "config.yaml"
    main(["analyze", "dit-advantages", "--dit", f"{config}:{dit_run}"])
    out = json.loads(capsys.readouterr().out)
    assert out["pairs"] > 0 and out["steps_scored"] == out["pairs"] * 2 * (100 - 1)  # both sides, steps h ≥ 1
    keys = [k for k in out if k.startswith("corr_")]
    assert "corr_progress_vs_dit_return_to_go_advantage" in keys and not any("icrg" in k for k in keys)
    assert all(-1 <= out[k] <= 1 or np.isnan(out[k]) for k in keys)


@pytest.mark.parametrize(("argv", "message"), [
    (["--dit", "no-checkpoint"], "--dit 'no-checkpoint' is not CONFIG:CHECKPOINT"),
    (["--oracle"], "--oracle needs the Reach SAC family, got DarkRoomFamily"),
])
def test_dit_advantages_mistakes_are_one_line(dit_run, capsys, argv, message):
    run = ["--dit", f"{dit_run.parent.parent / 'config.yaml'}:{dit_run}"]
    with pytest.raises(SystemExit) as info:
        main(["analyze", "dit-advantages", *(argv if argv[0] == "--dit" else [*run, *argv])])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("icprl analyze dit-advantages: error: ") and message in err, err
