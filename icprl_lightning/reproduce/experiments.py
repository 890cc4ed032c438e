"""The experiment files of ``icprl reproduce``, one per table (``configs/experiment/<name>.yaml``), read into a
``Table``.

A table is runs (a method's configs and overrides, each trained once per training seed) and the evaluations made of
them. Its file says what ``Table`` holds; only ``title`` and ``runs`` are required::

    title: DarkRoom I-PRL, the paper's recipe        # the heading of its outputs
    budget: ≈ 2 min per fit on 1 core                # what one fit costs, for --list
    runs:
      - name: ICPO beta1 lam0.5                      # a row; no '=' or ','
        configs: [configs/icpo_darkroom.yaml]        # stacked as repeated --config
        overrides: {model.init_args.beta: 1.0}       # passed as --model.init_args.beta 1.0
        seeds: [0]                                   # its own training seeds, whatever --seeds says
        needs: {model.init_args.reward_gen_checkpoint: RewardGen}  # an earlier stage's checkpoint, same seed
        evaluated: false                             # an earlier stage that is no policy: trained, not deployed
        checkpoint: best                             # the checkpoint its record keeps (default last)
    evaluations: [{suffix: "", act: greedy}, {suffix: _sampled, act: sample}]   # the default
                                                   # (data: [FILE]: icprl evaluate --data FILE, other held-out tasks)
    contexts: [own, random_labels, flipped_labels, other_task]                  # the default
    eval_seeds: [0, 1]                                                          # the default
    baselines: {DQN from scratch: docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json}
    figure: lambda_beta                              # a table-specific figure (figures.FIGURES)
    ceiling: docs/results/darkroom_label_ceiling/darkroom_label_ceiling_uniform.json  # drawn on the learning curves

``overrides`` is a mapping of dotted keys or a list of them, passed in order as on a command line (a later value
of a key wins); a list item may instead name a values-only overlay file, whose values are passed the same way, so
a run's command shows every value it sets and the files in ``configs`` are its only stacked ones. A value is
passed as YAML writes it (``true``, ``[0, 1]``). ``groups`` holds named override mappings that runs reuse
through YAML anchors (``&name`` there, ``*name`` in a run); it is read for nothing else.

An evaluation is ``icprl evaluate`` of every evaluated run (``act: greedy`` or ``sample``; none: the checkpoint's
default), or online (``online: {rounds | episodes, rules, labels, ...}``: ``OnlineEvaluation``), or AD's learning
curve (``ad: {episodes: 20, against: {NAME: JSON}}``: ``ADEvaluation``, ``icprl evaluate ad``). A table whose
``runs_from`` names another deploys that table's runs, listed by name in ``runs``: their fits and records are
the other table's, so each is trained once for both.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import fields
from pathlib import Path
from typing import Any, NoReturn

from icprl_lightning.reproduce.tables import (
    ADEvaluation,
    Evaluation,
    OnlineEvaluation,
    Run,
    Table,
    needed_runs,
    stages,
)
from icprl_lightning.untrusted import UntrustedFileError, read_yaml

EXPERIMENTS = Path("configs/experiment")  # relative to the working directory, as every config path of a table
ACTS = {"greedy": ("--greedy",), "sample": ("--sample",)}
ONLINE_LABELS = ("own", "flipped", "random")
DOTTED = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


class TableError(ValueError):
    """An experiment file that does not describe a table; the message names the file and the field."""


def table_names(folder: Path = EXPERIMENTS) -> list[str]:
    """The tables of ``folder``: the names of its ``.yaml`` files."""
    return sorted(p.stem for p in folder.glob("*.yaml"))


def load_tables(folder: Path = EXPERIMENTS) -> dict[str, Table]:
    """Every table of ``folder``, by name."""
    if not table_names(folder):
        raise TableError(_no_tables(folder))
    return {name: load_table(name, folder) for name in table_names(folder)}


def _no_tables(folder: Path) -> str:
    return (f"no experiment files in {folder}/ (from {Path.cwd()}): run icprl reproduce from the repository root, "
            "or name a table's YAML file")


def load_table(source: str | Path, folder: Path = EXPERIMENTS) -> Table:
    """The table named ``source`` in ``folder``, or the one of the experiment file at path ``source``
    (``*.yaml``); every config and overlay it names must exist (paths relative to the working directory)."""
    path = Path(source) if str(source).endswith((".yaml", ".yml")) else folder / f"{source}.yaml"
    if not path.exists():
        if path.suffix and Path(source).suffix:
            raise TableError(f"{path}: no such experiment file")
        names = table_names(folder)
        if not names:
            raise TableError(_no_tables(folder))
        close = difflib.get_close_matches(str(source), names, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise TableError(f"no table {source!r} in {folder}/; {hint}its tables: {', '.join(names)}")
    try:
        data = read_yaml(path, "experiment file")
    except UntrustedFileError as e:
        raise TableError(str(e)) from None
    return _Reader(path, folder).table(data)


class _Reader:
    """Fills a ``Table`` from one experiment file's YAML; each problem is a ``TableError`` naming file and field."""

    def __init__(self, path: Path, folder: Path) -> None:
        self.path, self.folder = path, folder

    def fail(self, where: str, problem: str) -> NoReturn:
        raise TableError(f"{self.path}: {where}: {problem}")

    def keys(self, where: str, value: Any, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            self.fail(where or "the file", f"must be a mapping, got {type(value).__name__}")
        for key in value:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), allowed, n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                self.fail(f"{where}.{key}" if where else str(key), f"unknown key; {hint}the keys: {', '.join(allowed)}")
        for key in required:
            if key not in value:
                self.fail(f"{where}.{key}" if where else key, "missing")
        return value

    def text(self, where: str, value: Any) -> str:
        if not isinstance(value, str):
            self.fail(where, f"must be text, got {value!r}")
        return value

    def texts(self, where: str, value: Any) -> tuple[str, ...]:
        if not isinstance(value, list):
            self.fail(where, f"must be a list, got {value!r}")
        return tuple(self.text(f"{where}[{i}]", v) for i, v in enumerate(value))

    def ints(self, where: str, value: Any) -> tuple[int, ...]:
        if not isinstance(value, list) or not value or not all(type(v) is int and v >= 0 for v in value):
            self.fail(where, f"must be a non-empty list of integers ≥ 0, got {value!r}")
        return tuple(value)

    def flag(self, where: str, value: Any) -> bool:
        if not isinstance(value, bool):
            self.fail(where, f"must be true or false, got {value!r}")
        return value

    def file(self, where: str, value: Any) -> str:
        if not Path(self.text(where, value)).is_file():
            self.fail(where, f"{value} does not exist (paths are relative to the working directory: run from the "
                             "repository root)")
        return value

    def model(self, where: str, value: Any) -> str:
        """A checkpoint file or the name of a shipped model (``hub.shipped_models``)."""
        from icprl_lightning.hub import shipped_models

        if not (Path(self.text(where, value)).exists() or value in shipped_models()):
            self.fail(where, f"{value} is neither a checkpoint (paths are relative to the working directory) nor a "
                             f"shipped model ({', '.join(sorted(shipped_models()))})")
        return value

    def choice(self, where: str, value: Any, allowed: tuple[str, ...]) -> str:
        if value not in allowed:
            self.fail(where, f"must be one of {', '.join(allowed)}, got {value!r}")
        return value

    # ---- the table ------------------------------------------------------------------------------------------------

    def table(self, data: Any) -> Table:
        allowed = tuple(f.name for f in fields(Table) if f.name != "name") + ("groups",)
        data = self.keys("", data, allowed, ("title", "runs"))
        if "groups" in data:
            self.keys("groups", data["groups"], tuple(data["groups"] or ()))
        values: dict[str, Any] = {"name": self.path.stem, "title": self.text("title", data["title"])}
        if "runs_from" in data:
            values["runs_from"] = self.text("runs_from", data["runs_from"])
            values["runs"] = self.runs_of(values["runs_from"], self.texts("runs", data["runs"]))
        else:
            if not isinstance(data["runs"], list) or not data["runs"]:
                self.fail("runs", "must be a non-empty list of runs")
            values["runs"] = tuple(self.run(f"runs[{i}]", r) for i, r in enumerate(data["runs"]))
            self.check_names(values["runs"])
        if "evaluations" in data:
            items = data["evaluations"]
            if not isinstance(items, list) or not items:
                self.fail("evaluations", "must be a non-empty list")
            values["evaluations"] = tuple(self.evaluation(f"evaluations[{i}]", e) for i, e in enumerate(items))
            suffixes = [e.suffix for e in values["evaluations"]]
            if len(set(suffixes)) < len(suffixes):
                self.fail("evaluations", f"two write the same outputs (suffixes {suffixes})")
        if "contexts" in data:
            from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS

            known = ("own", *DIAGNOSTICS)
            values["contexts"] = tuple(self.choice(f"contexts[{i}]", c, known)
                                       for i, c in enumerate(self.texts("contexts", data["contexts"])))
        if "eval_seeds" in data:
            values["eval_seeds"] = self.ints("eval_seeds", data["eval_seeds"])
        if "baselines" in data:
            baselines = self.keys("baselines", data["baselines"], tuple(data["baselines"] or ()))
            values["baselines"] = tuple(f"{self.text('baselines', name)}={self.file(f'baselines.{name}', json)}"
                                        for name, json in baselines.items())
        for key in ("budget", "figure"):
            if key in data:
                values[key] = self.text(key, data[key])
        if values.get("baselines") and any(isinstance(e, ADEvaluation) for e in values.get("evaluations", ())):
            self.fail("baselines", "an ad evaluation takes none: its references are the source learner and the "
                                   "optimum (draw an online result beside it with ad.against)")
        if values.get("figure"):
            from icprl_lightning.reproduce.figures import FIGURES

            self.choice("figure", values["figure"], tuple(FIGURES))
        if "ceiling" in data:
            from icprl_lightning.reproduce.figures import read_ceiling

            values["ceiling"] = self.file("ceiling", data["ceiling"])
            try:
                read_ceiling(values["ceiling"])
            except ValueError as e:
                self.fail("ceiling", str(e))
        return Table(**values)

    def runs_of(self, source: str, names: tuple[str, ...]) -> tuple[Run, ...]:
        """The runs ``names`` of table ``source`` (this file's folder first, then the experiments folder) and the
        earlier stages they need."""
        path = next((p for p in (self.path.parent / f"{source}.yaml", self.folder / f"{source}.yaml")
                     if p.is_file()), None)
        if path is None:
            self.fail("runs_from", f"no table {source!r} in {self.path.parent}/ or {self.folder}/")
        other = load_table(path)
        if other.runs_from:
            self.fail("runs_from", f"{source} deploys the runs of {other.runs_from}: name that table instead")
        try:
            return needed_runs(other, list(names)).runs
        except ValueError as e:
            self.fail("runs", str(e).removeprefix("--only "))

    def run(self, where: str, data: Any) -> Run:
        allowed = tuple(f.name for f in fields(Run))
        data = self.keys(where, data, allowed, ("name", "configs"))
        name = self.text(f"{where}.name", data["name"])
        if "=" in name or "," in name or not name.strip():
            self.fail(f"{where}.name", f"{name!r}: a run's name has no '=' or ',' (icprl evaluate --run NAME=...)")
        where = f"{where} ({name})"
        configs = self.texts(f"{where}.configs", data["configs"])
        if not configs:
            self.fail(f"{where}.configs", "names no config")
        for i, config in enumerate(configs):
            self.file(f"{where}.configs[{i}]", config)
        values: dict[str, Any] = {"name": name, "configs": configs}
        if "overrides" in data:
            values["overrides"] = self.overrides(f"{where}.overrides", data["overrides"])
        if "seeds" in data:
            values["seeds"] = self.ints(f"{where}.seeds", data["seeds"])
        if "needs" in data:
            needs = self.keys(f"{where}.needs", data["needs"], tuple(data["needs"] or ()))
            values["needs"] = tuple((self.dotted(f"{where}.needs", key),
                                     (self.text(f"{where}.needs.{key}", runs),) if not isinstance(runs, list) else
                                     self.texts(f"{where}.needs.{key}", runs)) for key, runs in needs.items())
        if "evaluated" in data:
            values["evaluated"] = self.flag(f"{where}.evaluated", data["evaluated"])
        if "checkpoint" in data:
            values["checkpoint"] = self.choice(f"{where}.checkpoint", data["checkpoint"], ("last", "best"))
        return Run(**values)

    def check_names(self, runs: tuple[Run, ...]) -> None:
        names = [run.name for run in runs]
        for i, run in enumerate(runs):
            if names.index(run.name) != i:
                self.fail(f"runs[{i}].name", f"{run.name!r} names two runs")
            for flag, needed in run.needs:
                for n in needed:
                    if n not in names or n == run.name:
                        self.fail(f"runs[{i}] ({run.name}).needs.{flag[2:]}",
                                  f"{n!r} is {'the run itself' if n == run.name else 'no run of this table'}; "
                                  f"its runs: {', '.join(names)}")
        try:
            stages(runs)
        except ValueError as e:
            self.fail("runs", str(e))

    # ---- overrides ------------------------------------------------------------------------------------------------

    def dotted(self, where: str, key: Any) -> str:
        """``--key`` for a dotted key (``model.init_args.beta``)."""
        if not isinstance(key, str) or not DOTTED.fullmatch(key):
            self.fail(where, f"{key!r} is not a dotted key such as model.init_args.beta (no leading --)")
        return f"--{key}"

    def overrides(self, where: str, data: Any) -> tuple[str, ...]:
        items = data if isinstance(data, list) else [data]
        flags: list[str] = []
        for i, item in enumerate(items):
            at = f"{where}[{i}]" if isinstance(data, list) else where
            if isinstance(item, str):
                flags += self.overlay_flags(at, self.file(at, item))
            elif isinstance(item, dict):
                for key, value in item.items():
                    flags += [self.dotted(at, key), self.value(f"{at}.{key}", value)]
            else:
                self.fail(at, f"must be a mapping of dotted keys or an overlay file, got {item!r}")
        return tuple(flags)

    def overlay_flags(self, where: str, overlay: str) -> list[str]:
        """The flags of a values-only overlay: one per leaf, its dotted path, in the file's order."""
        try:
            data = read_yaml(overlay, "config overlay")
        except UntrustedFileError as e:
            self.fail(where, str(e))
        flags: list[str] = []

        def walk(node: Any, keys: tuple[str, ...]) -> None:
            if isinstance(node, dict) and node:
                for key, value in node.items():
                    if key == "class_path":
                        self.fail(where, f"{overlay} sets {'.'.join((*keys, key))}: an overlay that picks a class "
                                         "goes in the run's configs (overrides pass values only)")
                    walk(value, (*keys, str(key)))
            elif not keys:
                self.fail(where, f"{overlay} holds no mapping of values")
            else:
                flags.extend((self.dotted(where, ".".join(keys)), self.value(f"{where}: {overlay}", node)))

        walk(data, ())
        return flags

    def value(self, where: str, value: Any) -> str:
        """A value as the command line takes it: YAML's spelling of booleans, null and lists of scalars."""
        if isinstance(value, bool):
            return "true" if value else "false"
        if value is None:
            return "null"
        if isinstance(value, list):
            return "[" + ", ".join(self.value(where, v) for v in value) + "]"
        if isinstance(value, dict):
            self.fail(where, f"{value!r} is a mapping: write each of its keys dotted")
        return str(value)

    # ---- evaluations ----------------------------------------------------------------------------------------------

    def evaluation(self, where: str, data: Any) -> Evaluation | OnlineEvaluation | ADEvaluation:
        data = self.keys(where, data, ("suffix", "act", "data", "online", "ad", "evaluation", "options"), ("suffix",))
        suffix = self.text(f"{where}.suffix", data["suffix"])
        if "ad" in data:
            return self.ad_evaluation(where, suffix, data)
        if "online" not in data:
            act = self.choice(f"{where}.act", data["act"], tuple(ACTS)) if "act" in data else None
            files = tuple(self.file(f"{where}.data[{i}]", f) for i, f in enumerate(self.texts(f"{where}.data",
                                                                                              data.get("data", []))))
            return Evaluation(suffix, (ACTS[act] if act else ()) + self.registered(where, data), files)
        if "data" in data:
            self.fail(f"{where}.data", "an online evaluation deploys on the runs' own data")
        if "act" in data:
            self.fail(f"{where}.act", "an online evaluation acts as the checkpoint's default")
        allowed = tuple(f.name for f in fields(OnlineEvaluation) if f.name != "suffix")
        online = self.keys(f"{where}.online", data["online"] or {}, allowed)
        values: dict[str, Any] = {"suffix": suffix}
        for key, value in online.items():
            at = f"{where}.online.{key}"
            if key == "rules":
                from icprl_lightning.online import PAIR_RULES

                values[key] = tuple(self.choice(f"{at}[{i}]", r, tuple(PAIR_RULES))
                                    for i, r in enumerate(self.texts(at, value)))
            elif key == "labels":
                values[key] = self.choice(at, value, ONLINE_LABELS)
            elif key == "quality":
                values[key] = self.text(at, value)
            elif key == "figure":
                values[key] = self.flag(at, value)
            elif key == "data":
                values[key] = self.file(at, value)
            elif key == "beside":
                values[key] = tuple(self.model(f"{at}[{i}]", c) for i, c in enumerate(self.texts(at, value)))
            elif type(value) is int and value >= 1:  # episodes, rounds, problems
                values[key] = value
            else:
                self.fail(at, f"must be an integer ≥ 1, got {value!r}")
        if "episodes" in values and "rounds" in values:
            self.fail(f"{where}.online", "episodes (an MDP family) or rounds (a bandit), not both")
        return OnlineEvaluation(**values)

    def registered(self, where: str, data: dict) -> tuple[str, ...]:
        """``evaluation: NAME`` (a registered evaluation, ``evaluation/base.py``) and its ``options`` as the flags of
        ``icprl evaluate``; none without ``evaluation``."""
        if "evaluation" not in data:
            if "options" in data:
                self.fail(f"{where}.options", "options are an evaluation's: name it with evaluation: NAME")
            return ()
        import yaml

        from icprl_lightning.registry import EVALUATIONS

        name = self.text(f"{where}.evaluation", data["evaluation"])
        if name not in EVALUATIONS.names():
            self.fail(f"{where}.evaluation", f"{name!r} is not a registered evaluation ({EVALUATIONS.short_names()})")
        options = data.get("options") or {}
        if not isinstance(options, dict):
            self.fail(f"{where}.options", f"must be a mapping of keyword: value, got {options!r}")
        flags = ("--evaluation", name)
        for key, value in options.items():  # a value as YAML writes it inline: the command reads it back as YAML
            text = yaml.safe_dump(value, default_flow_style=True).removesuffix("...\n").strip()
            flags += ("--option", f"{key}={text}")
        return flags

    def ad_evaluation(self, where: str, suffix: str, data: dict) -> ADEvaluation:
        for key in ("act", "data", "online"):
            if key in data:
                self.fail(f"{where}.{key}", "an ad evaluation deploys AD with its default actions on its family's "
                                            "held-out goals; it takes only suffix and ad")
        allowed = tuple(f.name for f in fields(ADEvaluation) if f.name != "suffix")
        ad = self.keys(f"{where}.ad", data["ad"] or {}, allowed)
        values: dict[str, Any] = {"suffix": suffix}
        if "episodes" in ad:
            if type(ad["episodes"]) is not int or ad["episodes"] < 1:
                self.fail(f"{where}.ad.episodes", f"must be an integer ≥ 1, got {ad['episodes']!r}")
            values["episodes"] = ad["episodes"]
        if "against" in ad:
            against = self.keys(f"{where}.ad.against", ad["against"], tuple(ad["against"] or ()))
            values["against"] = tuple((self.text(f"{where}.ad.against", name),
                                       self.file(f"{where}.ad.against.{name}", path)) for name, path in against.items())
        return ADEvaluation(**values)
