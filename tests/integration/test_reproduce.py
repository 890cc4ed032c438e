"""``icprl reproduce``: trains every run per training seed, evaluates with the diagnostics, resumes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from factories import REPO, tiny_darkroom_args

from icprl_lightning.commands.reproduce import main
from icprl_lightning.reproduce import (
    Evaluation,
    OnlineEvaluation,
    Run,
    Table,
    TableError,
    fit_command,
    fit_inputs,
    load_table,
    load_tables,
    needed_runs,
    reproduce,
    slug,
    stages,
)


@pytest.fixture
def tables(monkeypatch) -> dict[str, Table]:
    """Every table of configs/experiment/, read from the repository root (their paths are relative to it)."""
    monkeypatch.chdir(REPO)
    return load_tables()


def test_list_names_every_experiment_file_with_its_budget(tables, capsys):
    assert len(tables) == len(list((REPO / "configs/experiment").glob("*.yaml"))) > 20
    main(["--list"])
    listed = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in listed] == sorted(tables)
    assert all(table.budget in line for table, line in zip(tables.values(), listed, strict=True))
    assert "online_bandit: " in "\n".join(listed) and "1 runs of bandit" in "\n".join(listed)


def test_fit_command_sets_the_training_seed_after_the_configs(tmp_path):
    run = Run("ICPO", ("a.yaml", "b.yaml"), ("--model.init_args.beta", "0.1"))
    command = fit_command(run, 2, tmp_path)
    assert command[:6] == ["icprl", "fit", "--config", "a.yaml", "--config", "b.yaml"]
    assert command[command.index("--seed_everything") + 1] == "2"


@pytest.mark.slow
def test_a_tiny_table_trains_two_seeds_evaluates_and_resumes(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    data = tiny_darkroom_args(str(tmp_path / "data"))
    tiny = ("--trainer.max_epochs", "1", "--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1",
            *data)
    table = Table("tiny", "tiny", (Run("ICPO", ("configs/icpo_darkroom.yaml", "configs/overlays/uniform_states.yaml"),
                                       tiny),),
                  evaluations=(Evaluation("", ("--greedy",)),), eval_seeds=(0,))
    summary = reproduce(table, [0, 1], jobs=2, work=tmp_path / "work", out_dir=tmp_path / "out")
    assert sorted(summary["fits"]) == ["ICPO-seed0", "ICPO-seed1"]
    checkpoints = [fit["checkpoint"] for fit in summary["fits"].values()]
    assert len(set(checkpoints)) == 2 and all(c.endswith("last.ckpt") for c in checkpoints)
    result = json.loads((tmp_path / "out" / "tiny.json").read_text())
    row = result["results"]["ICPO"]["low"]
    assert row["training_seeds"] == 2 and len(row["per_seed"]["return"]) == 2
    assert set(result["diagnostics"]["ICPO"]) == {"random_labels", "flipped_labels", "other_task"}
    # the evaluation read the run's own dataset: the uniform-state one of the overlay
    saved = json.loads((tmp_path / "out" / "tiny_reproduce.json").read_text())
    assert "uniform_states.yaml" in saved["fits"]["ICPO-seed0"]["command"]
    # each fit's CSV log gives its held-out return per validation epoch (the rollout callback's), and the
    # training seconds at that point (TrainingClock, a default callback)
    curve = saved["learning_curves"]["ICPO"]["0"]
    assert len(curve) == 1 and set(curve[0]) == {"step", "low", "medium", "high", "train_seconds"}
    assert curve[0]["train_seconds"] > 0
    assert (tmp_path / "out" / "tiny_curve.png").stat().st_size > 0
    # a second call finds both fits recorded and trains nothing
    again = reproduce(table, [0, 1], jobs=2, work=tmp_path / "work", out_dir=tmp_path / "out")
    assert again["fits"] == summary["fits"]


def test_run_names_read_back_through_evaluate_and_paths(tables):
    for table in tables.values():
        for run in table.runs:
            assert "=" not in run.name and "," not in run.name, run.name  # --run NAME=CONFIG:CKPT,CKPT
    assert slug("ICPO (labels at tau 0.25)") == "ICPO_labels_at_tau_0.25"


def test_a_record_is_reused_only_while_its_command_and_configs_are_unchanged(tmp_path, capsys):
    config = tmp_path / "method.yaml"
    config.write_text("model:\n  init_args:\n    beta: 1.0\n")
    run = Run("ICPO", (str(config),))
    table = Table("tiny", "tiny", (run,), evaluations=(Evaluation("", ()),))
    work = tmp_path / "work"
    command = fit_command(run, 0, work / "tiny" / "runs")
    (work / "tiny").mkdir(parents=True)
    record = work / "tiny" / "ICPO-seed0.json"
    checkpoint = tmp_path / "last.ckpt"
    checkpoint.write_bytes(b"")
    record.write_text(json.dumps({"command": " ".join(command), "inputs_sha256": fit_inputs(run, command),
                                  "checkpoint": str(checkpoint), "seconds": 1.0}))
    reproduce(table, [0], jobs=1, work=work, out_dir=tmp_path / "out", dry_run=True)
    assert "icprl fit" not in capsys.readouterr().out  # recorded and unchanged: nothing to train
    checkpoint.unlink()  # unchanged, but its checkpoint is gone: trained again, not reused
    reproduce(table, [0], jobs=1, work=work, out_dir=tmp_path / "out", dry_run=True)
    out = capsys.readouterr().out
    assert f"the checkpoint {checkpoint} recorded in {record} is gone; training it again" in out and "icprl fit" in out
    checkpoint.write_bytes(b"")
    config.write_text("model:\n  init_args:\n    beta: 0.1\n")  # the config changed since the fit
    reproduce(table, [0], jobs=1, work=work, out_dir=tmp_path / "out", dry_run=True)
    out = capsys.readouterr().out
    assert "changed since" in out and "icprl fit" in out
    record.write_text(json.dumps({"command": " ".join(command), "checkpoint": str(checkpoint)}))  # no digest
    reproduce(table, [0], jobs=1, work=work, out_dir=tmp_path / "out", dry_run=True)
    assert "icprl fit" in capsys.readouterr().out


@pytest.mark.parametrize("text, problem", [("{\"checkpoint\": \"x", "is damaged"),
                                           ("[1, 2]", "is not an icprl reproduce record (a JSON list"),
                                           ("{\"checkpoint\": 3}", "its 'checkpoint' is 3, not a string"),
                                           ("{\"inputs\": \"abc\"}", "its 'checkpoint' is None"),
                                           ("{\"checkpoint\": \"c\", \"inputs_sha256\": [1]}", "'inputs_sha256'")])
def test_a_damaged_or_foreign_record_is_one_error_naming_it_before_any_fit(tmp_path, monkeypatch, capsys, text,
                                                                           problem):
    """Every record is read before the first fit: the good run's fit never starts, the bad record is named."""
    import icprl_lightning.reproduce.runner as rep

    def no_fit(*args, **kwargs):
        raise AssertionError("a fit started before the records were checked")

    monkeypatch.setattr(rep, "run_fit", no_fit)
    pair = tmp_path / "pair.yaml"  # a table of the user's own, named by its path
    pair.write_text("title: pair\nruns:\n  - {name: A, configs: [configs/icpo_darkroom.yaml]}\n"
                    "  - {name: B, configs: [configs/icpo_darkroom.yaml]}\n")
    monkeypatch.chdir(REPO)
    work = tmp_path / "work"
    (work / "pair").mkdir(parents=True)
    bad = work / "pair" / "B-seed0.json"
    bad.write_text(text)
    with pytest.raises(SystemExit) as exit_:
        main([str(pair), "--seeds", "0", "--jobs", "1", "--work", str(work), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err  # one line, no traceback
    assert err.startswith(f"icprl reproduce: error: fit record {bad} ") and problem in err
    assert "--refit" in err


@pytest.mark.parametrize("table_name, metric, reference", [("bandit_teacher_noise", "weak_regret", "dts"),
                                                           ("darkroom_teacher_noise", "return", "behavior")])
def test_teacher_noise_figure_reads_regret_or_return(tables, tmp_path, table_name, metric, reference):
    from icprl_lightning.reproduce import FIGURES

    table = tables[table_name]
    rates = {run.name: run.setting("data.init_args.setting.init_args.annotator.init_args.epsilon")
             for run in table.runs}
    assert rates == {f"ICPO eps{e}": e for e in ("0", "0.1", "0.2", "0.3")}
    sources = ("uniform", "dts") if metric == "weak_regret" else ("low", "medium", "high")
    results = {name: {s: {metric: 0.1 * i, f"{metric}_sem": 0.01} for s in sources}
               for i, name in enumerate(rates)}
    results[reference] = {s: {metric: 0.5} for s in sources}
    (tmp_path / f"{table_name}.json").write_text(json.dumps({"results": results}))
    FIGURES[table.figure](table, tmp_path)
    assert (tmp_path / f"{table_name}_vs_noise.png").stat().st_size > 0


PIPELINE = (Run("policy", ("p.yaml",), needs=(("--model.init_args.reward", ("reward",)),
                                                ("--model.init_args.folds", ("fold0", "fold1")))),
            Run("fold0", ("r.yaml",), evaluated=False), Run("reward", ("r.yaml",), evaluated=False),
            Run("fold1", ("r.yaml",), evaluated=False), Run("baseline", ("b.yaml",)))


def test_a_later_stage_trains_after_the_runs_it_needs_and_gets_their_checkpoints(tmp_path):
    assert [[r.name for r in stage] for stage in stages(PIPELINE)] == [["fold0", "reward", "fold1", "baseline"],
                                                                        ["policy"]]
    paths = {"reward": "r/best.ckpt", "fold0": "f0/best.ckpt", "fold1": "f1/best.ckpt"}
    command = fit_command(PIPELINE[0], 1, tmp_path, paths)
    assert command[command.index("--model.init_args.reward") + 1] == "r/best.ckpt"
    assert command[command.index("--model.init_args.folds") + 1] == "[f0/best.ckpt,f1/best.ckpt]"
    # its record goes stale when an earlier stage is retrained, even at the same checkpoint path
    (tmp_path / "p.yaml").write_text("model: {}\n")
    run = Run("policy", (str(tmp_path / "p.yaml"),), needs=PIPELINE[0].needs)
    assert fit_inputs(run, command, ("a", "b", "c")) != fit_inputs(run, command, ("a", "b", "changed"))
    with pytest.raises(ValueError, match="cycle"):
        stages((Run("x", ("x.yaml",), needs=(("--a", ("y",)),)), Run("y", ("y.yaml",), needs=(("--b", ("x",)),))))
    with pytest.raises(ValueError, match="lacks"):
        stages((Run("x", ("x.yaml",), needs=(("--a", ("nowhere",)),)),))


def test_only_keeps_the_named_runs_and_what_they_need():
    table = Table("pipeline", "pipeline", PIPELINE)
    assert {r.name for r in needed_runs(table, ["policy"]).runs} == {"policy", "reward", "fold0", "fold1"}
    assert [r.name for r in needed_runs(table, ["fold1"]).runs] == ["fold1"]
    with pytest.raises(ValueError, match="no such run"):
        needed_runs(table, ["ICRG"])


def test_the_tprl_table_passes_each_seeds_reward_models_to_icrg(tables, tmp_path, capsys):
    """Dry run with the RewardGen stages recorded: ICRG's commands name the same seed's checkpoints."""
    table = tables["darkroom_tprl"]
    work = tmp_path / "work"
    (work / table.name).mkdir(parents=True)
    ckpt = tmp_path / "ckpt"  # the recorded checkpoints exist: a record whose file is gone is trained again
    for run in stages(table.runs)[0]:
        command = fit_command(run, 0, work / table.name / "runs")
        (ckpt / f"{slug(run.name)}-seed0").mkdir(parents=True)
        (ckpt / f"{slug(run.name)}-seed0" / "best.ckpt").write_bytes(b"")
        record = {"command": " ".join(command), "inputs_sha256": fit_inputs(run, command),
                  "checkpoint": f"{ckpt}/{slug(run.name)}-seed0/best.ckpt"}
        (work / table.name / f"{slug(run.name)}-seed0.json").write_text(json.dumps(record))
    reproduce(table, [0], jobs=1, work=work, out_dir=tmp_path / "out", dry_run=True)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("icprl fit")]
    icrg = [run for run in table.runs if run.needs]
    assert len(icrg) >= 2 and len(lines) == len(icrg)  # only the ICRG stage is left
    assert all("icrg_darkroom.yaml" in line for line in lines)
    for run in icrg:  # each ICRG names the same seed's checkpoint of the RewardGen run it needs
        line = next(line for line in lines if f"--trainer.logger.init_args.name {slug(run.name)}-seed0 " in line)
        (stage1,) = dict(run.needs)["--model.init_args.reward_gen_checkpoint"]
        assert f"--model.init_args.reward_gen_checkpoint {ckpt}/{slug(stage1)}-seed0/best.ckpt" in line
    assert sum(f"{ckpt}/RewardGen-seed0/best.ckpt" in line for line in lines) >= 2
    crossfit = [run for run in icrg if len(run.needs) == 2]
    assert sum("cross_fit_checkpoints" in line for line in lines) == len(crossfit) >= 2
    for run in crossfit:  # the fold models in fold order, of the same seed
        line = next(line for line in lines if f"--trainer.logger.init_args.name {slug(run.name)}-seed0 " in line)
        folds = dict(run.needs)["--model.init_args.cross_fit_checkpoints"]
        assert "[" + ",".join(f"{ckpt}/{slug(f)}-seed0/best.ckpt" for f in folds) + "]" in line
    unbounded = f"[{ckpt}/RewardGen_fold0-seed0/best.ckpt,{ckpt}/RewardGen_fold1-seed0/best.ckpt]"
    assert any(unbounded in line for line in lines)


def test_a_later_stage_starts_as_soon_as_its_own_needs_are_done(tmp_path, monkeypatch):
    """With 2 jobs, C (which needs the quick B) trains while the slow A, which it does not need, still runs."""
    import threading

    import icprl_lightning.reproduce.runner as rep

    events, a_may_finish = [], threading.Event()

    def fake_fit(command, inputs, log, record, threads, which="last", children=None):
        name = command[command.index("--trainer.logger.init_args.name") + 1]
        events.append(("start", name))
        if name.startswith("A-"):
            assert a_may_finish.wait(10), "C never started while A ran"
        if name.startswith("C-"):
            assert "--needs" in command and command[command.index("--needs") + 1] == "b.ckpt"
            a_may_finish.set()
        events.append(("end", name))
        return {"command": " ".join(command), "inputs_sha256": inputs, "checkpoint": f"{name[0].lower()}.ckpt",
                "seconds": 0.0}

    monkeypatch.setattr(rep, "run_fit", fake_fit)
    for name in "abc":
        (tmp_path / f"{name}.yaml").write_text("model: {}\n")
    table = Table("sched", "sched", (Run("A", (str(tmp_path / "a.yaml"),)), Run("B", (str(tmp_path / "b.yaml"),)),
                                     Run("C", (str(tmp_path / "c.yaml"),), needs=(("--needs", ("B",)),))))
    summary = reproduce(table, [0], jobs=2, work=tmp_path / "work", out_dir=tmp_path / "out", only=["A", "C"])
    assert sorted(summary["fits"]) == ["A-seed0", "B-seed0", "C-seed0"]
    assert events.index(("start", "C-seed0")) < events.index(("end", "A-seed0"))
    assert events.index(("end", "B-seed0")) < events.index(("start", "C-seed0"))


@pytest.mark.parametrize("which, printed", [
    ("last", "last checkpoint (epoch 0, step 2): {path}"), ("last", "last checkpoint: {path}"),
    ("best", "best checkpoint (val/loss = 0.25, epoch 3): {path}")])
def test_a_fit_record_takes_the_checkpoint_the_fit_printed(tmp_path, monkeypatch, which, printed):
    from icprl_lightning.reproduce.children import Children, run_fit

    path = tmp_path / "runs" / "a b" / "checkpoints" / f"{which}.ckpt"

    def fake_fit(self, argv, log, env):
        best = "best checkpoint (val/loss = 9.0): /elsewhere.ckpt"
        other = best if which == "last" else "last checkpoint: /elsewhere.ckpt"
        log.write_text(f"Epoch 0: 100%\n{other}\n{printed.format(path=path)}\n")
        return 0

    monkeypatch.setattr(Children, "run", fake_fit)
    result = run_fit(["icprl", "fit"], "digest", tmp_path / "fit.log", tmp_path / "rec.json", 1, which, Children())
    assert result["checkpoint"] == str(path) and json.loads((tmp_path / "rec.json").read_text()) == result


def test_final_epoch_means_average_the_last_epochs_training_metrics(tmp_path):
    from icprl_lightning.reproduce import final_epoch_means, learning_curve

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "metrics.csv").write_text(
        "epoch,step,train/clipped_fraction,val/darkroom/low/return,time/train_seconds\n"
        "0,10,0.9,,\n1,20,0.1,,\n1,30,0.3,,\n1,30,,12.5,4.04\n")
    checkpoint = str(tmp_path / "checkpoints" / "last.ckpt")
    assert final_epoch_means(checkpoint) == {"clipped_fraction": pytest.approx(0.2)}  # epoch 0's 0.9 left out
    assert learning_curve(checkpoint) == [{"step": 30, "low": 12.5, "train_seconds": 4.0}]
    assert final_epoch_means(str(tmp_path / "elsewhere" / "checkpoints" / "last.ckpt")) == {}


def test_redraw_draws_every_figure_from_the_outputs_alone(tables, tmp_path):
    from icprl_lightning.commands.reproduce import main

    table = tables["darkroom_dit_steps"]
    with pytest.raises(FileNotFoundError, match="run `icprl reproduce darkroom_dit_steps` first"):
        main([table.name, "--redraw", "--out", str(tmp_path)])
    results = REPO / "docs" / "results" / table.name
    (tmp_path / table.name).mkdir()
    for suffix in ("", "_sampled", "_reproduce"):
        shutil.copy(results / f"{table.name}{suffix}.json", tmp_path / table.name)
    main([table.name, "--redraw", "--out", str(tmp_path)])
    drawn = {p.name for p in (tmp_path / table.name).glob("*.png")}
    assert drawn == {f"{table.name}{s}.png" for s in ("", "_diagnostics", "_sampled", "_sampled_diagnostics", "_curve")}


def test_an_ad_run_plays_online_as_the_ad_row_on_the_data_and_beside_the_models_its_table_names(tmp_path, monkeypatch):
    """An AD run's checkpoints go to the online deployment as ``ad_checkpoints``, on the ``data`` config (its own data
    are learning histories), with the ``beside`` models as the ICPO checkpoints; a wrong ``beside`` is one error."""
    import icprl_lightning.evaluation.online_command as online_command
    import icprl_lightning.reproduce.runner as rep

    def fake_fit(command, inputs, log, record, threads, which="last", children=None):
        run_dir = tmp_path / "runs" / command[command.index("--trainer.logger.init_args.name") + 1]
        (run_dir / "checkpoints").mkdir(parents=True)
        (run_dir / "config.yaml").write_text("model:\n  class_path: icprl_lightning.methods.ad.ADModule\n")
        checkpoint = run_dir / "checkpoints" / "last.ckpt"
        checkpoint.write_bytes(b"")
        result = {"command": " ".join(command), "inputs_sha256": inputs, "checkpoint": str(checkpoint), "seconds": 0}
        record.write_text(json.dumps(result))
        return result

    deployed = []
    monkeypatch.setattr(rep, "run_fit", fake_fit)
    monkeypatch.setattr(online_command, "evaluate_online",
                        lambda configs, checkpoints, **options: deployed.append((configs, checkpoints, options)) or {})
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ad.yaml").write_text("model: {}\n")
    (tmp_path / "duels.yaml").write_text("data: {}\n")
    (tmp_path / "t.yaml").write_text(
        "title: t\nruns:\n  - {name: AD, configs: [ad.yaml]}\nevaluations:\n"
        "  - {suffix: '', online: {rounds: 20, data: duels.yaml, beside: [bandit-icpo]}}\n")
    reproduce(load_table("t.yaml"), [0, 1], jobs=1, work=tmp_path / "work", out_dir=tmp_path / "out")
    ((configs, checkpoints, options),) = deployed
    assert configs == ["duels.yaml"] and checkpoints == ["bandit-icpo"]
    assert [Path(c).parent.parent.name for c in options["ad_checkpoints"]] == ["AD-seed0", "AD-seed1"]
    (tmp_path / "u.yaml").write_text("title: t\nruns:\n  - {name: AD, configs: [ad.yaml]}\nevaluations:\n"
                                     "  - {suffix: '', online: {beside: [bandit-icpp]}}\n")
    with pytest.raises(TableError, match=r"evaluations\[0\]\.online\.beside\[0\]: bandit-icpp is neither a checkpoint"):
        load_table("u.yaml")


def test_a_table_of_another_tables_runs_shares_its_fits_and_evaluates_online_through_one_call(tmp_path, monkeypatch,
                                                                                               capsys):
    """An online table deploys the runs of another: its fits land in that table's folder (and are found there by
    that table), and each online evaluation is one ``evaluate_online`` call, which deploys the run's training
    seeds through the package's online evaluation (``evaluation/online_command.py``) with the table's options."""
    import icprl_lightning.reproduce.runner as rep

    def fake_fit(command, inputs, log, record, threads, which="last", children=None):
        checkpoint = tmp_path / "ckpt" / f"{command[command.index('--trainer.logger.init_args.name') + 1]}.ckpt"
        checkpoint.parent.mkdir(exist_ok=True)
        checkpoint.write_bytes(b"")
        result = {"command": " ".join(command), "inputs_sha256": inputs, "checkpoint": str(checkpoint), "seconds": 0}
        record.write_text(json.dumps(result))
        return result

    monkeypatch.setattr(rep, "run_fit", fake_fit)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.yaml").write_text("model: {}\n")
    folder = tmp_path / "experiments"
    folder.mkdir()
    (folder / "source.yaml").write_text("title: source\nruns:\n  - {name: A, configs: [a.yaml]}\n"
                                        "  - {name: B, configs: [a.yaml], overrides: {model.init_args.beta: 0.5}}\n")
    (folder / "asked.yaml").write_text(
        "title: asked online\nruns_from: source\nruns: [B]\neval_seeds: [0, 1, 2]\nevaluations:\n"
        "  - {suffix: _active, online: {rounds: 20, rules: [action_uniform, top_two], figure: true}}\n"
        "  - {suffix: _flipped, online: {rounds: 20, labels: flipped}}\n")
    online = load_table("asked", folder)
    assert online.runs_from == "source" and [r.name for r in online.runs] == ["B"]
    assert online.runs[0].setting("model.init_args.beta") == "0.5" and online.runs[0].setting("trainer.x") is None
    assert online.evaluations == (OnlineEvaluation("_active", ("action_uniform", "top_two"), rounds=20, figure=True),
                                  OnlineEvaluation("_flipped", labels="flipped", rounds=20))
    work, out = tmp_path / "work", tmp_path / "out"
    import icprl_lightning.evaluation.online_command as online_command

    deployed = []

    def fake_deploy(configs, checkpoints, **options):
        deployed.append((configs, checkpoints, options))
        return {"configs": [str(c) for c in configs]}

    monkeypatch.setattr(online_command, "evaluate_online", fake_deploy)
    reproduce(online, [0, 1], jobs=1, work=work, out_dir=out)
    (configs, checkpoints, first), (_, _, second) = deployed
    assert configs == [tmp_path / "config.yaml"] and checkpoints == [str(tmp_path / "ckpt" / "B-seed0.ckpt"),
                                                                               str(tmp_path / "ckpt" / "B-seed1.ckpt")]
    assert (first["rules"], first["labels"], first["seeds"], first["rounds"], first["out"]) == (
        ("action_uniform", "top_two"), "own", (0, 1, 2), 20, out / "asked_active")  # the figure: out writes it
    assert (second["labels"], second["out"]) == ("flipped", None)
    assert json.loads((out / "asked_flipped.json").read_text()) == {"configs": [str(configs[0])]}
    assert sorted(p.name for p in (work / "source").glob("*.json")) == ["B-seed0.json", "B-seed1.json"]
    assert not (work / "asked").exists()
    reproduce(load_table("source", folder), [0, 1], jobs=1, work=work, out_dir=out, dry_run=True, only=["B"])
    assert "icprl fit" not in capsys.readouterr().out  # the source table finds the online table's fits

    calls = []

    def fake_online(table, evaluation, checkpoints, out_dir):
        calls.append((evaluation.suffix, evaluation.labels, sorted(checkpoints)))
        return {"out": str(out_dir / f"{table.name}{evaluation.suffix}.json")}

    from icprl_lightning.reproduce import deployments

    monkeypatch.setattr(deployments, "deploy_online", fake_online)
    summary = reproduce(online, [0, 1], jobs=1, work=work, out_dir=out)
    assert calls == [("_active", "own", ["B"]), ("_flipped", "flipped", ["B"])]
    assert [e["online"]["out"] for e in summary["evaluations"]] == [str(out / "asked_active.json"),
                                                                    str(out / "asked_flipped.json")]


def test_the_tables_that_borrow_runs_deploy_the_runs_their_results_came_from(tables):
    """Each table with ``runs_from`` deploys the very run (same fit command) of the table it names, and writes the
    files docs/results holds for it: the online tables, the Reach held-out table (the paper's goals, fresh ones) and
    the labelling page's comparison-budget studies (a registered evaluation)."""
    borrowing = {name: table for name, table in tables.items() if table.runs_from}
    online = {"online_bandit", "online_darkroom_uniform", "online_darkroom_uniform_next", "online_darkroom_paper"}
    assert set(borrowing) == online | {"metaworld_heldout", "labelling_budget", "labelling_budget_uniform"}
    for table in borrowing.values():
        source = {run.name: run for run in tables[table.runs_from].runs}
        assert all(run == source[run.name] for run in table.runs)
        assert all(isinstance(e, OnlineEvaluation) for e in table.evaluations) == (table.name in online)
        for evaluation in table.evaluations:
            assert (REPO / "docs/results" / table.name / f"{table.name}{evaluation.suffix}.json").exists(), evaluation


def test_the_learning_curves_draw_the_tables_label_ceiling_per_quality(tables, tmp_path):
    """A table's ``ceiling`` (``icprl analyze label-ceiling``'s JSON) is a dashed line on each quality's panels at
    the Bayes-optimal reader's return, so a reader sees how far the fits are from what the labels allow."""
    from icprl_lightning.reproduce.figures import curve_figure, read_ceiling

    table = tables["darkroom_label_schedule"]
    assert table.ceiling
    ceiling = read_ceiling(table.ceiling)
    curves = json.loads((REPO / "docs" / "results" / table.name / f"{table.name}_reproduce.json").read_text())
    fig = curve_figure(table, curves["learning_curves"], tmp_path / "curve.png")
    assert (tmp_path / "curve.png").is_file()
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == 2 * 3  # steps and training seconds × low, medium, high
    for ax in panels:
        quality = ax.get_title().removesuffix(" contexts")
        dashed = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
        assert [line.get_ydata()[0] for line in dashed] == [ceiling[quality]], ax.get_title()
    assert len(set(ceiling.values())) == 3  # the qualities' ceilings differ, so a line on the wrong panel fails
