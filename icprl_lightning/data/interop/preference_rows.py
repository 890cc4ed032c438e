"""Foreign preference data as our contexts: TRL-style chosen/rejected rows (``--format trl``) and imitation/B-Pref
segment-pair label arrays (``--format bpref``); the columns, label conventions and ties are in
docs/data_formats.md.

A TRL row names the winner by its column, so the pair is put in a seeded random order (``--seed``) and no label
is constant. B-Pref's label ``1 * (return_1 < return_2)`` means segment **2** won. A tie is never stored as 0.5
nor made a hard label here: ``--ties refuse`` (default) stops, ``--ties drop`` imports the others
(``source_row`` still names each kept row). The result goes through ``importer.import_preferences``: the same
checks, dtypes, task split and store layout as an ``.npz`` import.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

TIES = ("refuse", "drop")
CONVENTIONS = ("imitation", "bpref")
TIE = 0.5
BPREF_FIELDS = ("states_1", "actions_1", "states_2", "actions_2", "label")
ROW_COLUMNS = {"step_preference": ("prompt", "chosen", "rejected"), "trajectory_preference": ("chosen", "rejected")}
OPTIONAL_COLUMNS = {"step_preference": ("task_index", "context_id"), "trajectory_preference": ("task_index",)}


def read_table(source: str | Path) -> dict[str, list[Any]]:
    """``{column: Python values}`` of a Parquet file or a Hugging Face dataset saved to disk."""
    source = Path(source)
    if source.is_file():
        import pyarrow.parquet as pq

        try:
            return pq.read_table(source).to_pydict()
        except Exception as e:  # pyarrow raises several types for a file that is not Parquet
            raise ValueError(f"{source} is not a readable Parquet file ({type(e).__name__}: {e})") from None
    if not source.is_dir():
        raise FileNotFoundError(f"no table at {source}: pass a Parquet file or a dataset saved by save_to_disk")
    import datasets

    loaded = datasets.load_from_disk(str(source))
    if isinstance(loaded, datasets.DatasetDict):
        if "train" not in loaded and len(loaded) != 1:
            raise ValueError(f"{source} holds splits {sorted(loaded)}; keep the rows in a 'train' split (or only one)")
        loaded = loaded["train"] if "train" in loaded else next(iter(loaded.values()))
    return loaded.data.table.to_pydict()


def _array(name: str, values: Any, row: str = "row") -> np.ndarray:
    """A column's values as one numeric array; a ragged or non-numeric column is a ``ValueError`` naming it."""
    try:
        x = np.asarray(values)
    except ValueError:
        x = np.asarray(values, dtype=object)
    if x.dtype.kind not in "biuf":
        raise ValueError(f"column {name!r} must hold numbers of one shape in every {row} (got {x.dtype} values: "
                         "missing entries or lists of different lengths)")
    return x


def _swap(n_shape: tuple[int, ...], seed: int) -> np.ndarray:
    """Seeded coin flips: where True the rejected element is put first (``preferred`` = 0)."""
    return np.random.default_rng(seed).random(n_shape) < 0.5


def _ordered(chosen: np.ndarray, rejected: np.ndarray, swap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = swap.reshape(swap.shape + (1,) * (chosen.ndim - swap.ndim))
    return np.where(s, rejected, chosen), np.where(s, chosen, rejected)


def _groups(context_id: np.ndarray) -> np.ndarray:
    """[N, T] row indices of each context (first appearance order, steps in table order); equal lengths required."""
    ids, first, inverse, counts = np.unique(context_id, return_index=True, return_inverse=True, return_counts=True)
    if np.unique(counts).size > 1:
        t = int(np.bincount(counts).argmax())
        odd = ids[counts != t][:5].tolist()
        raise ValueError(f"column 'context_id': every context needs the same number of rows (steps T); most have {t}, "
                         f"contexts {odd} do not")
    order = np.argsort(first)  # contexts in the order they first appear
    rows = np.argsort(inverse, kind="stable").reshape(len(ids), -1)  # rows of context k, in table order
    return rows[order]


def _task_index(columns: Mapping[str, Any], rows: np.ndarray) -> dict[str, np.ndarray]:
    if "task_index" not in columns:
        return {}
    task = _array("task_index", columns["task_index"])
    if task.ndim != 1 or task.dtype.kind not in "iu":
        raise ValueError(f"column 'task_index' must hold one integer per row, got {task.dtype} of shape "
                         f"{list(task.shape)}")
    per_context = task[rows].reshape(len(rows), -1)
    if (per_context != per_context[:, :1]).any():
        bad = int(np.argmax((per_context != per_context[:, :1]).any(1)))
        raise ValueError(f"column 'task_index' differs within context {bad} (rows {rows[bad].tolist()[:5]}...); "
                         "a context belongs to one task")
    return {"task_index": per_context[:, 0]}


def trl_arrays(columns: Mapping[str, list[Any]], kind: str, seed: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(the context arrays of ``kind``, [N] source row of each context's first step) from TRL columns."""
    if kind not in ROW_COLUMNS:
        raise ValueError(f"TRL rows import as kind {sorted(ROW_COLUMNS)}, got {kind!r}")
    required, optional = ROW_COLUMNS[kind], OPTIONAL_COLUMNS[kind]
    for name in columns:
        if name not in required + optional:
            hint = (" (T-PRL trajectories carry their states: drop 'prompt'; the task goes in 'task_index')"
                    if name == "prompt" else "")
            raise ValueError(f"unknown column {name!r}{hint}; TRL rows of kind {kind} have {list(required)} and "
                             f"optional {list(optional)}")
    for name in required:
        if name not in columns:
            raise ValueError(f"missing column {name!r}; TRL rows of kind {kind} need {list(required)}")
    n_rows = len(columns["chosen"])
    if n_rows == 0:
        raise ValueError("the table has no rows")
    if kind == "step_preference":
        rows = (_groups(_array("context_id", columns["context_id"])) if "context_id" in columns
                else np.arange(n_rows)[:, None])
        states = _array("prompt", columns["prompt"])
        if states.ndim != 2:
            raise ValueError(f"column 'prompt' must hold the state, a list of S floats per row; got shape "
                             f"{list(states.shape)}")
        chosen, rejected = _array("chosen", columns["chosen"]), _array("rejected", columns["rejected"])
        swap = _swap(rows.shape, seed)
        actions, alt_actions = _ordered(chosen[rows], rejected[rows], swap)
        arrays = {"states": states[rows], "actions": actions, "alt_actions": alt_actions,
                  "preferred": (~swap).astype(np.uint8)}
    else:
        rows = np.arange(n_rows)[:, None]
        parts = {}
        for side in ("chosen", "rejected"):
            values = columns[side]
            if not all(isinstance(v, Mapping) and {"states", "actions"} <= set(v) for v in values):
                raise ValueError(f"column {side!r} must hold one struct {{'states': [H][S], 'actions': [H] or [H][A]}} "
                                 "per row (a T-PRL trajectory)")
            parts[side] = {f: _array(f"{side}.{f}", [v[f] for v in values]) for f in ("states", "actions")}
        swap = _swap((n_rows,), seed)
        states_a, states_b = _ordered(parts["chosen"]["states"], parts["rejected"]["states"], swap)
        actions_a, actions_b = _ordered(parts["chosen"]["actions"], parts["rejected"]["actions"], swap)
        arrays = {"states_a": states_a, "actions_a": actions_a, "states_b": states_b, "actions_b": actions_b,
                  "preferred": (~swap).astype(np.uint8)}
    return {**arrays, **_task_index(columns, rows)}, rows[:, 0]


def label_arrays(arrays: Mapping[str, np.ndarray], convention: str = "imitation", ties: str = "refuse"
                 ) -> tuple[dict[str, np.ndarray], np.ndarray, int]:
    """(T-PRL arrays, [N'] source row of each kept pair, number of ties dropped) from segment-pair label arrays."""
    if convention not in CONVENTIONS:
        raise ValueError(f"label convention must be one of {list(CONVENTIONS)}, got {convention!r}")
    if ties not in TIES:
        raise ValueError(f"ties must be one of {list(TIES)}, got {ties!r}")
    known = (*BPREF_FIELDS, "task_index")
    for name in arrays:
        if name not in known:
            raise ValueError(f"unknown field {name!r}; segment-pair label arrays have {list(BPREF_FIELDS)} and "
                             "optional 'task_index'")
    for name in BPREF_FIELDS:
        if name not in arrays:
            raise ValueError(f"missing field {name!r}; segment-pair label arrays need {list(BPREF_FIELDS)}")
    label = np.asarray(arrays["label"])
    if label.ndim == 2 and label.shape[1] == 1:  # B-Pref keeps labels as [N, 1]
        label = label[:, 0]
    if label.ndim != 1 or label.dtype.kind not in "biuf":
        raise ValueError(f"field 'label' must be numbers of shape [N] or [N, 1], got {label.dtype} of shape "
                         f"{list(np.shape(arrays['label']))}")
    label = label.astype(np.float64)
    allowed = {"imitation": (0.0, TIE, 1.0), "bpref": (0.0, TIE, 1.0, -1.0)}[convention]
    bad = ~np.isin(label, allowed)
    if bad.any():
        meaning = ("the probability that segment 1 is preferred" if convention == "imitation"
                   else "1 = segment 2 preferred, 0 = segment 1, -1 or 0.5 = equally preferable")
        raise ValueError(f"field 'label' holds {int(bad.sum())} values outside {list(allowed)} ({convention} "
                         f"convention: {meaning}); found {np.unique(label[bad])[:5].tolist()}")
    tie = (label == TIE) | (label == -1.0)
    n_ties = int(tie.sum())
    if n_ties and ties == "refuse":
        raise ValueError(f"field 'label' holds {n_ties} ties (equally preferable pairs) among {len(label)} rows; this "
                         "import keeps labels of 0 or 1 (only icprl label --export writes ties as 0.5, for ICPO and "
                         "RewardGen), so a tie is neither stored as 0.5 nor guessed: pass --ties drop (ties='drop') "
                         f"to import the other {len(label) - n_ties} rows")
    keep = np.flatnonzero(~tie)
    if keep.size == 0:
        raise ValueError(f"field 'label': all {len(label)} rows are ties; nothing is left to import")
    first_won = label[keep] if convention == "imitation" else 1.0 - label[keep]
    out = {"states_a": arrays["states_1"], "actions_a": arrays["actions_1"], "states_b": arrays["states_2"],
           "actions_b": arrays["actions_2"]}
    for name, x in out.items():
        if np.shape(x)[:1] != label.shape:
            raise ValueError(f"field {name.replace('_a', '_1').replace('_b', '_2')!r} has {np.shape(x)[:1]} rows, "
                             f"'label' has {len(label)}: one row per pair")
    out = {name: np.asarray(x)[keep] for name, x in out.items()}
    out["preferred"] = first_won.astype(np.uint8)
    if "task_index" in arrays:
        task = np.asarray(arrays["task_index"])
        if task.shape != label.shape:
            raise ValueError(f"field 'task_index' must have shape [N={len(label)}], got {list(task.shape)}")
        out["task_index"] = task[keep]
    return out, keep, n_ties
