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
the held-out tasks come from the data (``Run.data.evaluation_suites()``, ``bandit_suites()``, ...), never from a
training split. ``docs/extending_evaluations.md`` walks through one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

KIND = "evaluation"  # the payload key that names a registered evaluation


class Run(NamedTuple):
    """One trained method under evaluation: its row name, the data it is deployed on (prepared, the data contract
    ``PreferenceData``), its checkpoints (one per training seed) and how it acts (``--greedy`` True, ``--sample``
    False, None: the method's own default)."""

    name: str
    data: Any
    checkpoints: tuple[str, ...]
    greedy: bool | None = None

    def agent(self, checkpoint: str, seed: int):
        """A checkpoint as a deployed ``Agent`` (``load_agent``), acting as asked, its sampling seeded."""
        from icprl_lightning.deploy import load_agent

        return load_agent(checkpoint, seed=seed, greedy=self.greedy)


class HeldOutEvaluation(ABC):
    """A kind of held-out evaluation (see the module docstring). ``options`` are the ``--option KEY=VALUE`` of the
    command line (an experiment file's ``options``), passed to the constructor as keywords."""

    name: ClassVar[str]

    @abstractmethod
    def run(self, runs: list[Run], seeds: list[int]) -> dict[str, Any]:
        """The results of every run as a JSON-serializable payload."""

    @staticmethod
    @abstractmethod
    def markdown(payload: dict[str, Any]) -> str:
        """The payload's tables as markdown (what ``<out>.md`` and the rendered docs show)."""

    @staticmethod
    def figure(payload: dict[str, Any], path: Path) -> None:
        """Draw the payload's figure at ``path`` (none by default); save it with ``io.save_figure``, which never
        writes through a link."""
        return None


def evaluation_of(payload: Any) -> type[HeldOutEvaluation] | None:
    """The registered evaluation a results payload names (its ``evaluation`` key), or None for another JSON."""
    from icprl_lightning.registry import EVALUATIONS

    name = payload.get(KIND) if isinstance(payload, dict) else None
    return EVALUATIONS.get(name) if isinstance(name, str) else None
