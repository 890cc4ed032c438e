"""``icprl reproduce TABLE``: regenerate a results table and its figure from scratch.

    icprl reproduce --list
    icprl reproduce darkroom_ipref                     # 3 training seeds per method, then evaluation
    icprl reproduce darkroom_ipref --seeds 0 --jobs 1  # a quicker, one-seed version
    icprl reproduce darkroom_ipref --dry-run           # print the commands only
    icprl reproduce darkroom_ipref --redraw            # redraw its figures from docs/results, nothing else
    icprl reproduce my_table.yaml --dry-run            # a table of your own: an experiment file anywhere

A table is an experiment file, ``configs/experiment/<table>.yaml`` (``experiments.py``): runs and the evaluations
made of them. Every run is trained once per training seed (``--seed_everything``: same dataset, different
initialization, shuffling and pairs) by ``icprl fit`` in its own process, at most ``--jobs`` at a time
(``OMP_NUM_THREADS`` = cores / jobs), logged to ``<work>/<table>/<run>-seed<s>.log``. Then ``icprl evaluate``
deploys each run's last checkpoints on the held-out contexts with the context diagnostics, greedy and sampled,
writing ``docs/results/<table>/<table>[_sampled]`` (``.json``, ``.md``, ``.png``, ``_diagnostics.png``); an online
evaluation asks for comparisons as it acts (``evaluate_online``); an ad one plays AD for episodes in a row beside
its source learner (``evaluate_ad``). A ``runs_from`` table finds its fits in ``<work>/<other table>/``. The
rollout callback's held-out returns per epoch become ``learning_curves`` and ``<table>_curve.png``.

A finished fit is recorded in ``<run>-seed<s>.json`` with a digest of its inputs (the fit command and the text of
its config files): running again skips a fit whose inputs are unchanged and whose checkpoint exists, so an
interrupted reproduction resumes where it stopped (``--refit`` trains all again). Every record is read before the
first fit: a damaged or foreign one is one error naming it, never a traceback mid-run. SIGTERM or SIGINT stops the
running fits (each saves ``last.ckpt``), records them as interrupted and exits 128 + the signal; the same command
resumes them (``children.py``); a second ``icprl reproduce`` in the same folder is refused. Each stage's
wall-clock seconds, the checkpoints and the exact commands are printed and written to
``docs/results/<table>/<table>_reproduce.json``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shlex
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from icprl_lightning.io import write_json_atomic
from icprl_lightning.reproduce.children import Children, Interrupted, run_fit, work_lock
from icprl_lightning.reproduce.figures import FIGURES, curve_figure
from icprl_lightning.reproduce.fit_logs import final_epoch_means, learning_curve
from icprl_lightning.reproduce.tables import (
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
    """The fit record at ``path`` (None if there is none), checked to be what ``children.run_fit`` writes: a JSON object
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
        resume = recorded is not None and recorded.get("status") == "interrupted"
        if resume and recorded.get("inputs_sha256") == inputs and Path(recorded["checkpoint"]).is_file():
            print(f"{run.name} seed {seed}: resuming the interrupted fit from {recorded['checkpoint']}", flush=True)
            command = [*command, "--ckpt_path", recorded["checkpoint"]]  # its inputs stay those of the fit
        elif resume:
            print(f"{run.name} seed {seed}: interrupted before a checkpoint of these inputs; training it again",
                  flush=True)
        elif recorded is not None and not Path(recorded["checkpoint"]).is_file():
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
        result = run_fit(command, inputs, root / f"{slug(run.name)}-seed{seed}.log", record, threads, run.checkpoint,
                          children)
        print(f"  {run.name} seed {seed}: {result['seconds']} s -> {result['checkpoint']}", flush=True)
        return result

    # A worker waits for the fits its run needs: they were submitted before it, so they are running or done
    # (never queued behind it), and a later stage starts as soon as its own seed's earlier stages are done.
    futures: dict[tuple[str, int], Future] = {}
    children = Children()
    pool = ThreadPoolExecutor(max_workers=1 if dry_run else jobs)
    try:
        with contextlib.nullcontext() if dry_run else work_lock(root), children.forwarding():
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
    except Interrupted:
        children.wait()  # the fits were sent the signal: each saves, exits and is recorded as interrupted
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
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
        record = evaluation.deploy(table, checkpoints, out_dir)
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
    """Redraw ``table``'s figures from the outputs a full run wrote to ``out_dir`` (each evaluation's JSON, the
    learning curves in ``<table>_reproduce.json``), without training or evaluating; returns the files read.
    An online evaluation draws its own figure when it runs."""
    summary = out_dir / f"{table.name}_reproduce.json"
    drawn = [(e, e.output(table, out_dir)) for e in table.evaluations if e.output(table, out_dir) is not None]
    sources = [source for _, source in drawn] + [summary]
    missing = [str(p) for p in sources if not p.exists()]
    if missing:
        raise FileNotFoundError(f"--redraw draws from a full run's outputs; missing {', '.join(missing)}: run "
                                f"`icprl reproduce {table.name}` first")
    for evaluation, source in drawn:
        evaluation.redraw(source)
    if table.figure:
        FIGURES[table.figure](table, out_dir)
    curve_figure(table, json.loads(summary.read_text())["learning_curves"], out_dir / f"{table.name}_curve.png")
    return sources
