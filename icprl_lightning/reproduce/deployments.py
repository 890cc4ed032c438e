"""How each kind of a table's evaluation deploys its runs, written once for ``tables.py``'s evaluation classes
(``Evaluation.deploy``, ``OnlineEvaluation.deploy``, ``ADEvaluation.deploy``): ``icprl evaluate`` of every evaluated
run, in a process of its own as recorded; an online deployment (``icprl evaluate online``); AD's learning curve
(``icprl evaluate ad``). Each returns what the table's ``_reproduce.json`` records of it. The runner calls
``evaluation.deploy(...)`` whatever the kind, so a kind is one class, not a branch of the runner.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from icprl_lightning.io import write_json_atomic


def saved_config(checkpoints: list[str]) -> Path:
    """The ``config.yaml`` a run's first training seed saved: it names the run's exact dataset (configs, overlays
    and overrides)."""
    return Path(checkpoints[0]).parent.parent / "config.yaml"


def is_ad_run(config: Path) -> bool:
    """Whether a run's saved config trains Algorithm Distillation (an online deployment plays it as the ``ad`` row)."""
    if not config.is_file():
        return False
    model = (yaml.safe_load(config.read_text()) or {}).get("model") or {}
    return isinstance(model, dict) and model.get("class_path") == "icprl_lightning.methods.ad.ADModule"


def evaluate_command(table: Any, evaluation: Any, checkpoints: dict[str, list[str]], out_dir: Path) -> list[str]:
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


def deploy_offline(table: Any, evaluation: Any, checkpoints: dict[str, list[str]], out_dir: Path) -> dict:
    """``icprl evaluate`` of every evaluated run, run as recorded in a process of its own like every fit (and the
    commands room stays above the library); what the table records of it: the command."""
    command = evaluate_command(table, evaluation, checkpoints, out_dir)
    if subprocess.run([sys.executable, "-m", "icprl_lightning", *command[1:]]).returncode != 0:
        raise RuntimeError(f"{shlex.join(command)} failed; its output is above")
    return {"command": shlex.join(command)}


def deploy_online(table: Any, evaluation: Any, checkpoints: dict[str, list[str]], out_dir: Path) -> dict:
    """Deploy every evaluated run of ``table`` online as ``evaluation`` says (each run's training seeds are its
    ``checkpoints``, its dataset the ``saved_config`` of the first), episode seeds ``table.eval_seeds``, beside
    ``table.baselines``; write ``<out_dir>/<table><suffix>.json`` (and ``.png`` with ``evaluation.figure``) and
    return what it records of the evaluation."""
    from icprl_lightning.evaluation.online_command import evaluate_online

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
    result = evaluate_online([evaluation.data or config], policies, rules=evaluation.rules,
                           labels=evaluation.labels, seeds=table.eval_seeds, episodes=evaluation.episodes,
                           quality=evaluation.quality, rounds=evaluation.rounds, n_problems=evaluation.problems,
                           dqn=baselines.get("DQN from scratch") if evaluation.labels == "own" else None,
                           out=out if evaluation.figure else None, ad_checkpoints=ad_checkpoints)
    if not evaluation.figure:
        write_json_atomic(f"{out}.json", result)
    return {"out": f"{out}.json", "run": run.name}


def deploy_ad(table: Any, evaluation: Any, checkpoints: dict[str, list[str]], out_dir: Path) -> dict:
    """AD's learning curve (``icprl evaluate ad``) of every evaluated run of ``table`` (each run's training seeds
    are its ``checkpoints``, its data the ``saved_config`` of the first), episode seeds ``table.eval_seeds``, for
    ``evaluation.episodes`` episodes beside ``evaluation.against``; writes ``<out_dir>/<table><suffix>`` (``.json``,
    ``.md``, ``.png``) and returns what it records of the evaluation."""
    from icprl_lightning.evaluation.ad_command import ad_markdown, evaluate_ad

    if table.baselines:
        raise ValueError(f"{table.name}: an ad evaluation takes no baselines (its reference is the source learner), "
                         f"got {list(table.baselines)}")
    runs = {r.name: (str(saved_config(checkpoints[r.name])), checkpoints[r.name]) for r in table.runs if r.evaluated}
    out = out_dir / f"{table.name}{evaluation.suffix}"
    print(ad_markdown(evaluate_ad(runs, evaluation.episodes, table.eval_seeds, out, table.title,
                                dict(evaluation.against))), end="", flush=True)
    return {"out": f"{out}.json", "runs": list(runs), "episodes": evaluation.episodes}


def redraw(source: Path) -> None:
    """The figures of a results JSON, drawn by the evaluation it is the results of (``evaluation_of``)."""
    from icprl_lightning.evaluation.base import evaluation_of

    payload = json.loads(source.read_text())
    kind = evaluation_of(payload)
    if kind is None:
        raise ValueError(f"{source} is the results of no registered evaluation: nothing to redraw")
    kind.figure(payload, source.with_suffix(".png"))
