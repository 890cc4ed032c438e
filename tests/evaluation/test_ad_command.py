"""``icprl evaluate ad``: untrained tiny AD checkpoints deployed end to end on a small DarkRoom (the JSON's shape,
its Markdown re-rendered byte for byte, the bootstrap summary, the runner's ``ad`` evaluation), and the user
errors, each one line naming its option, raised before any episode is played."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from factories import REPO, save_untrained

from icprl_lightning.commands.evaluate import main
from icprl_lightning.evaluation import ad_command
from icprl_lightning.evaluation.ad_command import OPTIMAL, SOURCE, ad_markdown, evaluate_ad, is_ad_payload
from icprl_lightning.evaluation.ad_rollout import ad_learning_curve, optimal_curve
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.methods.ad import ADModule
from icprl_lightning.methods.dpt import DPTModule
from icprl_lightning.reproduce import render
from icprl_lightning.reproduce.runner import evaluate_ad as runner_evaluate_ad
from icprl_lightning.reproduce.tables import ADEvaluation, Run, Table

pytestmark = pytest.mark.usefixtures("one_thread")
TINY = {"n_layer": 1, "n_embd": 16, "n_head": 2}
HORIZON, GOALS = 10, 3
CONFIG = f"""data:
  class_path: icprl_lightning.data.learning_histories.LearningHistoryDataModule
  init_args:
    family:
      class_path: icprl_lightning.families.darkroom.DarkRoomFamily
      init_args: {{horizon: {HORIZON}, n_train_tasks: 8, n_test_tasks: {GOALS}}}
    learner:
      class_path: icprl_lightning.families.darkroom.learning_histories.QLearningHistories
      init_args: {{episodes: 4, epsilon_decay_episodes: 2}}
    context_episodes: 2
    root_dir: ROOT
"""


@pytest.fixture
def setup(tmp_path):
    """A learning-history config on 10-step DarkRoom with 3 held-out goals and two untrained AD checkpoints (two
    'training seeds'), each in a run directory beside its config, as ``icprl fit`` leaves them."""
    config = tmp_path / "ad.yaml"
    config.write_text(CONFIG.replace("ROOT", str(tmp_path / "data")))
    checkpoints = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        model = ADModule(state_dim=2, action_dim=5, discrete=True, max_context=2 * HORIZON, backbone=TINY)
        (tmp_path / f"run{seed}" / "checkpoints").mkdir(parents=True)
        (tmp_path / f"run{seed}" / "config.yaml").write_text(config.read_text())
        checkpoints.append(str(save_untrained(model, tmp_path / f"run{seed}" / "checkpoints" / "last.ckpt")))
    return tmp_path, str(config), checkpoints


def test_the_command_writes_the_learning_curves_beside_the_source_learner_and_the_optimum(setup, capsys):
    tmp_path, config, checkpoints = setup
    out = tmp_path / "ad"
    payload = main(["ad", "--run", f"AD={config}:{','.join(checkpoints)}", "--episodes", "3", "--seeds", "0", "1",
                    "--out", str(out), "--title", "tiny"])
    printed = capsys.readouterr().out
    written = json.loads(out.with_suffix(".json").read_text())
    assert written == json.loads(json.dumps(payload)) and is_ad_payload(written)
    assert out.with_suffix(".png").stat().st_size > 0
    # the Markdown is the JSON's, rendered again byte for byte (the drift test's condition), and printed
    assert out.with_suffix(".md").read_text() == ad_markdown(written) and ad_markdown(written) in printed
    assert [line.split(" |")[0] for line in ad_markdown(written).splitlines() if line[:3] in ("| 1", "| 3")] == [
        "| 1", "| 3"]
    # results: rows × the first and last episode, per_task [training seed][goal] for the bootstrap
    assert list(written["results"]) == ["AD", SOURCE, OPTIMAL]
    assert all(list(row) == ["episode 1", "episode 3"] for row in written["results"].values())
    ad_cell = written["results"]["AD"]["episode 3"]
    assert np.asarray(ad_cell["per_task"]["return"]).shape == (2, GOALS)
    assert ad_cell["return"] == pytest.approx(np.mean(ad_cell["per_task"]["return"]))
    assert np.asarray(written["results"][SOURCE]["episode 1"]["per_task"]["return"]).shape == (2, GOALS)
    # curves: AD mean ± sem over training seeds, each seed's curve; the source learner's; the optimum per goal
    curves = written["learning_curves"]
    assert np.asarray(curves["AD"]["per_seed"]).shape == (2, 3)
    assert curves["AD"]["mean"] == pytest.approx(np.mean(curves["AD"]["per_seed"], axis=0))
    assert len(curves[SOURCE]["mean"]) == 3 and len(curves[OPTIMAL]["per_goal"]) == GOALS
    assert np.all(np.asarray(curves["AD"]["mean"]) <= np.asarray(curves[OPTIMAL]["mean"]) + 1e-9)
    assert np.all(np.asarray(curves[OPTIMAL]["mean"]) > 0) and written["slide"] == HORIZON
    # the same numbers again from the function (seeded), and the AD curve is load_agent's own rollout
    again = evaluate_ad({"AD": (config, checkpoints)}, episodes=3, seeds=[0, 1], title="tiny")
    assert json.loads(json.dumps(again)) == written
    family = DarkRoomFamily(horizon=HORIZON, n_train_tasks=8, n_test_tasks=GOALS)
    from icprl_lightning import load_agent

    agent = load_agent(checkpoints[0], seed=1)
    agent.slide = HORIZON
    seed1 = ad_learning_curve(agent, family, family.test_goals, 3, seed=1)
    assert (seed1 <= optimal_curve(family, family.test_goals, 3, seed=1) + 1e-9).all()
    # render's summary reads it: intervals over training seeds × goals, one block per column
    summary = "\n".join(render.payload_summary(written, "ad"))
    assert "**episode 1**" in summary and "**episode 3**" in summary and f"| 2 × {GOALS} |" in summary


def test_the_runner_s_ad_evaluation_deploys_every_training_seed_from_the_saved_config(setup):
    tmp_path, _, checkpoints = setup
    table = Table("tiny_ad", "tiny", (Run("AD", ("unused.yaml",)),), (ADEvaluation("", episodes=2),),
                  eval_seeds=(0,))
    record = runner_evaluate_ad(table, table.evaluations[0], {"AD": checkpoints}, tmp_path)
    payload = json.loads(Path(record["out"]).read_text())
    assert record["episodes"] == 2 and payload["runs"][0].startswith(f"AD={tmp_path / 'run0' / 'config.yaml'}:")
    assert payload["seeds"] == [0] and np.asarray(payload["learning_curves"]["AD"]["per_seed"]).shape == (2, 2)
    assert (tmp_path / "tiny_ad.md").read_text() == ad_markdown(payload)


def _fails(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(["ad", *argv])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err
    return err


def test_a_wrong_input_is_one_line_naming_its_option_before_any_episode(setup, capsys, monkeypatch):
    tmp_path, config, checkpoints = setup
    played = []
    monkeypatch.setattr("icprl_lightning.evaluation.ad_rollout.ad_learning_curve", lambda *a, **k: played.append(1))
    out = ["--out", str(tmp_path / "x")]
    torch.manual_seed(0)
    dpt = save_untrained(DPTModule(state_dim=2, action_dim=5, discrete=True, max_context=2 * HORIZON, backbone=TINY),
                         tmp_path / "dpt.ckpt")
    short = save_untrained(ADModule(state_dim=2, action_dim=5, discrete=True, max_context=8, backbone=TINY),
                           tmp_path / "short.ckpt")
    bad_json = tmp_path / "bad.json"
    bad_json.write_text(json.dumps({"results": {}}))
    cases = [
        (["--run", f"AD={config}", *out], "--run 'AD=" + config + "' is not NAME=CONFIG:CHECKPOINT"),
        (["--run", f"AD={config}:{dpt}", *out], "is a DPTModule checkpoint, not an AD one (ADModule)"),
        (["--run", f"AD={REPO / 'configs/icpo_darkroom.yaml'}:{checkpoints[0]}", *out],
         "holds PreferenceDataModule data, not learning histories"),
        (["--run", f"AD={config}:{short}", *out], "has max_context 8, shorter than the data's contexts (20)"),
        (["--run", f"AD={config}:{tmp_path / 'none.ckpt'}", *out], "--run AD: "),
        (["--run", f"AD={tmp_path / 'none.yaml'}:{checkpoints[0]}", *out], "does not exist"),
        (["--run", f"AD={config}:{checkpoints[0]}", "--episodes", "0", *out], "--episodes must be an integer ≥ 1"),
        (["--run", f"AD={config}:{checkpoints[0]}", "--seeds", "0", "0", *out], "--seeds must be distinct"),
        (["--run", f"optimal={config}:{checkpoints[0]}", *out], "name 'optimal' is taken"),
        (["--run", f"AD={config}:{checkpoints[0]}", "--against", f"I={bad_json}", *out],
         "not the JSON of `icprl evaluate online` on an MDP family"),
        (["--run", f"AD={config}:{checkpoints[0]}", "--against", f"I={tmp_path / 'no.json'}", *out],
         f"--against I={tmp_path / 'no.json'}: no such file"),
        (["--run", f"AD={config}:{checkpoints[0]}", "--out", str(tmp_path / "nowhere" / "x")],
         "--out " + str(tmp_path / "nowhere" / "x") + ": its folder"),
    ]
    for argv, message in cases:
        err = _fails(argv, capsys)
        assert message in err, (argv, err)
    assert not played and not list(tmp_path.glob("x.*"))


def test_an_online_result_on_other_goals_is_refused(setup, capsys, monkeypatch):
    """``--against``'s curve is drawn only when its held-out goals are AD's: the paper-recipe ICPO online result
    is on the 20 goals of the default DarkRoom, not on this 3-goal one."""
    tmp_path, config, checkpoints = setup
    monkeypatch.chdir(REPO)  # the result names its configs relative to the repository
    online = REPO / "docs/results/online_darkroom_paper/online_darkroom_paper.json"
    err = _fails(["--run", f"AD={config}:{checkpoints[0]}", "--against", f"ICPO={online}", "--out",
                  str(tmp_path / "x")], capsys)
    assert "its held-out tasks are not the ones AD is deployed on" in err


def test_the_markdown_shows_every_fifth_episode_and_the_last():
    assert ad_command.shown_episodes(1) == [1]
    assert ad_command.shown_episodes(12) == [1, 5, 10, 12]
    assert ad_command.shown_episodes(20) == [1, 5, 10, 15, 20]
