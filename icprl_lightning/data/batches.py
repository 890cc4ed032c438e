"""Batches from memory-mapped arrays: a whole batch per index list, served as the models want it.

A training sample is one context (one stored row). With ``pairs`` a batch also holds the comparisons of
*another* row of the same task (``pair_*`` fields): ICPO's default loss pairs and RewardGen's context,
which the model cannot copy from its own context. With ``query_labels`` it holds the query states and
their optimal-action labels (``query_states``, ``optimal_actions``) of DPT/DP²T. With ``tasks`` it holds
``task`` (int64 (B,)), each row's training-task index ``row // per_task``: ICRG's cross-fitting picks the
RewardGen that was not fitted on that task (``methods/icrg.py``). The index names a training task, never its
goal or reward; no model reads it as input.

Rows are stored task-major: row ``task * per_task + j`` is trajectory j of the task.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from icprl_lightning.contexts import context_fields

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


class ContextBatches(Dataset):
    """Indexable by a list of row indices; returns a whole batch as a dict of tensors.

    With ``pairs`` the batch also holds ``pair_fields`` of another trajectory of the same task, as ``pair_*``;
    with ``tasks`` each row's task index ``row // trajectories_per_task`` as ``task``.
    """

    def __init__(self, arrays: dict[str, np.ndarray], context_fields: tuple[str, ...], trajectories_per_task: int,
                 pairs: bool, query_labels: bool, pair_fields: tuple[str, ...] = PAIR_FIELDS,
                 tasks: bool = False) -> None:
        self.arrays = arrays
        self.fields = list(context_fields) + (list(LABEL_FIELDS) if query_labels else [])
        self.per_task = trajectories_per_task
        self.pairs = pairs
        self.pair_fields = pair_fields
        self.tasks = tasks
        if pairs and trajectories_per_task < 2:
            raise ValueError("pairs from another trajectory of the same task need trajectories_per_task >= 2")

    def __len__(self) -> int:
        return len(self.arrays[self.fields[0]])

    def __getitem__(self, index: list[int]) -> dict[str, torch.Tensor]:
        idx = np.sort(np.asarray(index))  # sorted reads are kinder to memory maps
        batch = {k: to_tensor(self.arrays[k][idx]) for k in self.fields}
        if self.tasks:
            batch["task"] = torch.from_numpy(idx // self.per_task).long()
        if self.pairs:
            other = other_rows(idx, self.per_task, torch.randint(1, self.per_task, (len(idx),)).numpy())
            for k in self.pair_fields:
                batch[f"pair_{k}"] = to_tensor(self.arrays[k][other])
        return batch
