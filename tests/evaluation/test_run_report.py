"""A run's metrics, offline: a tiny fit of configs/icpo_darkroom.yaml writes ``metrics.csv`` (and W&B's files)
inside its run directory, prints progress and epoch summaries into a log, and ``icprl report RUN_DIR``
prints its curves and last rollout table and draws ``curves.png``.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path
from types import SimpleNamespace

import pytest
from factories import TINY_DATA, TINY_MODEL
from lightning.pytorch.loggers import CSVLogger, WandbLogger

from icprl_lightning import progress
from icprl_lightning.callbacks.progress import TrainingProgress
from icprl_lightning.callbacks.run_directory import RUN_DIR_ATTR
from icprl_lightning.callbacks.run_logs import CSVMetrics, wandb_in_run_directory
from icprl_lightning.commands import run_cli
from icprl_lightning.commands.report import main as report_main

REPO = Path(__file__).resolve().parents[2]
TINY = [*TINY_DATA, *TINY_MODEL, "--trainer.max_epochs", "2", "--trainer.limit_train_batches", "4",
        "--trainer.log_every_n_steps", "1",
        "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false"]


def tiny_fit(tmp: Path, *extra: str) -> tuple[Path, str]:
    """A tiny fit of configs/icpo_darkroom.yaml (its W&B logger saving under ``tmp/out``), wired as the CLI
    wires it: ``CSVMetrics`` and ``TrainingProgress`` among the callbacks, W&B pointed at the run directory
    before the fit. Returns the run directory and what the fit printed on stdout and stderr, as a log
    (``2>&1``, not a terminal) holds them."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out), pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp)
        mp.setattr(progress, "MIN_SECONDS", 0.0)  # tiny loops: a line at every 10%
        cli = run_cli(["--config", str(REPO / "configs/icpo_darkroom.yaml"), "--data.init_args.root_dir",
                       str(tmp / "data"), *TINY, "--trainer.logger.init_args.save_dir", str(tmp / "out"), *extra],
                      run=False)
        trainer = cli.trainer
        trainer.callbacks[:] = [c for c in trainer.callbacks if not isinstance(c, (CSVMetrics, TrainingProgress))]
        trainer.callbacks += [CSVMetrics(), TrainingProgress()]
        wandb_in_run_directory(trainer)
        trainer.fit(cli.model, datamodule=cli.datamodule)
    printed = out.getvalue()
    found = re.findall(r"^run directory: (\S+)$", printed, re.M)
    assert len(found) == 1, printed[-3000:]
    return Path(found[0]), printed


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[Path, str, Path]:
    tmp = tmp_path_factory.mktemp("report")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("WANDB_MODE", "disabled")
        run_dir, printed = tiny_fit(tmp)
    return run_dir, printed, tmp


def test_metrics_csv_lands_inside_the_run_directory(tiny_run):
    run_dir, _, tmp = tiny_run
    assert run_dir.parent.parent == tmp / "out"  # <save_dir>/<project>/<run id>
    assert sorted(p.relative_to(tmp / "out").as_posix() for p in (tmp / "out").iterdir()) == ["icprl"]
    header = (run_dir / "csv" / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"epoch", "step", "train/loss", "val/loss", "val/darkroom/high/return"} <= set(header)
    assert (run_dir / "csv" / "hparams.yaml").is_file() and (run_dir / "config.yaml").is_file()
    assert sorted(p.name for p in tmp.iterdir()) == ["data", "out"]  # nothing in the working directory


def test_a_log_shows_training_progress_and_epoch_summaries(tiny_run):
    _, printed, _ = tiny_run
    assert re.search(r"^epoch 1/2: 25% \(1/4 batches\) .*batches/s, elapsed \d+s, ETA \d+s$", printed, re.M), printed
    for epoch in (1, 2):
        summary = rf"^epoch {epoch}/2: train loss [\d.e-]+, val loss [\d.e-]+, [\d.]+ (steps/s|s/step), elapsed \d+s$"
        assert re.search(summary, printed, re.M), printed
    assert re.search(r"^rollouts darkroom/high: 100% \(100/100 steps\)", printed, re.M), printed
    assert "\r" not in printed


def test_report_prints_curves_and_the_last_rollout_table_and_draws_a_png(tiny_run, capsys):
    run_dir, _, _ = tiny_run
    report_main([str(run_dir)])
    printed = capsys.readouterr().out
    assert "Learning curves" in printed and "In-context rollouts on held-out tasks" in printed
    curve = re.search(r"val/loss\s*│\s*2\s*│\s*[\d.]+\s*│\s*[\d.]+ @ step 7 \(epoch 1\)", printed)
    assert curve, printed
    assert re.search(r"train/loss\s*│\s*8\s*│", printed), printed  # one point per step
    rows = re.findall(r"│ darkroom/(low|medium|high) ", printed)
    assert rows == ["low", "medium", "high"] and "behavior return" in printed and "optimal return" in printed
    figure = run_dir / "curves.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_errors_are_one_line(tiny_run, tmp_path, capsys):
    run_dir, _, _ = tiny_run
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "wandb").mkdir()
    cases = {tmp_path / "missing": "no such run directory", bad: "no metrics.csv: the run was logged without a CSV "
             "logger (its W&B files can be uploaded with `wandb sync`)"}
    broken = tmp_path / "broken"
    broken.mkdir()
    text = (run_dir / "csv" / "metrics.csv").read_text().splitlines()
    (broken / "metrics.csv").write_text("\n".join([text[0], text[1], re.sub(r"^\d+", "oops", text[2])]) + "\n")
    cases[broken] = "line 3 holds a value that is not a number"
    for path, message in cases.items():
        with pytest.raises(SystemExit) as exit_info:
            report_main([str(path), "--no-figure"])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("icprl report: error: ") and message in err, err


@pytest.mark.slow  # starts W&B's offline service
def test_wandb_offline_files_land_inside_the_run_directory(tmp_path):
    import wandb

    wandb.teardown()  # an earlier run in this process (WANDB_MODE=disabled) left W&B set up disabled
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("WANDB_MODE", "offline")
            run_dir, _ = tiny_fit(tmp_path, "--trainer.max_epochs", "1")
    finally:
        wandb.finish()
        wandb.teardown()  # later runs in this process read WANDB_MODE afresh
    offline = list((run_dir / "wandb").glob(f"offline-run-*-{run_dir.name}"))
    assert len(offline) == 1 and list(offline[0].glob("*.wandb")), sorted(run_dir.rglob("*"))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["icprl"]  # no <save_dir>/wandb
    assert (run_dir / "csv" / "metrics.csv").is_file()


def test_csv_metrics_adds_one_csv_logger_only_beside_another_logger(tmp_path):
    run_dir = str(tmp_path / "run")
    own = CSVLogger(str(tmp_path), name="mine")
    for loggers, added in (([], False), ([own], False), ([WandbLogger(save_dir=str(tmp_path), offline=True)], True)):
        trainer = SimpleNamespace(loggers=list(loggers), **{RUN_DIR_ATTR: run_dir})  # run_directory's choice
        CSVMetrics().setup(trainer, None, "fit")
        new = trainer.loggers[len(loggers):]
        assert len(new) == int(added), (loggers, new)
        if added:
            assert isinstance(new[0], CSVLogger) and new[0].log_dir == str(tmp_path / "run" / "csv")


def test_report_of_a_bandit_run_shows_the_regret_table_and_lowest_regret_as_best(tmp_path, capsys):
    keys = ["val/bandit/uniform/icpo/weak_regret", "val/bandit/uniform/dts/weak_regret"]
    rows = ["epoch,step,train/loss," + ",".join(keys), "0,9,0.9,,", "0,9,,0.30,0.40", "1,19,0.7,,", "1,19,,0.35,0.20"]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    report_main([str(tmp_path)])
    printed = capsys.readouterr().out
    assert "Weak regret on held-out problems" in printed and "icpo final" in printed and "dts final" in printed
    assert re.search(r"val/bandit/uniform/icpo/weak_regret\s*│\s*2\s*│\s*0\.3\s*│\s*0\.35 @ step 19 \(epoch 1\)\s*"
                     r"│\s*0\.3\s*│\s*step 9 \(epoch 0\)", printed), printed  # regret: lower is better
    assert (tmp_path / "curves.png").is_file()


def test_the_figure_shows_return_per_quality_against_steps_and_seconds_then_losses_never_the_clock(tmp_path):
    from icprl_lightning.evaluation.run_report import best_point, panels, read_metrics, run_name

    keys = ["time/train_seconds", "train/loss", "val/loss"] + [
        f"val/darkroom/{q}/{k}" for q in ("high", "low", "medium") for k in ("return", "behavior_return")]
    rows = ["epoch,step," + ",".join(keys)]
    for epoch, step in ((0, 9), (1, 19)):
        rows.append(f"{epoch},{step}," + ",".join(str(1.0 + i + step) for i in range(len(keys))))
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    curves = read_metrics(tmp_path / "metrics.csv")
    shown = panels(curves)
    assert [(title, axis) for title, axis, _ in shown] == [
        ("held-out return per context quality", "step"), ("held-out return per context quality", "seconds"),
        ("losses", "step")]
    assert list(shown[0][2]) == ["darkroom/low", "darkroom/medium", "darkroom/high"]
    assert best_point("time/train_seconds", curves["time/train_seconds"]) is None
    assert best_point("val/loss", curves["val/loss"]).step == 9
    name = run_name(tmp_path)
    assert not name.startswith("/") and name.endswith(tmp_path.name)
    report_main([str(tmp_path)])
    assert (tmp_path / "curves.png").read_bytes()[:4] == b"\x89PNG"


def test_every_training_config_keeps_a_csv_log_for_icprl_report():
    import yaml

    from icprl_lightning.commands.trainer import TRAINER_DEFAULTS

    assert TRAINER_DEFAULTS["logger"]  # a W&B logger, beside which CSVMetrics adds csv/metrics.csv
    for path in sorted((REPO / "configs").rglob("*.yaml")):
        trainer = (yaml.safe_load(path.read_text()) or {}).get("trainer") or {}
        assert trainer.get("logger", True) not in (False, None), f"{path}: logger false leaves no metrics.csv"
