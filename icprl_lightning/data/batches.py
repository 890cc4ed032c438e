"""Batches from memory-mapped arrays: a whole batch per index list, served as typed samples (``samples.py``).

A training sample is one context (one stored row), served as the typed context of the data's kind. With ``pairs``
a batch also holds another row of the same task as ``pair`` (ICPO's default scored comparisons and RewardGen's
and ICRG's context, which the model cannot copy from its own context). With ``query_labels`` it holds the query
states and their optimal-action labels of DPT/DP²T. With ``tasks`` it holds ``task``, each row's training-task
index ``row // per_task``: ICRG's cross-fitting picks the RewardGen that was not fitted on that task
(``methods/icrg.py``). Reward-trajectory rows (DIT) hold two trajectories of one task and are served as
``RewardTrajectorySamples``.

Rows are stored task-major: row ``task * per_task + j`` is trajectory j of the task.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from icprl_lightning.contexts import CONTEXT_TYPES, Context, RewardTrajectoryContext, context_fields
from icprl_lightning.samples import ContextSamples, RewardTrajectorySamples, Samples

PAIR_FIELDS = context_fields("step_preference")
LABEL_FIELDS = ("query_states", "optimal_actions")


def to_tensor(x: np.ndarray) -> torch.Tensor:
    """Stored compactly, served as the model wants: labels (uint8) as float, indices as int64.

    Read-only views of the memory-mapped store are copied: a tensor must never alias the dataset file.
    """
    x = np.ascontiguousarray(x)
    t = torch.from_numpy(x if x.flags.writeable else x.copy())
    if t.dtype == torch.uint8:
        return t.float()
    return t.long() if not t.is_floating_point() else t


def other_rows(rows: np.ndarray, per_task: int, shift: np.ndarray | int) -> np.ndarray:
    """Row of the trajectory ``shift`` places after each row's, within the same task (task-major storage)."""
    j = rows % per_task
    return rows - j + (j + shift) % per_task


def stored_context(kind: str, arrays: dict[str, np.ndarray], rows: np.ndarray | slice,
                   fields: tuple[str, ...] | None = None) -> Context:
    """The typed context of ``kind`` held by ``rows`` of ``arrays`` (stored under the context's field names;
    ``fields``: which of them, by default its required ones)."""
    cls = CONTEXT_TYPES[kind]
    names = context_fields(kind) if fields is None else fields
    return cls(**{k: to_tensor(arrays[k][rows]) for k in names})


def _reward_trajectories(rows: dict[str, torch.Tensor], task: torch.Tensor | None) -> RewardTrajectorySamples:
    return RewardTrajectorySamples(
        RewardTrajectoryContext(rows["states_a"], rows["actions_a"], rows["rewards_a"]),
        RewardTrajectoryContext(rows["states_b"], rows["actions_b"], rows["rewards_b"]),
        rows.get("advantages_a"), rows.get("advantages_b"), task)


class ContextBatches(Dataset):
    """Indexable by a list of row indices; returns a whole batch as typed samples of ``kind``.

    ``context_fields`` are the stored fields of a row's context (its required fields for the context kinds;
    ``states_a`` ... ``rewards_b`` and the optional ``advantages_*`` for reward trajectories). With ``pairs`` the
    batch also holds ``pair_fields`` of another trajectory of the same task as ``pair``; with ``tasks`` each row's
    task index ``row // trajectories_per_task`` as ``task``.
    """

    def __init__(self, arrays: dict[str, np.ndarray], context_fields: tuple[str, ...], trajectories_per_task: int,
                 pairs: bool, query_labels: bool, pair_fields: tuple[str, ...] = PAIR_FIELDS,
                 tasks: bool = False, *, kind: str) -> None:
        if kind not in CONTEXT_TYPES:
            raise ValueError(f"unknown context kind {kind!r}; known: {sorted(CONTEXT_TYPES)}")
        if kind == "reward_trajectory" and (pairs or query_labels):
            raise ValueError("reward-trajectory rows already hold two trajectories of one task, each the other's "
                             "context, and no query labels: set pairs and query_labels false")
        if pairs and trajectories_per_task < 2:
            raise ValueError("pairs from another trajectory of the same task need trajectories_per_task >= 2")
        self.arrays = arrays
        self.kind = kind
        self.context_fields = tuple(context_fields)
        self.per_task = trajectories_per_task
        self.pairs = pairs
        self.query_labels = query_labels
        self.pair_fields = tuple(pair_fields)
        self.tasks = tasks

    def __len__(self) -> int:
        return len(self.arrays[self.context_fields[0]])

    def context(self, rows: np.ndarray, fields: tuple[str, ...] | None = None) -> Context:
        """The typed context held by ``rows`` (``fields``: by default the row's context fields)."""
        return stored_context(self.kind, self.arrays, rows, self.context_fields if fields is None else fields)

    def __getitem__(self, index: list[int]) -> Samples:
        idx = np.sort(np.asarray(index))  # sorted reads are kinder to memory maps
        task = torch.from_numpy(idx // self.per_task).long() if self.tasks else None
        if self.kind == "reward_trajectory":
            return _reward_trajectories({k: to_tensor(self.arrays[k][idx]) for k in self.context_fields}, task)
        labels = ((to_tensor(self.arrays["query_states"][idx]), to_tensor(self.arrays["optimal_actions"][idx]))
                  if self.query_labels else (None, None))
        pair = None
        if self.pairs:
            other = other_rows(idx, self.per_task, torch.randint(1, self.per_task, (len(idx),)).numpy())
            pair = self.context(other, self.pair_fields)
        return ContextSamples(self.context(idx), pair, *labels, task)
