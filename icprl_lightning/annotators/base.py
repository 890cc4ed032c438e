"""Who labels a pair: the ``Annotator`` interface and the batches of queries it answers.

A setting asks its annotator to label a batch of *queries* (B-Pref's word for a pair shown to a teacher):
I-PRL ``StepQueries`` or T-PRL ``TrajectoryQueries``, which carry privileged fields (the oracle's utilities or
latent rewards, each pair's task) for scripted teachers, a person or an LLM. None of these leave data
generation: the stored context holds the states, actions and the label only (``labels.py``).
"""

from __future__ import annotations

import sys
from abc import ABC, abstractmethod
from typing import Any, NamedTuple

import numpy as np


class StepQueries(NamedTuple):
    """n I-PRL step pairs; ``actions`` [n] (discrete) or [n, A] (continuous), like ``alt_actions``."""

    states: np.ndarray  # [n, S] float32, the observation s_h
    actions: np.ndarray  # the first proposal a (stored as ``actions``)
    alt_actions: np.ndarray  # the second proposal a' (``alt_actions``)
    utility: np.ndarray  # [n] A*(s_h, a), privileged
    alt_utility: np.ndarray  # [n] A*(s_h, a'), privileged
    tasks: np.ndarray | None = None  # [n, ...] the task of each pair (DarkRoom: goal cell), privileged


class TrajectoryQueries(NamedTuple):
    """n T-PRL pairs of episodes of horizon H; actions [n, H] (discrete) or [n, H, A]."""

    states_a: np.ndarray  # [n, H, S] float32
    actions_a: np.ndarray
    rewards_a: np.ndarray  # [n, H] latent per-step rewards, privileged
    states_b: np.ndarray
    actions_b: np.ndarray
    rewards_b: np.ndarray
    tasks: np.ndarray | None = None  # [n, ...] the task of each pair, privileged

    @property
    def returns_a(self) -> np.ndarray:
        """Σ_h r_h of ξ_a, [n] (the latent ordering a label agrees with or not)."""
        return self.rewards_a.sum(1)

    @property
    def returns_b(self) -> np.ndarray:
        return self.rewards_b.sum(1)


class Annotator(ABC):
    """Labels batches of step pairs and of trajectory pairs; see the module docstring."""

    @abstractmethod
    def label_steps(self, queries: StepQueries, rng: np.random.Generator) -> np.ndarray:
        """uint8 codes [n], one per step pair (1 = ``actions`` preferred)."""

    @abstractmethod
    def label_trajectories(self, queries: TrajectoryQueries, rng: np.random.Generator) -> np.ndarray:
        """uint8 codes [n], one per trajectory pair (1 = ξ_a preferred)."""

    @abstractmethod
    def init_args(self) -> dict[str, Any]:
        """The constructor's arguments, JSON-serializable (what ``config()`` records)."""

    def config(self) -> dict[str, Any]:
        """``{class_path, init_args}``: the annotator as YAML would name it (recorded in the manifest).

        The class path is the package's re-export when there is one (``icprl_lightning.annotators.X``),
        so moving a class between the package's files keeps the configs, and the datasets' hashes.
        """
        cls = type(self)
        package = cls.__module__.rpartition(".")[0]
        exported = package and getattr(sys.modules.get(package), cls.__qualname__, None) is cls
        return {"class_path": f"{package if exported else cls.__module__}.{cls.__qualname__}",
                "init_args": self.init_args()}
