"""A table of ``icprl reproduce``: runs (a method's configs and overrides, each trained once per training seed)
and the evaluations made of them, ``icprl evaluate`` of every evaluated run, an online deployment or AD's learning
curve; ``experiments.py`` fills it from its experiment file, ``configs/experiment/<table>.yaml``."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

from icprl_lightning.reproduce import deployments

ALL_CONTEXTS = ("own", "random_labels", "flipped_labels", "other_task")


def slug(name: str) -> str:
    """A run name as a file name (no spaces, commas or '=', which ``--run`` and paths would misread)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")


@dataclass(frozen=True)
class Run:
    """One method of a table: its configs (stacked, as repeated ``--config``) and command-line overrides. A later
    pipeline stage (ICRG after RewardGen) names its earlier ones in ``needs``: each ``(flag, runs)`` passes the
    same training seed's checkpoints of ``runs`` as ``flag`` (a list when several); it is trained after them, and
    again whenever one of them is."""

    name: str  # a table row; no '=' or ',' (``icprl evaluate --run NAME=CONFIG:CKPT,CKPT``)
    configs: tuple[str, ...]
    overrides: tuple[str, ...] = ()  # flag, value, flag, value, ...
    seeds: tuple[int, ...] | None = None  # this run's training seeds, whatever the command's ``--seeds``
    needs: tuple[tuple[str, tuple[str, ...]], ...] = ()
    evaluated: bool = True  # False: an earlier stage that is no policy (RewardGen): trained, not deployed
    checkpoint: str = "last"  # the checkpoint the record keeps: "last", or "best" (the fit's monitored best)

    def setting(self, key: str) -> str | None:
        """The value the overrides give the dotted ``key`` (the last one, as on a command line), or None."""
        values = [v for flag, v in zip(self.overrides[::2], self.overrides[1::2], strict=False) if flag == f"--{key}"]
        return values[-1] if values else None


@dataclass(frozen=True)
class Evaluation:
    """One ``icprl evaluate`` of a table's runs: output suffix, its flags (``--greedy``, ``--sample``) and the data
    files stacked on every run's config (``--data``: other held-out tasks, e.g.)."""

    suffix: str
    flags: tuple[str, ...]
    data: tuple[str, ...] = ()
    online: ClassVar[bool] = False  # deployed from an empty context, asking as it acts
    takes_baselines: ClassVar[bool] = True

    def deploy(self, table: Table, checkpoints: dict[str, list[str]], out_dir: Path) -> dict[str, Any]:
        """Run it on the table's trained runs (``checkpoints``: each run's training seeds); what the table's
        ``_reproduce.json`` records of it."""
        return deployments.deploy_offline(table, self, checkpoints, out_dir)

    def output(self, table: Table, out_dir: Path) -> Path | None:
        """The JSON it writes, which ``redraw`` draws its figures from (None: it draws its own when it runs)."""
        return out_dir / f"{table.name}{self.suffix}.json"

    def redraw(self, source: Path) -> None:
        deployments.redraw(source)


@dataclass(frozen=True)
class OnlineEvaluation:
    """One online deployment of a table's runs (``icprl evaluate online``), written to ``<table><suffix>``: from an
    empty context, ``episodes`` of an MDP family at ``quality``'s held-out tasks or ``rounds`` duels on the first
    ``problems`` bandit problems, each pair by a rule of ``rules``, answers per ``labels``; ``None``: the default.
    An AD run on duels plays as the ``ad`` row: ``data`` names the config of the bandit data it is deployed on
    (its own are learning histories), ``beside`` the ICPO checkpoints (or shipped model names) asked beside it."""

    suffix: str
    rules: tuple[str, ...] = ("action_uniform",)
    labels: str = "own"
    episodes: int | None = None
    rounds: int | None = None
    quality: str | None = None
    problems: int | None = None
    figure: bool = False
    data: str | None = None
    beside: tuple[str, ...] = ()
    online: ClassVar[bool] = True
    takes_baselines: ClassVar[bool] = True  # only "DQN from scratch", drawn beside the curve

    def deploy(self, table: Table, checkpoints: dict[str, list[str]], out_dir: Path) -> dict[str, Any]:
        return {"online": deployments.deploy_online(table, self, checkpoints, out_dir)}

    def output(self, table: Table, out_dir: Path) -> Path | None:
        return None

    def redraw(self, source: Path) -> None:
        raise NotImplementedError("an online evaluation draws its figure when it runs")


@dataclass(frozen=True)
class ADEvaluation:
    """Algorithm Distillation's in-context learning curve, written to ``<table><suffix>``: every evaluated run (AD
    checkpoints, learning-history configs) deployed for ``episodes`` consecutive episodes on the family's held-out
    goals, its history kept across them, beside the source learner from scratch and the optimum
    (``evaluation.ad_command``); ``against`` holds (name, JSON) pairs of ``icprl evaluate online`` results drawn
    beside it."""

    suffix: str
    episodes: int = 20
    against: tuple[tuple[str, str], ...] = ()
    online: ClassVar[bool] = False
    takes_baselines: ClassVar[bool] = False  # its reference is the source learner

    def deploy(self, table: Table, checkpoints: dict[str, list[str]], out_dir: Path) -> dict[str, Any]:
        return {"ad": deployments.deploy_ad(table, self, checkpoints, out_dir)}

    def output(self, table: Table, out_dir: Path) -> Path | None:
        return out_dir / f"{table.name}{self.suffix}.json"

    def redraw(self, source: Path) -> None:
        deployments.redraw(source)


@dataclass(frozen=True)
class Table:
    name: str
    title: str
    runs: tuple[Run, ...]
    evaluations: tuple[Evaluation | OnlineEvaluation | ADEvaluation, ...] = (
        Evaluation("", ("--greedy",)), Evaluation("_sampled", ("--sample",)))
    contexts: tuple[str, ...] = ALL_CONTEXTS
    eval_seeds: tuple[int, ...] = (0, 1)
    baselines: tuple[str, ...] = ()  # NAME=JSON of ``icprl evaluate --baseline``
    budget: str = ""  # what one run costs here, for --list
    figure: str = ""  # a table-specific figure made from the evaluations (``FIGURES``)
    ceiling: str = ""  # ``icprl analyze label-ceiling``'s JSON for the runs' data, drawn on the learning curves
    runs_from: str = ""  # the table whose runs (and fit records) these are; "" for its own


def stages(runs: tuple[Run, ...]) -> list[list[Run]]:
    """The runs in the order they can be trained: each stage only needs runs of earlier stages."""
    names = {run.name for run in runs}
    order, placed = [], set()
    while len(placed) < len(runs):
        ready = [r for r in runs if r.name not in placed and all(n in placed for _, ns in r.needs for n in ns)]
        if not ready:
            missing = {n for r in runs for _, ns in r.needs for n in ns} - names
            raise ValueError(f"runs need {sorted(missing)}, which the table lacks" if missing else
                             "the runs' needs form a cycle")
        order.append(ready)
        placed.update(r.name for r in ready)
    return order


def needed_runs(table: Table, only: list[str]) -> Table:
    """``table`` cut to the runs named in ``only`` and the earlier stages they need."""
    by_name = {run.name: run for run in table.runs}
    unknown = sorted(set(only) - set(by_name))
    if unknown:
        raise ValueError(f"--only {unknown}: no such run in {table.name}; its runs: {list(by_name)}")
    keep, todo = set(), list(only)
    while todo:
        name = todo.pop()
        if name not in keep:
            keep.add(name)
            todo += [n for _, names in by_name[name].needs for n in names]
    return replace(table, runs=tuple(run for run in table.runs if run.name in keep))
