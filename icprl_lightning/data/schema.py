"""The whole-dataset check: every split's fields against the schema of the contexts they hold, before training.

A field's *role* (state, action, label, reward, row index) is declared once here, by name; from the roles and
what the model was built for (``DatasetSchema``) follow the dtypes, shapes and value ranges every split must
meet, generated or imported. The shape and dtype rules read the ``.npy`` headers only; the value rules read
every value once, in blocks of rows (``_CHUNK_VALUES``), so a memory-mapped dataset is streamed, never copied
whole. Any violation is one ``InvalidDatasetError`` naming the dataset, the split and the field.

**Magnitudes are refused, not standardized.** ``|x| > 1e6`` in a state, reward or continuous action means
unscaled units or a sentinel (1e30 for "missing"): the models take these values raw through linear
layers, so such inputs saturate attention and LayerNorm and train to NaN weights, and a standardization
learnt from the data would have to travel with every checkpoint and be applied to each deployment
context by ``Agent.reset``. No family of this project comes near the bound (DarkRoom cells are 0..9,
Meta-World positions are metres, rewards are distances), and 1e6 squared (LayerNorm variances, squared
errors) is still far inside float32's range. Rescale such data before ``icprl import``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from icprl_lightning.contexts import ActionSpec
from icprl_lightning.data.store import InvalidDatasetError, StoredDataset

MAX_MAGNITUDE = 1e6  # |x| bound of states, rewards and continuous actions: see the module docstring
_CHUNK_VALUES = 1 << 22  # values per vectorized block: bounds the temporary memory on large datasets

STATE, ACTION, LABEL, REWARD, INDEX = "state", "action", "label", "reward", "index"
ROLES: dict[str, str] = {
    **dict.fromkeys(("states", "next_states", "states_a", "states_b", "behavior_states", "query_states"), STATE),
    **dict.fromkeys(("actions", "alt_actions", "actions_a", "actions_b", "behavior_actions", "optimal_actions",
                     "next_actions", "next_alt_actions"), ACTION),
    "preferred": LABEL,
    **dict.fromkeys(("rewards", "rewards_a", "rewards_b", "behavior_rewards", "advantages_a", "advantages_b"),
                    REWARD),
    **dict.fromkeys(("task_index", "quality", "source_row"), INDEX),
}
_ROLE_ORDER = (STATE, ACTION, LABEL, REWARD, INDEX)
PER_STEP_LABELS = ("step_preference",)  # kinds whose ``preferred`` is [N, T] (one label per step), not [N]


@dataclass(frozen=True)
class DatasetSchema:
    """What a model built for the data expects of it.

    Args:
        kind: the context kind (``contexts.CONTEXT_TYPES``); it says whether ``preferred`` is per step.
        actions: the action spec.
        state_dim: S of every state field (None: only equal across the fields of a split).
        max_steps: the longest context T the model takes (its ``max_context``); None: unbounded.
        soft_labels: labels are float32 in {0, 0.5, 1} (ties kept as 0.5: ``icprl label --export``), not uint8.
    """

    kind: str
    actions: ActionSpec
    state_dim: int | None = None
    max_steps: int | None = None
    soft_labels: bool = False

    def per_step(self, name: str) -> bool:
        role = ROLES.get(name)
        return role in (STATE, ACTION, REWARD) or (role == LABEL and self.kind in PER_STEP_LABELS)

    def expected(self, name: str) -> tuple[int, str]:
        """(number of axes, description) of a schema field, e.g. ``(3, "[N, T, S=2] float32")``."""
        role = ROLES[name]
        lead = "N, T" if self.per_step(name) else "N"
        s = "S" if self.state_dim is None else f"S={self.state_dim}"
        if role == STATE:
            return 3, f"[{lead}, {s}] float32"
        if role == ACTION and not self.actions.discrete:
            return 3, f"[{lead}, A={self.actions.size}] float32"
        if role == ACTION:
            return 2, f"[{lead}] integer action indices in [0, {self.actions.size})"
        if role == LABEL:
            return lead.count(",") + 1, (f"[{lead}] float32 labels in {{0, 0.5, 1}}" if self.soft_labels
                                         else f"[{lead}] uint8 labels in {{0, 1}}")
        if role == REWARD:
            return 2, f"[{lead}] float32"
        return 1, f"[{lead}] integer"


def check_dataset(dataset: StoredDataset, schema: DatasetSchema, hint: str) -> None:
    """Check every split of ``dataset`` against ``schema``; see the module docstring."""
    check_splits(dataset.splits, schema, str(dataset.path), hint)


def check_splits(splits: Mapping[str, Mapping[str, np.ndarray]], schema: DatasetSchema, where: str,
                 hint: str | None = None) -> None:
    """As ``check_dataset``, for ``{split: {field: array}}`` (e.g. before they are written); ``where`` names them.

    Every split's shapes and dtypes are checked before any value is read, so a malformed split is found
    without scanning the data before it.
    """
    fix = f". To fix: {hint}." if hint else ""

    def fail(split: str, name: str, x: np.ndarray, problem: str) -> InvalidDatasetError:
        return InvalidDatasetError(f"Dataset {where}: split {split!r}, field {name!r} ({split}/{name}.npy, shape "
                                   f"{list(x.shape)}, dtype {x.dtype}) {problem}{fix}")

    for split, arrays in splits.items():
        problem = _structure_problem(arrays, schema)
        if problem is not None:
            name, text = problem
            raise fail(split, name, arrays[name], text)
    for split, arrays in splits.items():
        for name, x in arrays.items():
            text = _value_problem(name, x, schema)
            if text is not None:
                raise fail(split, name, x, text)


def _structure_problem(arrays: Mapping[str, np.ndarray], schema: DatasetSchema) -> tuple[str, str] | None:
    """(field, what is wrong) with a split's dtypes and shapes, from the headers only; None if nothing."""
    for name, x in arrays.items():
        if x.dtype.kind not in "biuf":
            return name, f"has a non-numeric dtype; expected numbers ({_description(name, schema)})"
    known = [name for name in arrays if name in ROLES]
    if not known:  # not a split of contexts (the task split): numbers only
        return None
    for name, x in arrays.items():
        if x.ndim == 0:
            return name, f"is a scalar; expected one row per context ({_description(name, schema)})"
    # the references of N, T and S: the first fields with the axes their role expects
    known.sort(key=lambda name: _ROLE_ORDER.index(ROLES[name]))  # states first: the fields a context is built on
    shaped = [name for name in known if arrays[name].ndim == schema.expected(name)[0]] or known
    reference = shaped[0]
    n = arrays[reference].shape[0]
    steps = [name for name in shaped if schema.per_step(name)]
    t = arrays[steps[0]].shape[1] if steps else None
    sizes = [name for name in shaped if ROLES[name] == STATE]
    s = schema.state_dim if schema.state_dim is not None else (arrays[sizes[0]].shape[2] if sizes else None)
    for name, x in arrays.items():
        if x.shape[0] != n:
            return name, (f"has {x.shape[0]} rows (first axis) but {reference!r} has {n}: every field of a "
                          "split holds one row per context")
        if name not in ROLES:
            continue
        ndim, expected = schema.expected(name)
        if x.ndim != ndim:
            return name, f"has {x.ndim} axes; expected {expected}"
        problem = _dtype_problem(name, x, schema)
        if problem is not None:
            return name, f"{problem}; expected {expected}"
        if schema.per_step(name) and x.shape[1] != t:
            return name, (f"has {x.shape[1]} steps (T, second axis) but {steps[0]!r} has {t}: every per-step "
                          f"field of a split holds the same steps; expected {expected}")
        if ROLES[name] == STATE and x.shape[2] != s:
            other = "the model's state size" if schema.state_dim is not None else f"{sizes[0]!r}'s"
            return name, f"has state size {x.shape[2]}, {other} is {s}; expected {expected}"
        if ROLES[name] == ACTION and not schema.actions.discrete and x.shape[2] != schema.actions.size:
            return name, f"has action size {x.shape[2]}, the model's is {schema.actions.size}; expected {expected}"
    if t == 0:
        return steps[0], "holds empty contexts (T = 0); every context needs at least one step"
    if t is not None and schema.max_steps is not None and t > schema.max_steps:
        return steps[0], (f"holds contexts of T = {t} steps, longer than the model's context of "
                          f"{schema.max_steps} steps")
    return None


def _dtype_problem(name: str, x: np.ndarray, schema: DatasetSchema) -> str | None:
    role, kind = ROLES[name], x.dtype.kind
    if role == ACTION and schema.actions.discrete:
        return None if kind in "iu" else f"has dtype {x.dtype}, not integer action indices"
    if role in (STATE, REWARD, ACTION):
        return None if x.dtype == np.float32 else f"has dtype {x.dtype}, not float32"
    if role == LABEL:
        dtype = np.float32 if schema.soft_labels else np.uint8
        return None if x.dtype == dtype else f"has dtype {x.dtype}, not {np.dtype(dtype)}"
    return None if kind in "iu" else f"has dtype {x.dtype}, not integer"


def _description(name: str, schema: DatasetSchema) -> str:
    return schema.expected(name)[1] if name in ROLES else "a numeric array"


def row_blocks(x: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, rows) blocks of about ``_CHUNK_VALUES`` values: a memory map is read block by block."""
    per_row = int(np.prod(x.shape[1:], dtype=np.int64)) if x.ndim > 1 else 1
    step = max(1, _CHUNK_VALUES // max(per_row, 1))
    for lo in range(0, len(x), step):
        yield lo, np.asarray(x[lo:lo + step])


def magnitude_problem(x: np.ndarray, bound: float | None = MAX_MAGNITUDE) -> str | None:
    """What is wrong with a floating block's values (NaN, inf, ``|x| > bound``); None if nothing."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(x) if bound is None else np.abs(x) <= bound  # NaN compares False
    if ok.all():
        return None
    nan, inf = int(np.isnan(x).sum()), int(np.isinf(x).sum())
    huge = x[np.isfinite(x) & ~ok]
    parts = [f"{nan} NaN"] * bool(nan) + [f"{inf} inf"] * bool(inf)
    if huge.size:
        parts.append(f"{huge.size} values beyond ±{bound:g} (largest {float(np.abs(huge).max()):g})")
    rule = "finite" if bound is None else f"finite with |x| <= {bound:g} (rescale the data; see data/schema.py)"
    return f"holds {' and '.join(parts)}; every value must be {rule}"


def _value_problem(name: str, x: np.ndarray, schema: DatasetSchema) -> str | None:
    """What is wrong with one field's values (read in row blocks); None if nothing."""
    role = ROLES.get(name)
    discrete = role == ACTION and schema.actions.discrete
    bounded = role in (STATE, REWARD) or (role == ACTION and not discrete)
    n_actions = schema.actions.size
    for lo, block in row_blocks(x):
        if block.size == 0:
            continue
        rows = f" (rows {lo}-{lo + len(block) - 1})"
        if x.dtype.kind == "f":
            problem = magnitude_problem(block, MAX_MAGNITUDE if bounded else None)
            if problem is not None:
                return problem + rows
        if role == LABEL:
            bad = (block != 0) & (block != 1) & ((block != 0.5) | (not schema.soft_labels))
            if bad.any():
                found = np.unique(block[bad])[:5].tolist()
                allowed = "0, 0.5 (a tie) or 1" if schema.soft_labels else "0 or 1"
                return f"must hold only {allowed} (1 = the first of the pair won); found {found}"
        if discrete and (block.min() < 0 or block.max() >= n_actions):
            bad = (block < 0) | (block >= n_actions)
            return f"holds action indices outside [0, {n_actions}): found {np.unique(block[bad])[:5].tolist()}"
    return None
