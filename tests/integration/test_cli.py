"""The icprl command: every DarkRoom config trains under fast_dev_run, overrides, errors, config saving, evaluate."""

import glob
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from factories import config_args, tiny_darkroom_args

from icprl_lightning import load_agent
from icprl_lightning.commands import main, run_cli
from icprl_lightning.evaluation import diagnose_suite, rollout_in_context, rollout_seeds, summarize

DARKROOM_CONFIGS = ["configs/icpo_darkroom.yaml", "configs/dp2t_darkroom.yaml", "configs/dpt_darkroom.yaml"]


def tiny_data_args(root) -> list[str]:
    return ["--trainer.default_root_dir", str(root),
            *tiny_darkroom_args(str(root))]


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
@pytest.mark.parametrize("config", DARKROOM_CONFIGS + sorted(glob.glob("configs/paper/*darkroom.yaml")))
def test_config_runs_under_fast_dev_run(config, tmp_path):
    cli = run_cli(["fit", *config_args(config), "--trainer.fast_dev_run", "1", "--trainer.logger", "false",
                   *tiny_data_args(tmp_path)])
    assert cli.trainer.state.finished
    assert cli.model.hparams.max_context == cli.datamodule.context_length  # linked, not repeated


def test_overrides_reach_the_model(tmp_path):
    cli = run_cli(["fit", "--config", "configs/icpo_darkroom.yaml", "--model.init_args.optimizer.lr", "0.01",
                   "--model.init_args.lam", "0.3", "--trainer.fast_dev_run", "1", "--trainer.logger", "false",
                   *tiny_data_args(tmp_path)])
    assert cli.model.hparams.optimizer["lr"] == 0.01 and cli.model.hparams.lam == 0.3


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
def test_unknown_key_is_rejected_by_name(tmp_path):
    bad = tmp_path / "bad.yaml"
    cfg = yaml.safe_load(Path("configs/icpo_darkroom.yaml").read_text())
    cfg["model"]["init_args"]["lamda"] = 0.5
    bad.write_text(yaml.safe_dump(cfg))
    proc = subprocess.run([sys.executable, "-m", "icprl_lightning", "fit", "--config", str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "lamda" in proc.stderr


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
def test_print_config_shows_linked_model_and_data():
    proc = subprocess.run([sys.executable, "-m", "icprl_lightning", "fit", "--config",
                           "configs/icpo_darkroom.yaml", "--print_config"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    printed = yaml.safe_load(proc.stdout)
    assert printed["model"]["class_path"] == "icprl_lightning.methods.icpo.ICPOModule"
    assert printed["data"]["init_args"]["setting"]["init_args"]["bt_temperature"] == 1.0


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
def test_fit_saves_config_and_checkpoint_then_validate_and_generate(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    root = tmp_path / "data"
    main(["generate", "--config", f"{_repo()}/configs/icpo_darkroom.yaml", *tiny_data_args(root)])
    assert len([p for p in root.iterdir() if p.name.startswith("darkroom")]) == 1
    cli = run_cli(["fit", "--config", f"{_repo()}/configs/icpo_darkroom.yaml", "--trainer.max_epochs", "1",
                   "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1",
                   "--trainer.logger.init_args.save_dir", str(tmp_path / "runs"), *tiny_data_args(root)])
    saved = glob.glob(str(tmp_path / "runs" / "icprl" / "*" / "config.yaml"))
    assert len(saved) == 1
    assert yaml.safe_load(Path(saved[0]).read_text())["model"]["init_args"]["lam"] == 1.0
    ckpt = cli.trainer.checkpoint_callback.last_model_path
    assert ckpt.endswith("last.ckpt")
    assert "val/darkroom/high/return" in cli.trainer.callback_metrics
    capsys.readouterr()
    for _ in range(2):  # validate writes no config.yaml into the working directory, so it can run again
        val = run_cli(["validate", "--config", f"{_repo()}/configs/icpo_darkroom.yaml", "--ckpt_path", ckpt,
                       "--trainer.logger", "false", *tiny_data_args(root)])
        assert "val/darkroom/low/return" in val.trainer.callback_metrics
    assert not (tmp_path / "config.yaml").exists()
    printed = capsys.readouterr().err  # the rollout callback's table, with the behavior policy beside
    assert "In-context rollouts on held-out tasks" in printed and "behavior return" in printed
    assert "darkroom/high" in printed
    # the run's saved config + checkpoint deploy through `icprl evaluate`
    out = tmp_path / "table"
    main(["evaluate", "--seeds", "0", "--title", "t", "--run", f"ICPO={saved[0]}:{ckpt}", "--out", str(out)])
    table = json.loads(out.with_suffix(".json").read_text())
    assert list(table["results"]) == ["ICPO", "behavior", "optimal"] and table["reference_rows_from"] == "ICPO"
    reference = val.datamodule.load().manifest["info"]["test_reference"]
    assert table["results"]["behavior"]["high"]["return"] == pytest.approx(reference["high"]["behavior_return"])
    assert out.with_suffix(".png").stat().st_size > 0 and "| ICPO |" in out.with_suffix(".md").read_text()
    # the ICPO row is the deployed checkpoint's mean over held-out goals, as the rollout callback measures it
    suites = {s.quality: s for s in val.datamodule.held_out("rollouts")}
    high = rollout_in_context(load_agent(ckpt, seed=0), suites["high"], seed=0)
    assert table["results"]["ICPO"]["high"]["return"] == pytest.approx(summarize(suites["high"], high)["return"])
    # --contexts: every episode keeps its env and episode seed; only the context changes, as each diagnostic states
    suite = suites["low"]
    moved = diagnose_suite(suite, "other_task")
    np.testing.assert_array_equal(moved.task_index, suite.task_index)
    np.testing.assert_array_equal(moved.context.states.numpy(), np.roll(suite.context.states.numpy(), 1, axis=0))
    assert not np.array_equal(moved.context.states.numpy(), suite.context.states.numpy())
    main(["evaluate", "--seeds", "0", "1", "--run", f"ICPO={saved[0]}:{ckpt},{ckpt}", "--contexts", "own",
          "other_task", "flipped_labels", "random_labels", "--out", str(tmp_path / "other")])
    other = json.loads((tmp_path / "other.json").read_text())
    assert other["contexts"] == ["own", "other_task", "flipped_labels", "random_labels"]
    assert "other task's context" in (tmp_path / "other.md").read_text()
    assert (tmp_path / "other_diagnostics.png").stat().st_size > 0
    diagnosed = other["diagnostics"]["ICPO"]
    for name in ("other_task", "flipped_labels", "random_labels"):
        # the JSON's row is the deployed checkpoint on the diagnosed contexts (random labels drawn per episode seed)
        episodes = rollout_seeds(lambda seed: load_agent(ckpt, seed=seed), suite, [0, 1],
                                 lambda seed, name=name: diagnose_suite(suite, name, seed))
        assert diagnosed[name]["low"]["return"] == pytest.approx(summarize(suite, episodes)["return"])
    # two checkpoints = two training seeds: the row is their mean, with each seed's value beside it
    row = other["results"]["ICPO"]["high"]
    assert row["training_seeds"] == 2 and row["per_seed"]["return"] == [pytest.approx(row["return"])] * 2


def _repo() -> str:
    return str(Path(__file__).resolve().parents[2])
