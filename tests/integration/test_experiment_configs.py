"""Every experiment file (configs/experiment/<table>.yaml) reads, says its question, and every run of it parses.

Each run's fit command (``runner.fit_command``: its configs stacked, its overrides, a training seed) is parsed by
the LightningCLI's parser of ``icprl fit`` (fast), and, in the slow tier, given to the LightningCLI with
``run=False``, which builds the trainer, model and DataModule and generates no data; there a later pipeline stage
(ICRG) is built on untrained checkpoints of the earlier stages it needs, saved from those stages' own runs with
their fold records. The reader's errors name the file and the field.
"""

from __future__ import annotations

import re
from pathlib import Path

import lightning as L
import pytest
import torch
import yaml
from factories import REPO, save_untrained
from jsonargparse import Namespace

from icprl_lightning.checkpoints import SEAL_KEY, seal
from icprl_lightning.commands.reproduce import main
from icprl_lightning.reproduce import (
    Run,
    TableError,
    fit_command,
    load_table,
    slug,
    stages,
    table_names,
)
from icprl_lightning.reproduce.deployments import evaluate_command

EXPERIMENTS = REPO / "configs" / "experiment"
HISTORY = re.compile(r"\bissue \d|\b(January|February|March|April|May|June|July|August|September|October|November|"
                     r"December)\b|\b20\d\d-\d\d-\d\d\b", re.IGNORECASE)


@pytest.mark.parametrize("name", table_names(EXPERIMENTS))
def test_an_experiment_file_is_headed_by_its_question_and_holds_no_history(name):
    lines = (EXPERIMENTS / f"{name}.yaml").read_text().splitlines()
    header = " ".join(line[2:] for line in lines[:next(i for i, line in enumerate(lines) if not line.startswith("#"))])
    assert header and "?" in header, f"{name}.yaml: no header comment asking the table's question"
    assert not [line for line in lines if HISTORY.search(line)], f"{name}.yaml: issue numbers or dates"


# ---- every run parses with the LightningCLI --------------------------------------------------------------------

def _key(run: Run) -> tuple:
    return run.configs, run.overrides, run.needs


def _matches(resolved, written: str) -> bool:
    """Whether the parsed config holds the value an override wrote on the command line."""
    if isinstance(resolved, Namespace):  # a class given by name: its class_path
        return resolved.class_path.rsplit(".", 1)[-1] == written.rsplit(".", 1)[-1]
    if isinstance(resolved, bool):
        return written == str(resolved).lower()
    if isinstance(resolved, int | float):
        return float(written) == resolved
    if isinstance(resolved, list | tuple):
        return [float(v) for v in resolved] == [float(v) for v in yaml.safe_load(written)]
    return str(resolved) == written


@pytest.fixture(scope="module")
def parser(tmp_path_factory):
    """The LightningCLI's parser of ``icprl fit`` (built once), and the runs it has parsed."""
    from icprl_lightning.commands import run_cli

    root = tmp_path_factory.mktemp("parser")
    cli = run_cli(["--config", str(REPO / "configs/icpo_darkroom.yaml"), "--trainer.default_root_dir", str(root)],
                  run=False)
    return cli.parser, root, set()


@pytest.mark.parametrize("name", table_names(EXPERIMENTS))
def test_every_run_of_an_experiment_parses_with_the_lightning_cli(name, parser, monkeypatch):
    """Each run's fit command parses (every key known, every value of its type) and sets what it overrides."""
    parse, root, parsed = parser
    monkeypatch.chdir(REPO)  # a table's paths are relative to the repository root
    for run in load_table(name, EXPERIMENTS).runs:
        if _key(run) in parsed:
            continue
        needed = {n: str(root / f"{slug(n)}.ckpt") for _, names in run.needs for n in names}
        config = parse.parse_args(fit_command(run, 0, root, needed)[2:])
        for flag in run.overrides[::2]:
            key = flag[2:]
            assert _matches(config[key], run.setting(key)), (run.name, key, config[key])
        for flag, names in run.needs:  # each earlier stage's checkpoint, one path or a list of them
            paths = [needed[n] for n in names]
            assert config[flag[2:]] == (paths[0] if len(paths) == 1 else paths), (run.name, flag)
        parsed.add(_key(run))


@pytest.fixture(scope="module")
def built() -> dict[tuple, str | None]:
    """Runs already built in this module (by fit command), with the stage checkpoint saved from each."""
    return {}


@pytest.mark.slow
@pytest.mark.parametrize("name", table_names(EXPERIMENTS))
def test_every_run_of_an_experiment_instantiates(name, built, monkeypatch, tmp_path_factory):
    """Each run's fit command builds its trainer, model and DataModule (``run=False``: no data generated); a later
    stage is built on the earlier stages it needs, saved untrained as their fits would save them."""
    from icprl_lightning.commands import run_cli

    monkeypatch.chdir(REPO)
    table = load_table(name, EXPERIMENTS)
    root = tmp_path_factory.mktemp(name)
    needed_by_others = {n for run in table.runs for _, names in run.needs for n in names}
    by_name = {run.name: run for run in table.runs}
    for stage in stages(table.runs):
        for run in stage:
            if _key(run) in built:
                continue
            needed = {n: built[_key(by_name[n])] for _, names in run.needs for n in names}
            cli = run_cli(fit_command(run, 0, root, needed)[2:], run=False)
            assert isinstance(cli.model, L.LightningModule) and isinstance(cli.datamodule, L.LightningDataModule)
            checkpoint = None
            if run.name in needed_by_others:  # an earlier stage: saved as its fit would, with its fold record
                path = root / f"{len(built)}.ckpt"
                save_untrained(cli.model, path)
                ckpt = torch.load(path, weights_only=True)
                ckpt[type(cli.datamodule).__name__] = cli.datamodule.state_dict()
                ckpt[SEAL_KEY] = seal(ckpt)
                torch.save(ckpt, path)
                checkpoint = str(path)
            built[_key(run)] = checkpoint


# ---- the reader's errors name the file and the field -----------------------------------------------------------

GOOD_RUN = "  - {name: A, configs: [configs/icpo_darkroom.yaml]}\n"


@pytest.mark.parametrize("text, field, problem", [
    ("title: t\nruns:\n  - {name: A, confgs: [configs/icpo_darkroom.yaml]}\n", "runs[0].confgs",
     "unknown key; did you mean 'configs'?"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/nope.yaml]}\n", "runs[0] (A).configs[0]",
     "configs/nope.yaml does not exist"),
    (f"title: t\nruns:\n{GOOD_RUN}  - {{name: B, configs: [configs/icpo_darkroom.yaml], "
     "needs: {model.init_args.reward_gen_checkpoint: RewardGn}}\n",
     "runs[1] (B).needs.model.init_args.reward_gen_checkpoint", "'RewardGn' is no run of this table; its runs: A, B"),
    (f"title: t\nrunz: []\nruns:\n{GOOD_RUN}", "runz", "unknown key; did you mean 'runs'?"),
    ("runs:\n" + GOOD_RUN, "title", "missing"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml], overrides: {--model.init_args.beta: 1}}\n",
     "runs[0] (A).overrides", "'--model.init_args.beta' is not a dotted key"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml], overrides: {model: {init_args: 1}}}\n",
     "runs[0] (A).overrides.model", "is a mapping: write each of its keys dotted"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml], "
     "overrides: [configs/overlays/sac_oracle.yaml]}\n", "runs[0] (A).overrides[0]",
     "configs/overlays/sac_oracle.yaml sets data.init_args.family.class_path: an overlay that picks a class goes in "
     "the run's configs"),
    (f"title: t\nruns:\n{GOOD_RUN}{GOOD_RUN}", "runs[1].name", "'A' names two runs"),
    ("title: t\nruns:\n  - {name: 'A=B', configs: [configs/icpo_darkroom.yaml]}\n", "runs[0].name", "no '=' or ','"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml], seeds: 0}\n", "runs[0] (A).seeds",
     "must be a non-empty list of integers"),
    ("title: t\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml], checkpoint: first}\n",
     "runs[0] (A).checkpoint", "must be one of last, best"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', act: argmax}}]\n", "evaluations[0].act",
     "must be one of greedy, sample"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', online: {{labels: flipd}}}}]\n",
     "evaluations[0].online.labels", "must be one of own, flipped, random"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', online: {{rules: [top_three]}}}}]\n",
     "evaluations[0].online.rules[0]", "must be one of action_uniform"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', online: {{rounds: 0}}}}]\n",
     "evaluations[0].online.rounds", "must be an integer ≥ 1"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', data: [configs/eval/nope.yaml]}}]\n",
     "evaluations[0].data[0]", "configs/eval/nope.yaml does not exist"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', online: {{}}, "
     f"data: [configs/eval/reach_fresh_goals.yaml]}}]\n",
     "evaluations[0].data", "an online evaluation deploys on the runs' own data"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: ''}}, {{suffix: ''}}]\n", "evaluations",
     "two write the same outputs"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: {{episodes: 0}}}}]\n",
     "evaluations[0].ad.episodes", "must be an integer ≥ 1, got 0"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: {{episods: 5}}}}]\n",
     "evaluations[0].ad.episods", "unknown key; did you mean 'episodes'?"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', act: greedy, ad: {{}}}}]\n",
     "evaluations[0].act", "an ad evaluation deploys AD with its default actions"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: {{against: {{ICPO: results/nope.json}}}}}}]\n",
     "evaluations[0].ad.against.ICPO", "results/nope.json does not exist"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: {{against: [results/nope.json]}}}}]\n",
     "evaluations[0].ad.against", "must be a mapping"),
    (f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: {{}}}}]\nbaselines: "
     "{DQN: docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json}\n", "baselines",
     "an ad evaluation takes none"),
    (f"title: t\nruns:\n{GOOD_RUN}contexts: [own, flipped]\n", "contexts[1]", "must be one of own, "),
    (f"title: t\nruns:\n{GOOD_RUN}figure: violin\n", "figure", "must be one of lambda_beta, teacher_noise"),
    (f"title: t\nruns:\n{GOOD_RUN}ceiling: results/nope.json\n", "ceiling", "results/nope.json does not exist"),
    (f"title: t\nruns:\n{GOOD_RUN}ceiling: configs/icpo_darkroom.yaml\n", "ceiling",
     "configs/icpo_darkroom.yaml is not JSON"),
    (f"title: t\nruns:\n{GOOD_RUN}ceiling: docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json\n", "ceiling",
     "holds no numeric everything.return_walking_to_map_goal for any quality"),
    ("title: t\nruns_from: nowhere\nruns: [A]\n", "runs_from", "no table 'nowhere'"),
    ("title: t\nruns_from: darkroom_ipref\nruns: [ICPQ]\n", "runs", "['ICPQ']: no such run in darkroom_ipref"),
])
def test_a_wrong_experiment_file_is_one_error_naming_the_file_and_field(text, field, problem, tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    with pytest.raises(TableError) as error:
        load_table(path, EXPERIMENTS)
    assert str(error.value).startswith(f"{path}: {field}: ") and problem in str(error.value), str(error.value)


def test_icprl_reproduce_reports_a_wrong_table_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(REPO)
    for argv, message in (([str(tmp_path / "absent.yaml")], f"{tmp_path / 'absent.yaml'}: no such experiment file"),
                          (["darkroom_iprf"], "no table 'darkroom_iprf' in configs/experiment/; did you mean "
                                              "'darkroom_ipref'?")):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and err.count("\n") == 1 and message in err, err
    monkeypatch.chdir(tmp_path)  # away from the repository: the folder is not there
    with pytest.raises(SystemExit):
        main(["--list"])
    assert "run icprl reproduce from the repository root" in capsys.readouterr().err


def test_overrides_become_flags_in_the_order_written(tmp_path, monkeypatch):
    """Mappings and values-only overlays, in order, a later key repeated as on a command line; values as YAML
    writes them (booleans, null, lists)."""
    monkeypatch.chdir(tmp_path)
    Path("base.yaml").write_text("model: {}\n")
    Path("overlay.yaml").write_text("data:\n  init_args:\n    setting:\n      init_args:\n        n: 600\n"
                                    "trainer:\n  limit_train_batches: 300\n")
    Path("t.yaml").write_text(
        "title: t\ngroups:\n  pick: &pick {model.init_args.eta: 1.0, model.init_args.gamma: 0.95}\nruns:\n"
        "  - name: A\n    configs: [base.yaml]\n"
        "    overrides: [overlay.yaml, *pick, {model.init_args.range: [0, 1], model.init_args.center: false,\n"
        "                model.init_args.scale: null, model.init_args.eta: 1e6, trainer.limit_train_batches: 30}]\n")
    (run,) = load_table("t.yaml").runs
    assert run.overrides == ("--data.init_args.setting.init_args.n", "600", "--trainer.limit_train_batches", "300",
                             "--model.init_args.eta", "1.0", "--model.init_args.gamma", "0.95",
                             "--model.init_args.range", "[0, 1]", "--model.init_args.center", "false",
                             "--model.init_args.scale", "null", "--model.init_args.eta", "1e6",
                             "--trainer.limit_train_batches", "30")
    assert run.setting("model.init_args.eta") == "1e6" and run.setting("trainer.limit_train_batches") == "30"
    assert fit_command(run, 0, tmp_path)[2:4] == ["--config", "base.yaml"]


def test_an_evaluation_s_data_files_are_stacked_by_icprl_evaluate(monkeypatch):
    """metaworld_heldout deploys the same fits on the paper's goals and, with ``--data``, on fresh ones."""
    monkeypatch.chdir(REPO)
    table = load_table("metaworld_heldout")
    paper, fresh = table.evaluations
    assert paper.data == () and fresh.data == ("configs/eval/reach_fresh_goals.yaml",)
    checkpoints = {run.name: [f"runs/{run.name}/checkpoints/last.ckpt"] for run in table.runs}
    command = evaluate_command(table, fresh, checkpoints, Path("out"))
    assert command[command.index("--data") + 1] == "configs/eval/reach_fresh_goals.yaml"
    assert "--data" not in evaluate_command(table, paper, checkpoints, Path("out"))


def test_an_ad_evaluation_reads_its_episodes_and_the_curves_drawn_beside_it(tmp_path, monkeypatch):
    """ad_darkroom deploys AD's training seeds for 20 episodes beside the paper-recipe ICPO's online curve; an empty
    ``ad`` takes the defaults."""
    from icprl_lightning.reproduce.tables import ADEvaluation

    monkeypatch.chdir(REPO)
    table = load_table("ad_darkroom")
    online = "docs/results/online_darkroom_paper/online_darkroom_paper.json"
    assert table.evaluations == (ADEvaluation("", 20, (("ICPO online (paper recipe)", online),)),)
    assert table.eval_seeds == (0, 1) and [run.configs for run in table.runs] == [("configs/ad_darkroom.yaml",)]
    path = tmp_path / "mine.yaml"
    path.write_text(f"title: t\nruns:\n{GOOD_RUN}evaluations: [{{suffix: '', ad: null}}]\n")
    assert load_table(path).evaluations == (ADEvaluation(""),)
