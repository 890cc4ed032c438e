"""The README's Python snippets of "Preferences from your own source" and "Online deployment" run as written."""

from __future__ import annotations

import re

import pytest
from factories import REPO, cli_data_args

from icprl_lightning.cli import run_cli


def _snippets(section: str) -> list[str]:
    text = (REPO / "README.md").read_text()
    body = text.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", body, re.S)


def test_the_annotator_snippet_generates_a_dataset(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the snippet writes under ./data
    (code,) = _snippets("Preferences from your own source")
    exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    printed = capsys.readouterr().out.split()
    assert printed[0] == "icprl_lightning.annotators.CallableAnnotator" and 0.5 < float(printed[1]) <= 1.0


@pytest.mark.slow
def test_the_online_snippet_runs_on_a_trained_bandit_checkpoint(tmp_path, monkeypatch, capsys):
    data = cli_data_args("bandit", root_dir=str(tmp_path / "data"), n_train_problems=8, n_val_problems=2,
                         n_eval_problems=4, batch_size=4, progress=False)
    cli = run_cli(["fit", "--config", str(REPO / "configs/icpo_bandit.yaml"), "--trainer.logger", "false",
                   "--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2",
                   "--trainer.limit_val_batches", "1",
                   "--trainer.callbacks", "[]", "--trainer.default_root_dir", str(tmp_path), *data])
    assert cli.trainer.global_step == 2
    checkpoint = str(next(tmp_path.rglob("*.ckpt")))  # Lightning's default checkpoint callback
    (code,) = _snippets("Online deployment")
    capsys.readouterr()
    exec(compile(code, "README.md", "exec"), {"__name__": "readme", "CHECKPOINT": checkpoint})
    assert capsys.readouterr().out.startswith("100 tensor(")
