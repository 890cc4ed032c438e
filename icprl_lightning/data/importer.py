"""Bring your own recorded preference data: check a user's arrays and write them as an icprl dataset
(``icprl import``; the fields and the command's forms are in docs/recorded_data.md and docs/data_formats.md).

The source is untrusted: ``data/source_files.py`` checks every ``.npy`` header against the file's size and a
limit before allocating anything, and every field is checked before anything is written, with a
``ValueError`` naming the field and what is expected. These are the loader's checks (``data/schema.py``)
applied to the source, so whatever imports also loads (``tests/reliability/test_import_fuzz.py``). States and
continuous actions beyond ``schema.MAX_MAGNITUDE`` are refused, not standardized (why: ``data/schema.py``).
Rows are stored task-major (stable, so each task keeps its recorded order) and the tasks split into train and
val by a seeded permutation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.schema import MAX_MAGNITUDE, magnitude_problem
from icprl_lightning.data.source_files import MAX_SOURCE_BYTES, read_source
from icprl_lightning.data.store import check_replaceable_dataset, write_dataset

FORMAT = "icprl_recorded"
FORMAT_VERSION = 1
TASK_FIELD = "task_index"
SOURCE_ROW = "source_row"  # written by the importer: each stored row's row number in the source arrays


@dataclass(frozen=True)
class FieldSpec:
    """One field: what it holds (``state``, ``action`` or ``label``) and whether it has a step axis."""

    role: str
    per_step: bool  # lead axes [N, T] (True) or [N] (False)


# The context fields of each supported kind, in the order they are checked (the first defines N, T, S).
KINDS: dict[str, dict[str, FieldSpec]] = {
    "step_preference": {"states": FieldSpec("state", True), "actions": FieldSpec("action", True),
                        "alt_actions": FieldSpec("action", True), "preferred": FieldSpec("label", True)},
    "trajectory_preference": {"states_a": FieldSpec("state", True), "actions_a": FieldSpec("action", True),
                              "states_b": FieldSpec("state", True), "actions_b": FieldSpec("action", True),
                              "preferred": FieldSpec("label", False)},
}
# DPT/DP²T's optional supervision: one query state and its optimal action per context step.
QUERY_FIELDS: dict[str, FieldSpec] = {"query_states": FieldSpec("state", True),
                                      "optimal_actions": FieldSpec("action", True)}


def _expected(spec: FieldSpec, n: int, t: int, s: int, actions: ActionSpec) -> str:
    lead = f"N={n}, T={t}" if spec.per_step else f"N={n}"
    if spec.role == "state":
        return f"[{lead}, S={s}] float"
    if spec.role == "label":
        return f"[{lead}] with values in {{0, 1}}"
    if actions.discrete:
        return f"[{lead}] integer action indices in [0, {actions.size})"
    return f"[{lead}, A={actions.size}] float"


def _check_finite(name: str, x: np.ndarray, note: str = "") -> None:
    for bad, test in (("NaN", np.isnan), ("inf", np.isinf)):
        count = int(test(x).sum())
        if count:
            raise ValueError(f"field {name!r} holds {bad} in {count} entries{note}; every value must be finite")


def _to_float32(name: str, x: np.ndarray) -> np.ndarray:
    _check_finite(name, x)
    with np.errstate(over="ignore"):  # reported below, by field
        out = x.astype(np.float32)
    _check_finite(name, out, " after conversion to float32 (values beyond its range)")
    problem = magnitude_problem(out, MAX_MAGNITUDE)
    if problem is not None:
        raise ValueError(f"field {name!r} {problem}")
    return out


def _index_dtype(n_actions: int) -> type:
    """The smallest signed integer type holding every index in [0, n_actions)."""
    return next(t for t in (np.int8, np.int16, np.int32, np.int64) if n_actions - 1 <= np.iinfo(t).max)


def _check_field(name: str, x: np.ndarray, spec: FieldSpec, n: int, t: int, s: int, actions: ActionSpec,
                 reference: str, soft_labels: bool = False) -> np.ndarray:
    """Check one field against [N, T, ...] of ``reference`` and return it in its stored dtype."""
    expected = _expected(spec, n, t, s, actions)
    if x.dtype.kind not in "biuf":
        raise ValueError(f"field {name!r} must be numeric, shape {expected}; got dtype {x.dtype}")
    trailing = 1 if spec.role == "state" or (spec.role == "action" and not actions.discrete) else 0
    ndim = (2 if spec.per_step else 1) + trailing
    if x.ndim != ndim:
        raise ValueError(f"field {name!r} must have {ndim} axes, shape {expected}; got shape {list(x.shape)}")
    if x.shape[0] != n:
        raise ValueError(f"field {name!r} has {x.shape[0]} rows (N, first axis) but {reference!r} has {n}: "
                         f"every field needs one row per context, shape {expected}")
    if spec.per_step and x.shape[1] != t:
        raise ValueError(f"field {name!r} has {x.shape[1]} steps (T, second axis) but {reference!r} has {t}; "
                         f"expected shape {expected}")
    if spec.role == "state":
        if x.shape[2] != s:
            raise ValueError(f"field {name!r} has state size {x.shape[2]} but {reference!r} has {s}; "
                             f"expected shape {expected}")
        if x.dtype.kind != "f":
            raise ValueError(f"field {name!r} must be floating point (float32 or float64), shape {expected}; "
                             f"got dtype {x.dtype}")
        return _to_float32(name, x)
    if spec.role == "label":
        if x.dtype.kind == "f":
            _check_finite(name, x)
        bad = np.unique(x[(x != 0) & (x != 1) & ((x != 0.5) | (not soft_labels))])
        if bad.size:
            raise ValueError(f"field {name!r} must hold only 0{', 0.5' * soft_labels} or 1 (1 = the first of the "
                             f"pair won), shape {expected}; found {bad[:5].tolist()}")
        return x.astype(np.float32 if soft_labels else np.uint8)
    if actions.discrete:
        if x.dtype.kind == "b":
            raise ValueError(f"field {name!r} is bool; discrete actions must be {expected}")
        if x.dtype.kind == "f":
            raise ValueError(f"field {name!r} must hold {expected} (discrete, --n-actions {actions.size}); got "
                             f"dtype {x.dtype} (for continuous actions pass --action-dim instead)")
        if x.min() < 0 or x.max() >= actions.size:
            raise ValueError(f"field {name!r} holds action indices in [{x.min()}, {x.max()}], outside "
                             f"[0, {actions.size}) of --n-actions {actions.size}")
        return x.astype(_index_dtype(actions.size))  # [0, n) fits: never a silent wrap
    if x.shape[2] != actions.size:
        raise ValueError(f"field {name!r} has action size {x.shape[2]}, --action-dim is {actions.size}; "
                         f"expected shape {expected}")
    if x.dtype.kind != "f":
        raise ValueError(f"field {name!r} must be floating point, shape {expected} (continuous, --action-dim "
                         f"{actions.size}); got dtype {x.dtype} (for discrete actions pass --n-actions)")
    return _to_float32(name, x)


def check_arrays(arrays: Mapping[str, np.ndarray], kind: str, actions: ActionSpec, soft_labels: bool = False
                 ) -> dict[str, np.ndarray]:
    """Validate a user's arrays for ``kind`` and return them in the stored dtypes (rows not reordered); with
    ``soft_labels`` the labels are float32 and may be 0.5 (a tie)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {sorted(KINDS)}, got {kind!r}")
    fields = KINDS[kind]
    known = [*fields, *QUERY_FIELDS, TASK_FIELD]
    for name in arrays:
        if name not in known:
            raise ValueError(f"unknown field {name!r}; a {kind} dataset has fields {list(fields)}, optional "
                             f"{TASK_FIELD!r} and {list(QUERY_FIELDS)}")
    for name in fields:
        if name not in arrays:
            raise ValueError(f"missing field {name!r}; a {kind} dataset needs {list(fields)}")
    present = [q for q in QUERY_FIELDS if q in arrays]
    if len(present) == 1:
        missing = next(q for q in QUERY_FIELDS if q not in arrays)
        raise ValueError(f"field {present[0]!r} needs field {missing!r}: query labels come as both or neither")
    reference = next(iter(fields))  # the first field defines N, T and S
    x = np.asarray(arrays[reference])
    if x.ndim != 3:
        raise ValueError(f"field {reference!r} must have shape [N, T, S] float, got shape {list(x.shape)}")
    n, t, s = x.shape
    if n == 0 or t == 0 or s == 0:
        raise ValueError(f"field {reference!r} is empty (shape {list(x.shape)}): a dataset needs at least one "
                         "context (N) of at least one step (T) with a state of at least one number (S)")
    out = {}
    for name, spec in {**fields, **{q: QUERY_FIELDS[q] for q in present}}.items():
        out[name] = _check_field(name, np.asarray(arrays[name]), spec, n, t, s, actions, reference, soft_labels)
    if TASK_FIELD in arrays:
        task = np.asarray(arrays[TASK_FIELD])
        if task.ndim != 1 or task.shape[0] != n:
            raise ValueError(f"field {TASK_FIELD!r} must have shape [N={n}] (one task id per context), got "
                             f"{list(task.shape)}")
        if task.dtype.kind not in "iu":
            raise ValueError(f"field {TASK_FIELD!r} must hold integer task ids, got dtype {task.dtype}")
        out[TASK_FIELD] = task.astype(np.int64)
    return out


def split_rows(task: np.ndarray | None, n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, val rows), task-major and stable, with a seeded share of the tasks held out for val.

    Without task ids every row is its own task.
    """
    if not 0 <= val_fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    ids = np.arange(n) if task is None else task
    tasks = np.unique(ids)
    n_val = 0 if val_fraction == 0 else max(1, round(val_fraction * len(tasks)))
    if n_val >= len(tasks):
        unit = "rows (no task_index given)" if task is None else f"tasks in field {TASK_FIELD!r}"
        raise ValueError(f"val_fraction {val_fraction} leaves no training data: only {len(tasks)} {unit}; "
                         "pass val_fraction 0 or import more tasks")
    val_tasks = tasks[np.random.default_rng(seed).permutation(len(tasks))[:n_val]]
    is_val = np.isin(ids, val_tasks)
    order = np.argsort(ids, kind="stable")
    return order[~is_val[order]], order[is_val[order]]


def _rows_per_task(task: np.ndarray) -> dict[str, int]:
    if task.size == 0:
        return {"min": 0, "max": 0}
    counts = np.unique(task, return_counts=True)[1]
    return {"min": int(counts.min()), "max": int(counts.max())}


@dataclass
class ImportSummary:
    path: Path
    kind: str
    manifest_info: dict[str, Any]

    def __str__(self) -> str:
        i = self.manifest_info
        spec = f"{i['action_size']} discrete actions" if i["discrete"] else f"action dim {i['action_size']}"
        lines = [f"imported {sum(i['contexts'].values())} {self.kind} contexts (T={i['context_length']}, "
                 f"S={i['state_dim']}, {spec}) into {self.path}"]
        for split in ("train", "val"):
            tasks = f", {i['tasks'][split]} tasks" if i["has_task_index"] else ""
            balance = i["label_balance"][split]
            labels = "no labels" if balance is None else f"preferred=1 in {100 * balance:.1f}% of labels"
            lines.append(f"  {split}: {i['contexts'][split]} contexts{tasks}, {labels}")
        if i["has_task_index"]:
            r = i["rows_per_task"]["train"]
            lines.append(f"  rows per task (train): {r['min']}-{r['max']}")
        else:
            lines.append(f"  no {TASK_FIELD!r}: each row is its own task (pairs=True will refuse this dataset)")
        return "\n".join(lines)


def _guard_out_dir(out: Path, source: Path | None, overwrite: bool) -> None:
    """Refuse to replace anything that is not one of our datasets (nor a directory holding the source)."""
    if not (out.exists() or out.is_symlink()):
        return
    if not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite (overwrite=True) to replace that dataset")
    check_replaceable_dataset(out)  # the store's one check: a directory with our manifest.json, else refused
    if source is not None and source.resolve().is_relative_to(out.resolve()):
        raise FileExistsError(f"the source {source} is inside {out}; replacing the dataset would delete it")


def import_preferences(source: str | Path | Mapping[str, np.ndarray], out_dir: str | Path,
                       kind: str = "step_preference", n_actions: int | None = None, action_dim: int | None = None,
                       val_fraction: float = 0.1, seed: int = 0, overwrite: bool = False,
                       max_source_bytes: int = MAX_SOURCE_BYTES, source_rows: np.ndarray | None = None,
                       origin: Mapping[str, Any] | None = None, soft_labels: bool = False) -> ImportSummary:
    """Check ``source`` (a file, directory or dict of arrays), convert it and write it to ``out_dir``.

    Exactly one of ``n_actions`` (discrete actions, indices in [0, n_actions)) and ``action_dim``
    (continuous action vectors) is given. Raises ``ValueError`` naming the first bad field (or file),
    ``OSError`` (``io.StorageError``) naming the path when reading or writing fails (a full disk: "no
    space left on <out_dir>", with nothing left behind). ``source_rows`` ([N]) is what ``source_row`` records
    for each array row (default: the row itself), for arrays converted from another format's rows; ``origin``
    (that format, its path, what was dropped) is kept in the manifest's info. ``soft_labels``: labels may be 0.5
    (a tie), stored float32 (``icprl label --export``); only ICPO and RewardGen train on such a dataset.
    """
    if (n_actions is None) == (action_dim is None):
        raise ValueError("pass exactly one of n_actions (discrete actions) and action_dim (continuous actions)")
    size = n_actions if n_actions is not None else action_dim
    if size < 1:
        raise ValueError(f"{'n_actions' if n_actions is not None else 'action_dim'} must be >= 1, got {size}")
    actions = ActionSpec(discrete=n_actions is not None, size=int(size))
    out = Path(out_dir)
    source_path = None if isinstance(source, Mapping) else Path(source)
    _guard_out_dir(out, source_path, overwrite)
    arrays = check_arrays(source if isinstance(source, Mapping) else read_source(source, max_source_bytes), kind,
                          actions, soft_labels)
    reference = next(iter(KINDS[kind]))
    n, t, s = arrays[reference].shape
    task = arrays.get(TASK_FIELD)
    rows = dict(zip(("train", "val"), split_rows(task, n, val_fraction, seed), strict=True))
    rows_in_source = np.arange(n) if source_rows is None else np.asarray(source_rows, dtype=np.int64)
    if rows_in_source.shape != (n,):
        raise ValueError(f"source_rows must have shape [N={n}], got {list(rows_in_source.shape)}")
    splits = {split: {**{k: v[r] for k, v in arrays.items()}, SOURCE_ROW: rows_in_source[r].astype(np.int64)}
              for split, r in rows.items()}
    config = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind, "discrete": actions.discrete,
              "action_size": actions.size, "state_dim": int(s), "context_length": int(t),
              "has_task_index": task is not None, "has_query_labels": "query_states" in arrays,
              "val_fraction": val_fraction, "seed": seed, **({"soft_labels": True} if soft_labels else {})}
    info = {**config, "source": "<arrays>" if source_path is None else str(source_path),
            "contexts": {k: len(r) for k, r in rows.items()},
            "label_balance": {k: float(v["preferred"].mean()) if len(v["preferred"]) else None
                              for k, v in splits.items()}}
    if task is not None:
        info["tasks"] = {k: int(np.unique(v[TASK_FIELD]).size) for k, v in splits.items()}
        info["rows_per_task"] = {k: _rows_per_task(v[TASK_FIELD]) for k, v in splits.items()}
        info["val_tasks"] = np.unique(splits["val"][TASK_FIELD]).tolist()
    if origin is not None:
        info["origin"] = dict(origin)
    write_dataset(out, splits, config, info=info, overwrite=True)
    return ImportSummary(path=out, kind=kind, manifest_info=info)


FORMATS = ("npz", "hf", "parquet", "minari", "trl", "bpref")
EXPORT_FORMATS = ("hf", "parquet", "minari")  # `icprl export-data` exports: rebuilt exactly, with kind and actions
