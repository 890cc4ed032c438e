"""A user's mistake on the ``icprl`` command line is one line on stderr and exit status 2 (``commands/__init__.py``,
``commands.trainer.summarize_parse_error``), with "did you mean" when a close name exists; ``--verbose`` shows the
traceback; ``icprl --help`` answers without importing torch or Lightning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from icprl_lightning.commands import GROUPS, SUBCOMMANDS, main

REPO = Path(__file__).resolve().parents[2]
CONFIG = str(REPO / "configs/icpo_darkroom.yaml")


def _one_line_error(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    captured = capsys.readouterr()
    err = captured.err
    assert err.count("\n") == 1 and err.startswith(f"icprl {argv[0]}: error: "), err
    assert "usage:" not in err and "Traceback" not in err
    return err


@pytest.mark.parametrize("extra, expected", [
    (["--model.init_args.lamm", "0.3"],
     "model.init_args.lamm: ICPOModule has no argument 'lamm' (did you mean 'lam'?)"),
    (["--trainer.max_epoch", "3"], "unknown option --trainer.max_epoch (did you mean '--trainer.max_epochs'?)"),
    (["--trainer.max_epochs", "abc"], "trainer.max_epochs: expected int, got 'abc'"),
    (["--data.init_args.setting.init_args.trajectories_per_tsk", "3"],
     "StepPreferences has no argument 'trajectories_per_tsk' (did you mean 'trajectories_per_task'?)"),
    (["--data.init_args.batch_sise", "3"], "(did you mean 'batch_size'?)"),
    (["--model.class_path", "icprl_lightning.methods.icpo.ICPOModul"],
     "icprl_lightning.methods.icpo has no class 'ICPOModul' (did you mean 'ICPOModule'?)"),
    (["--model.init_args.beta", "0"], "ICPOModule: beta must be > 0, got 0"),
])
def test_a_mistake_in_a_fit_is_one_line_naming_the_key(capsys, tmp_path, extra, expected):
    err = _one_line_error(capsys, ["fit", "--config", CONFIG, "--data.init_args.root_dir", str(tmp_path), *extra])
    assert expected in err, err
    assert not any(tmp_path.iterdir())  # refused before any data was generated


def test_a_mistyped_key_in_a_config_file_is_named(capsys, tmp_path):
    overlay = tmp_path / "typo.yaml"
    overlay.write_text("trainer:\n  max_epoch: 3\n")
    err = _one_line_error(capsys, ["fit", "--config", CONFIG, "--config", str(overlay)])
    assert "max_epoch" in err, err


def test_a_missing_config_file_is_one_line(capsys, tmp_path):
    err = _one_line_error(capsys, ["fit", "--config", str(tmp_path / "nope.yaml")])
    assert "nope.yaml" in err


def test_an_unknown_subcommand_suggests_the_close_one(capsys):
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["evalute"])
    assert info.value.code == 2
    assert capsys.readouterr().err == ("icprl: error: unknown subcommand 'evalute' (did you mean 'evaluate'?); "
                                       "icprl --help lists them\n")


def test_verbose_shows_the_traceback(tmp_path):
    argv = ["fit", "--config", CONFIG, "--data.init_args.root_dir", str(tmp_path), "--model.init_args.beta", "0"]
    with pytest.raises(ValueError, match="beta must be > 0"):
        main([*argv, "--verbose"])


def test_help_lists_every_subcommand_without_importing_torch_or_lightning():
    code = ("import sys; from icprl_lightning.commands import main; main(['--help']); "
            "print('heavy:', sorted(m for m in ('torch', 'lightning', 'numpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-1] == "heavy: []", out
    for name in SUBCOMMANDS:
        assert f"\n  {name} " in out, name


@pytest.mark.parametrize(("argv", "expected"), [
    (["oracle", "trian"], "icprl oracle: error: unknown verb 'trian' (did you mean 'train'?); icprl oracle --help "
                          "lists them\n"),
    (["baseline"], "icprl baseline: error: name one of sac, dqn, tune-bandit; icprl baseline --help says what each "
                   "does\n"),
    (["analyze", "label_ceiling"], "icprl analyze: error: unknown verb 'label_ceiling' (did you mean "
                                   "'label-ceiling'?); icprl analyze --help lists them\n"),
])
def test_a_missing_or_unknown_verb_is_one_line(capsys, argv, expected):
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert capsys.readouterr().err == expected


def test_a_mistake_inside_a_verb_is_one_line_naming_the_command(capsys, tmp_path):
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["oracle", "export", str(tmp_path / "no_run"), "--out", str(tmp_path / "oracle")])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("icprl oracle export: error: ") and "summary.json" in err, err
    assert "icprl oracle train" in err  # says how to make the run it expected


@pytest.mark.parametrize(("group", "verb"), [(g, v) for g, verbs in GROUPS.items() for v in verbs])
def test_every_verb_answers_help_under_its_own_name(capsys, group, verb):
    with pytest.raises(SystemExit) as info:
        main([group, verb, "--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: icprl {group} {verb}")
