"""One interface for a held-out evaluation: what a user writes to judge policies their own way.

A ``HeldOutEvaluation`` takes trained runs (each a method's checkpoints, one per training seed, and the data they
are deployed on) and returns a results payload (plain JSON) that knows its table (``markdown``) and its figure
(``figure``). Registered by its ``name`` (``registry.EVALUATIONS``: an entry point of group
``icprl_lightning.evaluations`` or ``register_evaluation``), it is a peer of the built-in tables in every command:

    icprl evaluate --evaluation NAME --run NAME=CONFIG:CKPT[,CKPT...] [--option KEY=VALUE ...] --out PATH
    # an experiment file:  evaluations: [{suffix: _mine, evaluation: NAME, options: {KEY: VALUE}}]
    icprl reproduce --render        # renders <out>.md from <out>.json with the evaluation's own ``markdown``

``icprl evaluate`` checks every run against its data, prepares the data, calls ``run`` and writes ``<out>.json``
(the payload, with ``evaluation: NAME`` added so the renderer finds its kind), ``<out>.md`` and ``<out>.png``.
Agents come from ``load_agent`` (``Run.agent``), so an evaluation sees a policy exactly as a user deploys it;
the held-out tasks come from the data (``Run.data.held_out("rollouts")``, ``held_out("duels")``, ...), never from a
training split. ``docs/extending_evaluations.md`` walks through one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

KIND = "evaluation"  # the payload key that names a registered evaluation


class Run(NamedTuple):
    """One trained method under evaluation: its row name, the data it is deployed on (prepared, the data contract
    ``PreferenceData``), its checkpoints (one per training seed), how it acts (``--greedy`` True, ``--sample``
    False, None: the method's own default) and the config its data came from."""

    name: str
    data: Any
    checkpoints: tuple[str, ...]
    greedy: bool | None = None
    config: str = ""

    @property
    def spec(self) -> str:
        """The run as ``--run`` spells it: ``NAME=CONFIG:CKPT[,CKPT...]``."""
        return f"{self.name}={self.config}:{','.join(self.checkpoints)}"

    def agent(self, checkpoint: str, seed: int):
        """A checkpoint as a deployed ``Agent`` (``load_agent``), acting as asked, its sampling seeded."""
        from icprl_lightning.deploy import load_agent

        return load_agent(checkpoint, seed=seed, greedy=self.greedy)


class HeldOutEvaluation(ABC):
    """A kind of held-out evaluation (see the module docstring). ``options`` are the ``--option KEY=VALUE`` of the
    command line (an experiment file's ``options``), passed to the constructor as keywords."""

    name: ClassVar[str]
    held_out_only: ClassVar[bool] = False  # reads only ``data.held_out(...)``: the training splits may be skipped

    @classmethod
    def recognizes(cls, payload: dict[str, Any]) -> bool:
        """Whether ``payload`` is this evaluation's results (it names it; a built-in kind also knows its JSONs
        written before payloads named their kind)."""
        return payload.get(KIND) == cls.name

    @abstractmethod
    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        """The results of every run as a JSON-serializable payload."""

    @staticmethod
    @abstractmethod
    def markdown(payload: dict[str, Any]) -> str:
        """The payload's tables as markdown (what ``<out>.md`` and the rendered docs show)."""

    @classmethod
    def write(cls, payload: dict[str, Any], out: str | Path) -> list[Path]:
        """What every command that evaluates writes: ``<out>.json`` (never through a link), ``<out>.md`` (the table,
        from the JSON as written, so it is what ``icprl reproduce --render`` makes of it) and ``<out>.png`` where
        ``figure`` draws one; returns the files written."""
        import json

        from icprl_lightning.io import write_atomic, write_json_atomic

        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        source = write_json_atomic(out.with_name(f"{out.name}.json"), payload)
        table = write_atomic(out.with_name(f"{out.name}.md"), cls.markdown(json.loads(source.read_text())))
        figure = out.with_name(f"{out.name}.png")
        cls.figure(payload, figure)
        return [source, table, *([figure] if figure.exists() else [])]

    @classmethod
    def during_fit(cls, subject: Any, data: Any, **options: Any) -> tuple[dict[str, Any], dict[str, float]]:
        """The numbers ``callbacks.held_out.HeldOutCallback`` keeps and logs at a validation epoch of a fit: the
        module deployed (``subject``) on ``data``'s held-out tasks. None by default: it judges checkpoints only."""
        raise NotImplementedError(f"the {cls.name!r} evaluation runs on checkpoints, not during a fit")

    @staticmethod
    def show_fit(results: dict[str, Any], when: str) -> None:
        """Print ``during_fit``'s results (``when``: ", epoch N" in a fit); nothing by default."""
        return None

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        """Draw the payload's figure at ``path`` (none by default); save it with ``io.save_figure``, which never
        writes through a link."""
        return None


def evaluation_of(payload: Any) -> type[HeldOutEvaluation] | None:
    """The registered evaluation whose results ``payload`` is (its ``evaluation`` key, or a built-in kind that
    recognizes it), or None for another JSON."""
    from icprl_lightning.registry import EVALUATIONS

    if not isinstance(payload, dict):
        return None
    if isinstance(payload.get(KIND), str):
        return EVALUATIONS.get(payload[KIND])
    return next((kind for kind in map(EVALUATIONS.get, EVALUATIONS.builtins) if kind.recognizes(payload)), None)


def over_training_seeds(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """One row from each training seed's held-out means: mean ± sem over seeds, and the seeds' values.

    With a single seed the row is that seed's (its ± is the sem over held-out tasks). A seed row's
    ``per_task`` (metric -> per-task values) becomes the row's ``per_task``: metric -> seeds × tasks values, the
    seeds × tasks matrix that ``reproduce.statistics`` bootstraps.
    """
    from icprl_lightning.metrics import mean_sem

    tasks = [seed_row.get("per_task") for seed_row in per_seed]
    per_seed = [{k: v for k, v in seed_row.items() if k != "per_task"} for seed_row in per_seed]
    if len(per_seed) == 1:
        row: dict[str, Any] = dict(per_seed[0])
    else:
        row = {"training_seeds": len(per_seed), "per_seed": {}}
        for key in (k for k in per_seed[0] if not k.endswith("_sem")):
            values = [seed_row[key] for seed_row in per_seed]
            row[key], row[f"{key}_sem"] = mean_sem(values)
            row["per_seed"][key] = values
    if all(t is not None for t in tasks):
        row["per_task"] = {metric: [t[metric] for t in tasks] for metric in tasks[0]}
    return row
