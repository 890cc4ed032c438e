"""The data contract: what a method, the callbacks and the CLI may ask of a DataModule (``PreferenceData``).

Both DataModules implement it, ``PreferenceDataModule`` (generated data, ``data/datamodule.py``) and
``RecordedPreferenceDataModule`` (recorded data, ``data/recorded.py``), and so must a user's own:

* the sizes the CLI links into the model: ``context_kind``, ``state_dim``, ``action_spec``, ``context_length``;
* what a training batch holds: ``batch_fields()``, and the flags ``pairs`` (another context of the same task
  as the samples' ``pair``) and ``query_labels`` (query states and their optimal actions), which the pairing check
  (``validation.pairing_errors``) compares with what a model's loss reads;
* ``train_arrays()``: the training split's arrays of exactly the served fields, on which a method fits its
  input statistics when a fit starts (the DataModule hands them over; a method never reads the store);
* the held-out evaluations it ``offers`` (names from ``EVALUATIONS``) and ``held_out(name)``, what each reads. A
  callback declares the ones it reads as ``requires_data`` (``ReadsData``), and the pairing check refuses a
  callback whose evaluation the data does not offer before any data is generated;
* ``metric_env`` (the ``val/<metric_env>/...`` namespace of logged metrics) and ``path`` (where the dataset is).

It sits on the ground floor, beside the contexts: methods may import it while they may not import ``data/``
(``tests/unit/test_layering.py``), so a method learns what the data serves with no path to a generator, a
family or an oracle.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from icprl_lightning.contexts import ActionSpec

if TYPE_CHECKING:
    import numpy as np


# The held-out evaluations a DataModule may offer (each the name of its method here), with what serves them.
EVALUATIONS: dict[str, str] = {
    "rollouts": "data with held-out in-context rollouts (an MDP setting: StepPreferences, "
                         "TrajectoryPairs, RewardContexts, RewardTrajectories)",
    "duels": "dueling-bandit data (setting icprl_lightning.data.settings.BanditDuels)",
    "pair_accuracy": "trajectory_preference data (setting icprl_lightning.data.settings.TrajectoryPairs)",
}


@runtime_checkable
class PreferenceData(Protocol):
    """What a method, a callback and the CLI may ask of a DataModule; see the module docstring."""

    pairs: bool          # a batch also holds another context of the same task as ``pair``
    query_labels: bool   # a batch also holds ``query_states`` and ``optimal_actions``

    @property
    def context_kind(self) -> str:
        """The kind of context a training sample holds (``contexts.CONTEXT_TYPES``)."""

    @property
    def state_dim(self) -> int: ...

    @property
    def action_spec(self) -> ActionSpec: ...

    @property
    def context_length(self) -> int:
        """Steps per context: the model's ``max_context``."""

    @property
    def metric_env(self) -> str:
        """The namespace of logged metrics: ``val/<metric_env>/...``."""

    @property
    def path(self) -> Path:
        """The dataset's directory."""

    @property
    def offers(self) -> frozenset[str]:
        """The held-out evaluations this data serves (names from ``EVALUATIONS``)."""

    def batch_fields(self) -> tuple[str, ...]:
        """The stored fields a training batch is made of."""

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training split's arrays of ``batch_fields()`` and nothing else (memory-mapped, read-only)."""

    def held_out(self, evaluation: str) -> Any:
        """What one offered evaluation reads: ``rollouts`` a list of ``data.suites.EvalSuite`` (one per context
        quality), ``duels`` a list of ``data.suites.BanditSuite`` (one per context source), ``pair_accuracy`` the
        held-out T-PRL pairs per quality (``ContextSamples``, each with another pair of its task). An evaluation
        not in ``offers`` is a ``ValueError`` (``not_offered``)."""


@runtime_checkable
class ReadsData(Protocol):
    """A callback that reads held-out evaluations of the data: ``requires_data`` names them (``EVALUATIONS``)."""

    requires_data: tuple[str, ...]


def missing_members(datamodule: object) -> list[str]:
    """The members of ``PreferenceData`` that ``datamodule`` lacks (empty: it implements the contract)."""
    members = {*PreferenceData.__annotations__, *(name for name in vars(PreferenceData) if not name.startswith("_"))}
    return sorted(m for m in members if not hasattr(datamodule, m))


def not_offered(data_name: str, evaluation: str, offers: frozenset[str], note: str = "") -> ValueError:
    """The error for asking ``data_name`` for an evaluation it does not offer, naming the data that would."""
    needs = EVALUATIONS.get(evaluation, "a DataModule that offers it")
    return ValueError(f"{data_name} offers no {evaluation} (it offers {sorted(offers)}); {evaluation} needs "
                      f"{needs}{note}")
