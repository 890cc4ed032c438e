"""``icprl analyze reward-bayes`` (``evaluation/reward_bayes.py``): the Bayes-optimal DarkRoom reward from one T-PRL
pair, by hand on its pieces and end to end on tiny data."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from factories import darkroom_tprl_config

from icprl_lightning.commands import main
from icprl_lightning.contexts import TrajectoryPreferenceContext
from icprl_lightning.evaluation import reward_bayes
from icprl_lightning.families.darkroom.env import step_reward, transition
from icprl_lightning.families.darkroom.oracle import optimal_actions

SIZE = 4
SETTING = dict(trajectories_per_task=3, val_trajectories_per_task=2, eval_contexts_per_task=2, calibration_episodes=2,
               reference_episodes=2)


def _walk(start, goal, steps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The optimal walk from ``start`` to ``goal`` on the SIZE grid, staying on it: states [1, steps, 2], actions."""
    s, states, actions = np.array(start), [], []
    for _ in range(steps):
        a = int(optimal_actions(s, np.array(goal)))
        states.append(s.copy())
        actions.append(a)
        s = transition(s, np.array(a), SIZE)
    return torch.tensor(np.array(states)[None], dtype=torch.float32), torch.tensor([actions])


def test_cells_and_rewards_agree_with_the_env():
    states, actions = _walk((0, 0), (2, 3), 8)
    cells = reward_bayes.landing_cells(states, actions, SIZE)
    goals = reward_bayes.grid_goals(SIZE)
    for g, goal in enumerate(goals):  # a one-hot posterior on goal g gives the env's reward r_g
        post = np.eye(SIZE * SIZE)[[g]]
        nxt = transition(states.numpy().astype(np.int64), actions.numpy(), SIZE)
        expected = step_reward(nxt, goal)
        np.testing.assert_array_equal(reward_bayes.bayes_rewards(post, states, actions, SIZE), expected)
    returns = reward_bayes.goal_returns(cells, SIZE * SIZE)
    assert returns.sum() == 8 and returns[0, 3 * SIZE + 2] == 4  # 4 moves to (2, 3), then 4 landings on it


def test_behavior_likelihood_peaks_at_the_goal_the_walk_heads_for():
    states, actions = _walk((0, 0), (2, 3), 12)
    loglik = reward_bayes.behavior_loglik(states, actions, p_optimal=0.8, size=SIZE)
    assert loglik.shape == (1, SIZE * SIZE) and int(loglik.argmax()) == 3 * SIZE + 2
    uniform = reward_bayes.behavior_loglik(states, actions, p_optimal=0.0, size=SIZE)
    np.testing.assert_allclose(uniform, 12 * np.log(1 / 5))  # a uniform policy says nothing about the goal


def test_label_likelihood_follows_the_label():
    a_states, a_actions = _walk((0, 0), (2, 3), 6)   # reaches (2, 3) at step 5
    b_states, b_actions = _walk((3, 0), (3, 0), 6)   # stays on (3, 0)
    pair = TrajectoryPreferenceContext(a_states, a_actions, b_states, b_actions, torch.tensor([1.0]))
    flipped = TrajectoryPreferenceContext(a_states, a_actions, b_states, b_actions, torch.tensor([0.0]))
    win, lose = reward_bayes.label_loglik(pair, SIZE, 1.0), reward_bayes.label_loglik(flipped, SIZE, 1.0)
    g_a, g_b = 3 * SIZE + 2, 0 * SIZE + 3
    assert win[0, g_a] > np.log(0.5) > win[0, g_b] and lose[0, g_b] > np.log(0.5) > lose[0, g_a]
    np.testing.assert_allclose(np.exp(win) + np.exp(lose), 1.0)
    post = reward_bayes.posteriors(pair, SIZE, 1.0, p_optimal=0.5)
    for p in post.values():
        np.testing.assert_allclose(p.sum(1), 1.0)
    # the label (ξ_a preferred) moves posterior mass toward the cell ξ_a walks to and stays on
    assert post["pair"][0, g_a] > post["trajectories"][0, g_a]


def test_command_end_to_end(data_root, tmp_path, capsys):
    config = darkroom_tprl_config(tmp_path / "tiny.yaml", data_root, SETTING)
    out_json = tmp_path / "bayes.json"
    main(["analyze", "reward-bayes", "--data-config", str(config), "--json", str(out_json)])
    out = json.loads(out_json.read_text())
    assert out == json.loads(json.dumps(reward_bayes.reward_bayes(config)))
    for evidence in ("label", "trajectories", "pair"):
        for q in ("low", "medium", "high"):
            m = out["bayes"][evidence][q]
            assert 0 <= m["other_pair_accuracy"] <= 1 and -1 <= m["reward_correlation"] <= 1
            assert 0 < m["posterior_on_goal"] <= 1
    # 200 goal-directed steps pin the goal down; one label cannot (at most one bit)
    assert out["bayes"]["pair"]["high"]["posterior_on_goal"] > 0.5 > out["bayes"]["label"]["high"]["posterior_on_goal"]
    assert "| the whole pair |" in capsys.readouterr().out



def test_labels_of_another_annotator_than_bradley_terry_are_one_line(tmp_path, capsys):
    config = darkroom_tprl_config(tmp_path / "teacher.yaml", str(tmp_path / "data"), {
        **SETTING, "annotator": {"class_path": "icprl_lightning.annotators.ScriptedTeacher"}})
    with pytest.raises(SystemExit) as info:
        main(["analyze", "reward-bayes", "--data-config", str(config)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("icprl analyze reward-bayes: error: --data-config") and "Bradley–Terry" in err, err
    assert not (tmp_path / "data").exists()  # refused before any dataset was generated
