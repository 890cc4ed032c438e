"""``icprl evaluate`` checks what it is given before any work (``evaluation/pairing.py``, ``report.read_baseline``):
a checkpoint that does not fit its config's data, a bad ``--baseline`` file, a bad config, each one line on
stderr, no dataset generated; then it prints its tables to stdout and writes beside the run by default."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml
from factories import REPO, bandit_data

from icprl_lightning.commands import evaluate as command
from icprl_lightning.commands import run_cli
from icprl_lightning.commands.evaluate import main
from icprl_lightning.data import PreferenceDataModule
from icprl_lightning.evaluation.pairing import run_datamodule
from icprl_lightning.evaluation.report import aligned_tables
from icprl_lightning.methods.dpt import DPTModule
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import TransformerConfig

pytestmark = pytest.mark.usefixtures("one_thread")
DARKROOM, BANDIT = str(REPO / "configs/icpo_darkroom.yaml"), str(REPO / "configs/icpo_bandit.yaml")
TINY = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))


def _save(module: torch.nn.Module, path: Path) -> str:
    """``module`` as Lightning saves it (with the class and checksum ``on_save_checkpoint`` stamps)."""
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(checkpoint, path)
    return str(path)


@pytest.fixture
def no_data(monkeypatch):
    """Any dataset generation (or read) fails the test: the checks must come first."""
    def refuse(self):
        raise AssertionError("prepare_data ran before the checks")

    monkeypatch.setattr(PreferenceDataModule, "prepare_data", refuse)


def _one_line_error(capsys, argv: list[str]) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err
    return err


CASES = {
    "bandit checkpoint, MDP config": (lambda: ICPOModule(state_dim=0, action_dim=20, discrete=True, max_context=200,
                                                         **TINY), DARKROOM,
                                      "MDP data (darkroom: step_preference contexts, state_dim 2, 5 discrete actions, "
                                      "context length 100)", "ICPOModule has state_dim 0, the data 2; has 20 "
                                                             "discrete actions, the data 5 discrete actions"),
    "MDP checkpoint, bandit config": (lambda: ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100,
                                                         **TINY), BANDIT, "dueling-bandit data",
                                      "has max_context 100, shorter than the data's contexts (200)"),
    "reward-context method": (lambda: DPTModule(state_dim=2, action_dim=5, discrete=True, max_context=100, **TINY),
                              DARKROOM, "MDP data", "DPTModule takes reward contexts, the data step_preference"),
    "continuous actions": (lambda: ICPOModule(state_dim=2, action_dim=5, discrete=False, max_context=100, **TINY),
                           DARKROOM, "MDP data", "has 5 action dims, the data 5 discrete actions"),
    "reward model": (lambda: RewardGenModule(state_dim=2, action_dim=5, discrete=True, max_context=100, **TINY),
                     DARKROOM, "MDP data", "RewardGenModule holds a reward model, not a policy"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_checkpoint_that_does_not_fit_its_config_is_one_line_before_any_data(tmp_path, capsys, no_data, case):
    make, config, data, problem = CASES[case]
    checkpoint = _save(make(), tmp_path / "m.ckpt")
    err = _one_line_error(capsys, ["--run", f"ICPO={config}:{checkpoint}", "--out", str(tmp_path / "t")])
    assert err.startswith(f"icprl evaluate: error: --run ICPO: {checkpoint} does not fit the {data}")
    assert f"of {config}: " in err and problem in err
    assert not list(tmp_path.glob("t.*"))


def test_a_missing_checkpoint_or_bad_config_is_one_line_before_any_data(tmp_path, capsys, no_data):
    err = _one_line_error(capsys, ["--run", f"ICPO={DARKROOM}:{tmp_path / 'gone.ckpt'}"])
    assert err == f"icprl evaluate: error: --run ICPO: No checkpoint at {tmp_path / 'gone.ckpt'}\n"
    good = _save(ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100, **TINY), tmp_path / "m.ckpt")
    (tmp_path / "bad.yaml").write_text("data:\n  class_path: nowhere.Foo\n")
    err = _one_line_error(capsys, ["--run", f"ICPO={tmp_path / 'bad.yaml'}:{good}"])
    assert err.startswith(f"icprl evaluate: error: --run ICPO: config {tmp_path / 'bad.yaml'} does not give a "
                          "DataModule (")
    # one fitting run does not excuse a second, unfitting one: every run is checked before any data
    bandit = _save(ICPOModule(state_dim=0, action_dim=20, discrete=True, max_context=200, **TINY), tmp_path / "b.ckpt")
    err = _one_line_error(capsys, ["--run", f"A={DARKROOM}:{good}", "--run", f"B={DARKROOM}:{good},{bandit}"])
    assert f"--run B: {bandit} does not fit" in err


@pytest.mark.parametrize("config", ["icpo_darkroom", "dpt_darkroom", "dp2t_darkroom", "dp2t_darkroom_tprl",
                                    "dit_darkroom", "icpo_bandit"])
def test_every_method_fits_the_config_it_was_trained_with(tmp_path, config):
    """No false refusal: a model as ``icprl fit`` builds it from a config (sizes linked from its data) passes."""
    path = REPO / "configs" / f"{config}.yaml"
    cli = run_cli(["--config", str(path), "--trainer.logger", "false"], run=False)
    checkpoint = _save(cli.model, tmp_path / "m.ckpt")
    run_datamodule("run", str(path), [checkpoint])


def test_icrg_fits_the_trajectory_pairs_it_labels(tmp_path):
    """ICRG's policy reads reward trajectories but deploys on T-PRL pairs (which R_ψ labels): the pairs' config fits."""
    from icprl_lightning.methods.icrg import ICRGModule

    module = ICRGModule(state_dim=2, action_dim=5, discrete=True, max_context=100, **TINY,
                        reward_gen_hparams=dict(backbone=TINY["backbone"].as_dict(), max_context=100))
    checkpoint = _save(module, tmp_path / "m.ckpt")
    run_datamodule("ICRG", str(REPO / "configs/icrg_darkroom.yaml"), [checkpoint])
    with pytest.raises(ValueError, match="ICRGModule takes trajectory_preference contexts, the data step_preference"):
        run_datamodule("ICRG", DARKROOM, [checkpoint])


@pytest.mark.parametrize("content, problem", [
    (None, "no such file"), ("{not json", "is not valid JSON"), ("[1, 2]", "is not a baselines/ result"),
    ('{"return": 3.0}', "'return' is 3.0, not {\"mean\": number, \"sem\": number}"),
    ('{"return": {"mean": "high", "sem": 1}}', "'return' is")])
def test_a_bad_baseline_file_is_one_line_before_anything_is_built(tmp_path, capsys, monkeypatch, content, problem):
    def refuse(*args):
        raise AssertionError("a DataModule was built before --baseline was checked")

    monkeypatch.setattr(command, "run_datamodule", refuse)
    path = tmp_path / "baseline.json"
    if content is not None:
        path.write_text(content)
    err = _one_line_error(capsys, ["--run", f"ICPO={DARKROOM}:x.ckpt", "--baseline", f"DQN={path}"])
    assert err.startswith(f"icprl evaluate: error: --baseline {path}") and problem in err
    with pytest.raises(SystemExit):  # a name already taken is a usage error
        main(["--run", f"ICPO={DARKROOM}:x.ckpt", "--baseline", f"ICPO={path}"])


def test_aligned_tables_pads_each_column_and_keeps_the_rest():
    text = ("return:\n\n| method | low | high |\n|---|---|---|\n| ICPO | 1.5 ± 0.2 | 30.0 |\n| behavior | 2 | 3 |\n"
            "\nnote\n")
    assert aligned_tables(text) == ("return:\n\n| method   | low       | high |\n| -------- | --------- | ---- |\n"
                                    "| ICPO     | 1.5 ± 0.2 | 30.0 |\n| behavior | 2         | 3    |\n\nnote\n")


def test_evaluate_prints_its_tables_and_writes_beside_the_run_by_default(tmp_path, capsys, monkeypatch):
    dm = bandit_data(root_dir=str(tmp_path / "data"), n_train_problems=4, contexts_per_problem=2, n_val_problems=2,
                     val_contexts_per_problem=2, n_eval_problems=2, batch_size=2, progress=False)
    family, setting = dm.family, dm.setting
    data = {"class_path": "icprl_lightning.data.PreferenceDataModule",
            "init_args": {"root_dir": dm.root_dir, "pairs": True, "progress": False,
                          "family": {"class_path": f"{type(family).__module__}.{type(family).__qualname__}",
                                     "init_args": {k: v for k, v in family.config().items() if k != "family"}},
                          "setting": {"class_path": f"{type(setting).__module__}.{type(setting).__qualname__}",
                                      "init_args": {k: v for k, v in setting.config().items()
                                                    if k not in ("setting", "context_kind")}}}}
    config = tmp_path / "bandit.yaml"
    config.write_text(yaml.safe_dump({"data": data}))
    torch.manual_seed(0)
    run_dir = tmp_path / "runs" / "icprl" / "abc"
    checkpoint = _save(ICPOModule(state_dim=0, action_dim=20, discrete=True, max_context=200, **TINY),
                       run_dir / "checkpoints" / "last.ckpt")
    # both runs in the same second
    monkeypatch.setattr(command.time, "strftime", lambda fmt: "20250101-000000")
    payload = main(["--seeds", "0", "--run", f"ICPO={config}:{checkpoint}"])
    out = capsys.readouterr().out
    written = run_dir / "eval" / "20250101-000000.json"  # the default --out: <run dir>/eval/<date-time>
    assert json.loads(written.read_text())["results"] == payload["results"]
    assert written.with_suffix(".md").exists() and written.with_suffix(".png").stat().st_size > 0
    assert "weak regret at h = H:" in out and f"wrote {written.with_suffix('')}.json" in out
    rows = [line for line in out.splitlines() if line.startswith("| ")]
    assert any(line.startswith("| ICPO ") for line in rows) and len({len(line) for line in rows[:5]}) == 1
    # a second evaluation in the same second does not overwrite the first
    main(["--seeds", "0", "--run", f"ICPO={config}:{checkpoint}"])
    assert (run_dir / "eval" / "20250101-000000-2.json").exists()


def test_a_data_file_stacks_on_the_run_config_and_a_missing_one_is_one_line(tmp_path, capsys, no_data):
    """``--data FILE`` changes the held-out tasks a run is deployed on, not the checks of its checkpoints."""
    module = ICPOModule(state_dim=2, action_dim=5, discrete=True, max_context=100, **TINY)
    checkpoint = _save(module, tmp_path / "m.ckpt")
    wider = tmp_path / "wider.yaml"
    wider.write_text("data:\n  init_args:\n    family:\n      init_args:\n        n_test_tasks: 12\n")
    assert run_datamodule("ICPO", DARKROOM, [checkpoint], [str(wider)]).family.n_test_tasks == 12
    assert run_datamodule("ICPO", DARKROOM, [checkpoint]).family.n_test_tasks != 12
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("data:\n  init_args:\n    family:\n      init_args:\n        n_tset: 12\n")
    err = _one_line_error(capsys, ["--run", f"ICPO={DARKROOM}:{checkpoint}", "--data", str(wrong)])
    assert f"{DARKROOM} + {wrong} does not give a DataModule" in err and "n_tset" in err, err
    err = _one_line_error(capsys, ["--run", f"ICPO={DARKROOM}:{checkpoint}", "--data", str(tmp_path / "no.yaml")])
    assert err.startswith(f"icprl evaluate: error: --data {tmp_path / 'no.yaml'}: no such file"), err
