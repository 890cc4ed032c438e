"""Any Python function as an annotator: ``CallableAnnotator(fn)``.

``fn(queries, rng)`` receives a ``StepQueries`` or ``TrajectoryQueries`` batch and the generator's ``rng``
(draw from it, so the dataset stays a function of the seed) and returns one code per pair (``labels.py``),
checked with an error naming what was wrong. In YAML ``fn`` is a dotted import path; the manifest records it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries, TrajectoryQueries
from icprl_lightning.annotators.labels import check_labels
from icprl_lightning.validation import HyperparameterError

LabelFunction = Callable[[StepQueries | TrajectoryQueries, np.random.Generator], Any]


class CallableAnnotator(Annotator):
    """Labels from ``fn(queries, rng)``; see the module docstring."""

    def __init__(self, fn: LabelFunction) -> None:
        if not callable(fn):
            raise HyperparameterError(f"CallableAnnotator: fn must be callable, got {type(fn).__name__}")
        self.fn = fn

    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        return self._call(queries, len(queries.states), rng)

    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        return self._call(queries, len(queries.states_a), rng)

    def _call(self, queries: StepQueries | TrajectoryQueries, n: int, rng: np.random.Generator) -> np.ndarray:
        return check_labels(self.fn(queries, rng), n, f"CallableAnnotator({self.name})")

    @property
    def name(self) -> str:
        module, name = getattr(self.fn, "__module__", None), getattr(self.fn, "__qualname__", None)
        return f"{module}.{name}" if module and name else repr(self.fn)

    def init_args(self) -> dict[str, Any]:
        return {"fn": self.name}
