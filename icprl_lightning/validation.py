"""Argument checks shared by the modules, settings, families and DataModules, and the CLI's pairing checks.

Every hyperparameter a user sets is range-checked where it is received (``__init__``), before any data is
generated or any weight is built, with a ``HyperparameterError`` (a ``ValueError``) naming the owner, the
key and the allowed range::

    ICPOModule: beta must be > 0, got 0

``check_pairing`` is what ``icprl fit|validate|test`` runs after instantiation and before any work (and a
method's ``on_fit_start`` again, for a fit without the CLI): the model's context kinds (``consumes``) against
the data's ``context_kind``, the data flags the model needs (``needs_pairs`` / ``needs_query_labels``) and the
held-out evaluations each callback declares in ``requires_data`` against those the data ``offers``. The data
side is read through the data contract (``data_contract.PreferenceData``): its declarations, not its class.

Ground floor: imports nothing of the package but ``contexts`` (the known kinds), ``data_contract`` and numpy.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from numbers import Integral, Real
from typing import Any

import numpy as np

from icprl_lightning.contexts import CONTEXT_TYPES
from icprl_lightning.data_contract import EVALUATIONS, PreferenceData, ReadsData, missing_members


class HyperparameterError(ValueError):
    """A constructor argument out of its range, or arguments that do not fit together; names the key."""


def hyperparameter_cause(error: BaseException) -> HyperparameterError | None:
    """The ``HyperparameterError`` behind ``error`` (jsonargparse wraps a constructor's error in its own)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, HyperparameterError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _fail(owner: str, key: str, rule: str, value: Any) -> None:
    """"ICPOModule: beta must be ..."; a group's key (owner "backbone.") reads "backbone.n_layer: must be ..."."""
    where = f"{owner}{key}:" if owner.endswith(".") else f"{owner}: {key}"
    raise HyperparameterError(f"{where} must be {rule}, got {value!r}")


def _number(owner: str, key: str, value: Any, integer: bool) -> float:
    kind = Integral if integer else Real
    if isinstance(value, bool) or not isinstance(value, (kind, np.integer if integer else np.number)):
        _fail(owner, key, "an integer" if integer else "a number", value)
    if not integer and not math.isfinite(float(value)):
        _fail(owner, key, "finite", value)
    return value


def check_int(owner: str, key: str, value: Any, minimum: int | None = 1, maximum: int | None = None) -> int:
    """``value`` is an integer in [minimum, maximum] (a bound of None is open)."""
    _number(owner, key, value, integer=True)
    if minimum is not None and value < minimum:
        _fail(owner, key, f">= {minimum}" + (f" and <= {maximum}" if maximum is not None else ""), value)
    if maximum is not None and value > maximum:
        _fail(owner, key, f"<= {maximum}" + (f" and >= {minimum}" if minimum is not None else ""), value)
    return int(value)


def check_bool(owner: str, key: str, value: Any) -> bool:
    """``value`` is True or False (not a string such as "false", not 0 or 1)."""
    if not isinstance(value, bool | np.bool_):
        _fail(owner, key, "true or false", value)
    return bool(value)


def check_positive(owner: str, key: str, value: Any) -> float:
    """``value`` is a finite number > 0."""
    _number(owner, key, value, integer=False)
    if not value > 0:
        _fail(owner, key, "> 0", value)
    return float(value)


def check_nonnegative(owner: str, key: str, value: Any) -> float:
    """``value`` is a finite number >= 0."""
    _number(owner, key, value, integer=False)
    if not value >= 0:
        _fail(owner, key, ">= 0", value)
    return float(value)


def check_interval(owner: str, key: str, value: Any, low: float, high: float, closed: str = "both") -> float:
    """``value`` lies in the interval from ``low`` to ``high``; ``closed``: "both", "left", "right", "neither"."""
    _number(owner, key, value, integer=False)
    left, right = closed in ("both", "left"), closed in ("both", "right")
    ok = (value >= low if left else value > low) and (value <= high if right else value < high)
    if not ok:
        _fail(owner, key, f"in {'[' if left else '('}{low}, {high}{']' if right else ')'}", value)
    return float(value)


def check_choice(owner: str, key: str, value: Any, choices: Iterable[Any]) -> Any:
    choices = tuple(choices)
    if value not in choices:
        _fail(owner, key, f"one of {list(choices)}", value)
    return value


def check_increasing(owner: str, key: str, values: Sequence[Any], low: float, high: float,
                     length: int | None = None) -> tuple[float, ...]:
    """``values`` strictly increasing, each strictly inside (low, high), ``length`` of them when given."""
    try:
        values = tuple(values)
    except TypeError:
        _fail(owner, key, "a sequence", values)
    if length is not None and len(values) != length:
        _fail(owner, key, f"{length} values", list(values))
    for v in values:
        _number(owner, key, v, integer=False)
    if any(not low < v < high for v in values):
        _fail(owner, key, f"values strictly inside ({low}, {high})", list(values))
    if any(b <= a for a, b in zip(values, values[1:], strict=False)):
        _fail(owner, key, "strictly increasing (low < medium < high)", list(values))
    return tuple(float(v) for v in values)


def check_range(owner: str, key: str, value: Any) -> tuple[float, float] | None:
    """``value`` is None or two finite numbers [low, high] with low < high."""
    if value is None:
        return None
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) != 2:
        _fail(owner, key, "null or a list [low, high]", value)
    low, high = (float(_number(owner, key, v, integer=False)) for v in value)
    if not low < high:
        _fail(owner, key, "[low, high] with low < high", list(value))
    return low, high


def check_sizes(owner: str, state_dim: Any, action_dim: Any) -> None:
    check_int(owner, "state_dim", state_dim, 0)
    check_int(owner, "action_dim", action_dim, 1)


def check_kind(owner: str, key: str, kind: Any) -> str:
    return check_choice(owner, key, kind, CONTEXT_TYPES)


# ---- the CLI's pairing checks --------------------------------------------------------------------------

# what serves a batch field a model may read beyond its context kind's own
_ORACLE_ADVANTAGES = ("reward_trajectory data with the oracle's A* "
                      "(--data.init_args.setting.init_args.oracle_advantages true)")
_FIELD_HINTS = {"advantages_a": _ORACLE_ADVANTAGES, "advantages_b": _ORACLE_ADVANTAGES}


def consumed_kinds(model: Any) -> tuple[str, ...] | None:
    """The context kinds a method trains on: ``model.consumes``, else ``(model.context_kind,)``, else None."""
    kinds = getattr(model, "consumes", None)
    if kinds is None:
        kind = getattr(model, "context_kind", None)
        return None if kind is None else (kind,)
    return (kinds,) if isinstance(kinds, str) else tuple(kinds)


def pairing_errors(model: Any, datamodule: Any, callbacks: Iterable[Any] = ()) -> list[str]:
    """Every mismatch between the model, the data and the callbacks, one sentence each (empty: they fit)."""
    m_name, d_name = type(model).__name__, type(datamodule).__name__
    if not isinstance(datamodule, PreferenceData):
        return [f"{d_name} does not implement the data contract (icprl_lightning.data_contract.PreferenceData): "
                f"it lacks {missing_members(datamodule)}"]
    errors = []
    kinds = consumed_kinds(model)
    produced = datamodule.context_kind
    if kinds is not None and produced not in kinds:
        errors.append(f"{m_name} trains on {' or '.join(kinds)} contexts but {d_name} ({datamodule.path}) holds "
                      f"{produced} contexts: pick a method for {produced} data or a data setting of kind {kinds[0]}")
    for flag, served in (("pairs", datamodule.pairs), ("query_labels", datamodule.query_labels)):
        if getattr(model, f"needs_{flag}", False) and not served:
            errors.append(f"{m_name} (as configured) needs {d_name} with {flag}: true; set "
                          f"--data.init_args.{flag} true")
    if getattr(datamodule, "soft_labels", False) and not getattr(model, "soft_labels", False):
        errors.append(f"{d_name} ({datamodule.path}) holds soft labels (ties stored as 0.5) and {m_name} trains on "
                      "labels of 0 or 1 only: train ICPO or RewardGen on it, or export the answers again with "
                      "--ties drop")
    fields = tuple(getattr(model, "needs_batch_fields", ()))
    missing = [f for f in fields if f not in datamodule.batch_fields()]
    if missing:
        hints = sorted({_FIELD_HINTS.get(f, f) for f in missing})
        errors.append(f"{m_name} (as configured) reads the batch fields {missing}, which {d_name} does not serve: "
                      f"it needs {', '.join(hints)}")
    for cb in callbacks:
        for evaluation in cb.requires_data if isinstance(cb, ReadsData) else ():
            if evaluation not in datamodule.offers:
                errors.append(f"{type(cb).__name__} reads the held-out {evaluation} of the data, but {d_name} "
                              f"({produced} contexts) has none: it needs {EVALUATIONS.get(evaluation, evaluation)}, "
                              "or drop the callback (the default evaluation: evaluation: null)")
    return errors


def check_pairing(model: Any, datamodule: Any, callbacks: Iterable[Any] = ()) -> None:
    """Raise ``ValueError`` listing every mismatch of ``pairing_errors``."""
    errors = pairing_errors(model, datamodule, callbacks)
    if errors:
        raise HyperparameterError("the model, data and callbacks do not fit together:\n  - " + "\n  - ".join(errors))
