"""``icprl reproduce TABLE``: regenerate a results table and its figure from scratch.

    icprl reproduce --list
    icprl reproduce darkroom_ipref                     # 3 training seeds per method, then evaluation
    icprl reproduce darkroom_ipref --seeds 0 --jobs 1  # a quicker, one-seed version
    icprl reproduce darkroom_ipref --dry-run           # print the commands only
    icprl reproduce darkroom_ipref --redraw            # redraw its figures from docs/results, nothing else
    icprl reproduce my_table.yaml --dry-run            # a table of your own: an experiment file anywhere

A table is an experiment file, ``configs/experiment/<table>.yaml`` (``experiments.py`` reads it): runs (a method's
configs and overrides) and the evaluations made of them. Every run is trained once per training seed
(``--seed_everything``) with ``icprl fit`` in its own process, at most ``--jobs`` at a time
(``OMP_NUM_THREADS`` = cores / jobs each), its log in ``<work>/<table>/<run>-seed<s>.log``; then
``icprl evaluate`` deploys each run's last checkpoints (all its training seeds) on the held-out contexts with
the context diagnostics, greedy and sampled, and writes ``docs/results/<table>/<table>[_sampled]`` (``.json``, ``.md``,
``.png``, ``_diagnostics.png``); an online evaluation deploys them asking for comparisons as they act
(``evaluate_online``); an ad evaluation plays AD checkpoints for episodes in a row beside their source learner
(``evaluate_ad``). Training seeds share the dataset (the family's seed fixes it); they differ in
initialization, shuffling and the pairs drawn. A table whose ``runs_from`` names another trains (or finds)
that table's fits in its folder, ``<work>/<other table>/``.

Each fit logs to CSV; the rollout callback's held-out returns per epoch become ``learning_curves`` in
the summary and ``docs/results/<table>/<table>_curve.png``. A finished fit records its checkpoint in
``<run>-seed<s>.json`` with a digest of its inputs (the fit command and the text of its config files);
running the command again skips a fit whose inputs are unchanged, so an interrupted reproduction resumes
where it stopped, and retrains one whose command or configs changed since, or whose recorded checkpoint
file is gone (``--refit`` trains all again). Every record is read before the first fit starts: a damaged
or foreign one (not JSON, or not a record's shape) is one error naming it, never a traceback mid-run.
The command prints, and writes to ``docs/results/<table>/<table>_reproduce.json``, each stage's wall-clock
seconds, the checkpoints and the exact commands.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import yaml

from icprl_lightning.io import write_json_atomic
from icprl_lightning.reproduce.figures import FIGURES, curve_figure
from icprl_lightning.reproduce.fit_logs import final_epoch_means, learning_curve
from icprl_lightning.reproduce.tables import (
    ADEvaluation,
    Evaluation,
    OnlineEvaluation,
    Run,
    Table,
    needed_runs,
    slug,
    stages,
)
from icprl_lightning.untrusted import UntrustedFileError, read_json


class RecordError(ValueError):
    """A fit record (``<run>-seed<s>.json``) that is not one: damaged or foreign; names the file and the way out."""


def read_record(path: Path) -> dict | None:
    """The fit record at ``path`` (None if there is none), checked to be what ``_run_fit`` writes: a JSON object
    whose ``checkpoint`` (and, if present, ``inputs_sha256``) is a string; anything else is a ``RecordError``."""
    if not path.exists():
        return None
    fix = "delete it, or pass --refit to train every run again"
    try:
        record = read_json(path, "fit record")
    except UntrustedFileError as e:
        raise RecordError(f"fit record {path} is damaged ({e}); {fix}") from None
    if not isinstance(record, dict):
        raise RecordError(f"fit record {path} is not an icprl reproduce record (a JSON {type(record).__name__}, "
                          f"not an object with 'checkpoint' and 'inputs_sha256'); {fix}")
    for key, required in (("checkpoint", True), ("inputs_sha256", False)):
        if (required or key in record) and not isinstance(record.get(key), str):
            raise RecordError(f"fit record {path} is not an icprl reproduce record: its {key!r} is "
                              f"{record.get(key)!r}, not a string; {fix}")
    return record


def fit_command(run: Run, seed: int, root: Path, needed: dict[str, str] | None = None) -> list[str]:
    """``icprl fit`` of one run and training seed, logging to CSV in ``<root>/<run>-seed<s>/version_0``;
    ``needed`` maps each run of ``run.needs`` to its checkpoint for this seed."""
    configs = [arg for config in run.configs for arg in ("--config", config)]
    earlier = []
    for flag, names in run.needs:
        paths = [(needed or {})[name] for name in names]
        earlier += [flag, paths[0] if len(names) == 1 else "[" + ",".join(paths) + "]"]
    return ["icprl", "fit", *configs, *run.overrides, *earlier, "--seed_everything", str(seed),
            "--trainer.logger", "lightning.pytorch.loggers.CSVLogger", "--trainer.logger.init_args.save_dir",
            str(root), "--trainer.logger.init_args.name", f"{slug(run.name)}-seed{seed}",
            "--trainer.default_root_dir", str(root)]


def fit_inputs(run: Run, command: list[str], needed_inputs: tuple[str, ...] = ()) -> str:
    """Digest of what a fit's result depends on that this command controls: its arguments, the text of its
    config files and the digests of the earlier stages it needs (the code is the repository's: a table is
    remade from one commit)."""
    digest = hashlib.sha256(shlex.join(command).encode())
    for config in run.configs:
        digest.update(b"\0" + Path(config).read_bytes())
    for inputs in needed_inputs:
        digest.update(b"\0" + inputs.encode())
    return digest.hexdigest()


def saved_config(checkpoints: list[str]) -> Path:
    """The ``config.yaml`` a run's first training seed saved: it names the run's exact dataset (configs, overlays
    and overrides)."""
    return Path(checkpoints[0]).parent.parent / "config.yaml"


def evaluate_command(table: Table, evaluation: Evaluation, checkpoints: dict[str, list[str]], out_dir: Path
                     ) -> list[str]:
    command = ["icprl", "evaluate", "--title", table.title, "--seeds", *map(str, table.eval_seeds),
               *evaluation.flags, "--out", str(out_dir / f"{table.name}{evaluation.suffix}")]
    if table.contexts != ("own",):
        command += ["--contexts", *table.contexts]
    for path in evaluation.data:
        command += ["--data", path]
    for run in (r for r in table.runs if r.evaluated):
        command += ["--run", f"{run.name}={saved_config(checkpoints[run.name])}:{','.join(checkpoints[run.name])}"]
    for baseline in table.baselines:
        command += ["--baseline", baseline]
    return command


def is_ad_run(config: Path) -> bool:
    """Whether a run's saved config trains Algorithm Distillation (an online deployment plays it as the ``ad`` row)."""
    if not config.is_file():
        return False
    model = (yaml.safe_load(config.read_text()) or {}).get("model") or {}
    return isinstance(model, dict) and model.get("class_path") == "icprl_lightning.methods.ad.ADModule"


def evaluate_online(table: Table, evaluation: OnlineEvaluation, checkpoints: dict[str, list[str]], out_dir: Path
                    ) -> dict:
    """Deploy every evaluated run of ``table`` online as ``evaluation`` says (each run's training seeds are its
    ``checkpoints``, its dataset the ``saved_config`` of the first), episode seeds ``table.eval_seeds``, beside
    ``table.baselines``; write ``<out_dir>/<table><suffix>.json`` (and ``.png`` with ``evaluation.figure``) and
    return what it records of the evaluation."""
    from icprl_lightning.evaluation.online_command import evaluate_online as deploy_online

    runs = [r for r in table.runs if r.evaluated]
    if len(runs) != 1:
        raise ValueError(f"{table.name}: an online evaluation deploys one run, the table has "
                         f"{[r.name for r in runs]}")
    (run,) = runs
    baselines = dict(b.split("=", 1) for b in table.baselines)
    unknown = sorted(set(baselines) - {"DQN from scratch"})
    if unknown:
        raise ValueError(f"{table.name}: online evaluations take only the 'DQN from scratch' baseline, got {unknown}")
    out = out_dir / f"{table.name}{evaluation.suffix}"
    config = saved_config(checkpoints[run.name])
    ad = is_ad_run(config)
    policies, ad_checkpoints = (list(evaluation.beside), checkpoints[run.name]) if ad else (checkpoints[run.name], None)
    result = deploy_online([evaluation.data or config], policies, rules=evaluation.rules,
                           labels=evaluation.labels, seeds=table.eval_seeds, episodes=evaluation.episodes,
                           quality=evaluation.quality, rounds=evaluation.rounds, n_problems=evaluation.problems,
                           dqn=baselines.get("DQN from scratch") if evaluation.labels == "own" else None,
                           out=out if evaluation.figure else None, ad_checkpoints=ad_checkpoints)
    if not evaluation.figure:
        write_json_atomic(f"{out}.json", result)
    return {"out": f"{out}.json", "run": run.name}


def evaluate_ad(table: Table, evaluation: ADEvaluation, checkpoints: dict[str, list[str]], out_dir: Path) -> dict:
    """AD's learning curve (``icprl evaluate ad``) of every evaluated run of ``table`` (each run's training seeds
    are its ``checkpoints``, its data the ``saved_config`` of the first), episode seeds ``table.eval_seeds``, for
    ``evaluation.episodes`` episodes beside ``evaluation.against``; writes ``<out_dir>/<table><suffix>`` (``.json``,
    ``.md``, ``.png``) and returns what it records of the evaluation."""
    from icprl_lightning.evaluation.ad_command import ad_markdown
    from icprl_lightning.evaluation.ad_command import evaluate_ad as deploy_ad

    if table.baselines:
        raise ValueError(f"{table.name}: an ad evaluation takes no baselines (its reference is the source learner), "
                         f"got {list(table.baselines)}")
    runs = {r.name: (str(saved_config(checkpoints[r.name])), checkpoints[r.name]) for r in table.runs if r.evaluated}
    out = out_dir / f"{table.name}{evaluation.suffix}"
    print(ad_markdown(deploy_ad(runs, evaluation.episodes, table.eval_seeds, out, table.title,
                                dict(evaluation.against))), end="", flush=True)
    return {"out": f"{out}.json", "runs": list(runs), "episodes": evaluation.episodes}


def _run_fit(command: list[str], inputs: str, log: Path, record: Path, threads: int, which: str = "last") -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "WANDB_MODE": os.environ.get("WANDB_MODE", "disabled")}
    start = time.time()
    with open(log, "w") as out:
        code = subprocess.run([sys.executable, "-m", "icprl_lightning",
                               *command[1:]], stdout=out,
                              stderr=subprocess.STDOUT, env=env).returncode
    if code != 0:
        raise RuntimeError(f"{shlex.join(command)} failed (exit {code}); its log: {log}")
    # "last checkpoint (epoch 0, step 2): PATH" or "best checkpoint (val/loss = 0.5, epoch 3): PATH"
    line = re.compile(rf"^{which} checkpoint(?: \(.*?\))?: (.+)$")
    last = [m.group(1).strip() for m in map(line.match, log.read_text().splitlines()) if m]
    if not last:
        raise RuntimeError(f"{shlex.join(command)} printed no '{which} checkpoint' line; its log: {log}")
    checkpoint = str(Path(last[-1]).absolute())  # the fit ran in this working directory
    result = {"command": shlex.join(command), "inputs_sha256": inputs, "checkpoint": checkpoint,
              "seconds": round(time.time() - start, 1)}
    write_json_atomic(record, result)
    return result


def reproduce(table: Table, seeds: list[int], jobs: int, work: Path, out_dir: Path, refit: bool = False,
              dry_run: bool = False, threads: int | None = None, only: list[str] | None = None) -> dict:
    """Train every run of ``table`` per seed (resuming recorded fits), then evaluate and write the outputs; with
    ``only``, train just those runs and what they need, and stop there (the records serve the full command)."""
    if only:
        table = needed_runs(table, only)
    root = work / (table.runs_from or table.name)
    root.mkdir(parents=True, exist_ok=True)
    threads = threads or max(1, (os.cpu_count() or 1) // jobs)
    done: dict[tuple[str, int], dict] = {}
    run_seeds = {run.name: list(run.seeds or seeds) for run in table.runs}
    for run in table.runs:
        for _, names in run.needs:
            for name in names:
                if not set(run_seeds[run.name]) <= set(run_seeds[name]):
                    raise ValueError(f"{run.name} needs {name} at training seeds {run_seeds[run.name]}, "
                                     f"which has only {run_seeds[name]}")
    # every record read now, before any fit starts: a bad one stops the command here, not between fits
    records = {} if refit else {(run.name, s): read_record(root / f"{slug(run.name)}-seed{s}.json")
                                for run in table.runs for s in run_seeds[run.name]}
    start = time.time()
    order = [run for stage in stages(table.runs) for run in stage]  # every fit after the fits it needs

    def fit(run: Run, seed: int, needed: list[dict | None]) -> dict | None:
        """The fit's record: reused while its inputs are unchanged, else trained (None: dry run, not known)."""
        if None in needed:  # dry run: an earlier stage still to train, so its checkpoint is unknown
            print(f"# {run.name} seed {seed}: after the runs it needs", flush=True)
            return None
        paths = dict(zip((n for _, names in run.needs for n in names), (n["checkpoint"] for n in needed), strict=True))
        record = root / f"{slug(run.name)}-seed{seed}.json"
        command = fit_command(run, seed, root / "runs", paths)
        inputs = fit_inputs(run, command, tuple(n["inputs_sha256"] for n in needed))
        recorded = records.get((run.name, seed))
        if recorded is not None and not Path(recorded["checkpoint"]).is_file():
            print(f"{run.name} seed {seed}: the checkpoint {recorded['checkpoint']} recorded in {record} is gone; "
                  "training it again", flush=True)
        elif recorded is not None and recorded.get("inputs_sha256") == inputs:
            return recorded
        elif recorded is not None:
            print(f"{run.name} seed {seed}: its command, configs or earlier stages changed since {record} was "
                  "written; training it again", flush=True)
        if dry_run:
            print(shlex.join(command), flush=True)
            return None
        print(f"  training {run.name} seed {seed}", flush=True)
        result = _run_fit(command, inputs, root / f"{slug(run.name)}-seed{seed}.log", record, threads, run.checkpoint)
        print(f"  {run.name} seed {seed}: {result['seconds']} s -> {result['checkpoint']}", flush=True)
        return result

    # A worker waits for the fits its run needs: they were submitted before it, so they are running or done
    # (never queued behind it), and a later stage starts as soon as its own seed's earlier stages are done.
    futures: dict[tuple[str, int], Future] = {}
    with ThreadPoolExecutor(max_workers=1 if dry_run else jobs) as pool:
        for run in order:
            for seed in run_seeds[run.name]:
                deps = [futures[(name, seed)] for _, names in run.needs for name in names]

                def task(run: Run = run, seed: int = seed, deps: list[Future] = deps) -> dict | None:
                    return fit(run, seed, [d.result() for d in deps])

                futures[(run.name, seed)] = pool.submit(task)
        for key, future in futures.items():
            result = future.result()
            if result is not None:
                done[key] = result
    if dry_run:
        return {}
    fit_seconds = round(time.time() - start, 1)
    if only:
        print(f"{table.name}: trained {sorted(only)} and what they need in {fit_seconds} s; run the command without "
              "--only to evaluate the whole table", flush=True)
        return {"fits": {f"{n}-seed{s}": r for (n, s), r in sorted(done.items())}, "fit_wall_seconds": fit_seconds}
    checkpoints = {run.name: [done[(run.name, s)]["checkpoint"] for s in run_seeds[run.name]] for run in table.runs}
    evaluations = []
    for evaluation in table.evaluations if any(run.evaluated for run in table.runs) else ():
        began = time.time()
        if isinstance(evaluation, OnlineEvaluation):
            record = {"online": evaluate_online(table, evaluation, checkpoints, out_dir)}
        elif isinstance(evaluation, ADEvaluation):
            record = {"ad": evaluate_ad(table, evaluation, checkpoints, out_dir)}
        else:
            command = evaluate_command(table, evaluation, checkpoints, out_dir)
            # run as recorded, in a process of its own like every fit (and the commands room stays above this one)
            if subprocess.run([sys.executable, "-m", "icprl_lightning", *command[1:]]).returncode != 0:
                raise RuntimeError(f"{shlex.join(command)} failed; its output is above")
            record = {"command": shlex.join(command)}
        evaluations.append({**record, "seconds": round(time.time() - began, 1)})
    if table.figure:
        FIGURES[table.figure](table, out_dir)
    curves = {run.name: {str(s): learning_curve(done[(run.name, s)]["checkpoint"]) for s in run_seeds[run.name]}
              for run in table.runs if run.evaluated}
    curve_figure(table, curves, out_dir / f"{table.name}_curve.png")
    final_metrics = {f"{run.name}-seed{s}": final_epoch_means(done[(run.name, s)]["checkpoint"])
                     for run in table.runs for s in run_seeds[run.name]}
    summary = {"table": table.name, "training_seeds": seeds, "jobs": jobs, "threads_per_fit": threads,
               "fit_wall_seconds": fit_seconds, "final_epoch_train_metrics": final_metrics,
               "fits": {f"{n}-seed{s}": r for (n, s), r in sorted(done.items())}, "evaluations": evaluations,
               "learning_curves": curves, "total_wall_seconds": round(time.time() - start, 1)}
    write_json_atomic(out_dir / f"{table.name}_reproduce.json", summary)
    print(f"{table.name}: fits {fit_seconds} s wall, all {summary['total_wall_seconds']} s "
          f"-> {out_dir / table.name}.md", flush=True)
    return summary


def redraw(table: Table, out_dir: Path) -> list[Path]:
    """Redraw ``table``'s figures from the outputs a full run wrote to ``out_dir`` (each ``icprl evaluate``'s JSON,
    the learning curves in ``<table>_reproduce.json``), without training or evaluating; returns the files read.
    An online evaluation draws its own figure when it runs."""
    from icprl_lightning.evaluation.ad_command import ad_figure
    from icprl_lightning.evaluation.base import evaluation_of
    from icprl_lightning.evaluation.report import write_figures

    offline = [e for e in table.evaluations if isinstance(e, Evaluation)]
    ad = [out_dir / f"{table.name}{e.suffix}.json" for e in table.evaluations if isinstance(e, ADEvaluation)]
    sources = [out_dir / f"{table.name}{e.suffix}.json" for e in offline] + ad + [
        out_dir / f"{table.name}_reproduce.json"]
    missing = [str(p) for p in sources if not p.exists()]
    if missing:
        raise FileNotFoundError(f"--redraw draws from a full run's outputs; missing {', '.join(missing)}: run "
                                f"`icprl reproduce {table.name}` first")
    for source in sources[:-1]:
        payload = json.loads(source.read_text())
        if source in ad:
            ad_figure(payload, source.with_suffix(".png"))
        elif (registered := evaluation_of(payload)) is not None:
            registered.figure(payload, source.with_suffix(".png"))
        else:
            write_figures(payload, source.with_suffix(""))
    if table.figure:
        FIGURES[table.figure](table, out_dir)
    curve_figure(table, json.loads(sources[-1].read_text())["learning_curves"], out_dir / f"{table.name}_curve.png")
    return sources
