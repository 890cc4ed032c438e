"""The methods a checkpoint or a model directory may name: this package's own and those a user registers.

A file never names code to import. A checkpoint's ``icprl_class_path`` (a model directory's ``method``) is looked
up here as a plain string; a name that is not registered is refused before anything is imported. The registry is
the union of

* the built-in methods (``BUILTIN_METHODS``, imported by these fixed names only when one is built);
* the entry points of the group ``icprl_lightning.methods`` of installed packages, as Gymnasium and pytest find
  their plug-ins: ``[project.entry-points."icprl_lightning.methods"] my_method = "my_pkg.module:MyMethod"``
  registers ``my_pkg.module.MyMethod``; its package is imported only when a file names exactly that class;
* classes passed to ``register_method(cls)`` in this process (a notebook, a script, a test).

A registered method is a peer of the built-in ones in every command: ``icprl fit`` trains any class the config
names (LightningCLI imports the config's own ``class_path``, which the user wrote), and ``load_agent``,
``icprl export``, ``icprl evaluate`` and ``icprl reproduce`` build it from its files through this registry.
What a method must provide is in ``docs/extending_methods.md``. This module imports nothing of the package.
"""

from __future__ import annotations

import importlib
from importlib.metadata import EntryPoint, entry_points

ENTRY_POINT_GROUP = "icprl_lightning.methods"
BUILTIN_METHODS = ("icprl_lightning.methods.dpt.DPTModule", "icprl_lightning.methods.dpt.DP2TModule",
                   "icprl_lightning.methods.icpo.ICPOModule", "icprl_lightning.methods.reward_gen.RewardGenModule",
                   "icprl_lightning.methods.dit.DITModule", "icprl_lightning.methods.icrg.ICRGModule",
                   "icprl_lightning.methods.ad.ADModule")
_REGISTERED: dict[str, type] = {}


def class_path(cls: type) -> str:
    """``module.QualName``: the string a checkpoint stores for the class that rebuilds it."""
    return f"{cls.__module__}.{cls.__qualname__}"


def register_method(cls: type) -> type:
    """Register a method class in this process (usable as a class decorator); returns ``cls``.

    It must be a class with ``make_agent`` and ``on_save_checkpoint`` (``methods.base.InContextModule`` gives
    both: the agent for ``load_agent`` and the class path and checksums ``load_agent`` verifies).
    """
    if not isinstance(cls, type):
        raise TypeError(f"register_method takes a class, got {type(cls).__name__}")
    missing = [name for name in ("make_agent", "on_save_checkpoint") if not callable(getattr(cls, name, None))]
    if missing:
        raise TypeError(f"register_method: {cls.__name__} has no {' or '.join(missing)}; subclass "
                        "icprl_lightning.methods.base.InContextModule (docs/extending_methods.md)")
    _REGISTERED[class_path(cls)] = cls
    return cls


def _entry_points() -> dict[str, EntryPoint]:
    """The installed packages' methods by the class path they register (``module:Class`` -> ``module.Class``)."""
    return {ep.value.replace(":", ".").replace(" ", ""): ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def method_names() -> tuple[str, ...]:
    """Every class path a file may name: built-in, installed (entry points, not imported) and registered here."""
    return tuple(dict.fromkeys([*BUILTIN_METHODS, *_entry_points(), *_REGISTERED]))


def short_names(names: tuple[str, ...] | None = None) -> str:
    """The registered methods' class names, comma-separated, for error messages."""
    return ", ".join(name.rpartition(".")[2] for name in (method_names() if names is None else names))


def method_class(name: object) -> type:
    """The class registered under ``name``; a name that is not registered is a ``ValueError``, and is never
    imported. An entry point whose object is not the class it names is refused too."""
    if not isinstance(name, str) or name not in method_names():
        raise ValueError(f"{name!r} is not a registered method ({short_names()}); a file never names code to "
                         "import: install or register the method first (docs/extending_methods.md)")
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in BUILTIN_METHODS:
        module, _, attr = name.rpartition(".")
        return getattr(importlib.import_module(module), attr)
    cls = _entry_points()[name].load()
    if not isinstance(cls, type) or class_path(cls) != name:
        raise ValueError(f"the entry point {name!r} of group {ENTRY_POINT_GROUP!r} loads "
                         f"{cls!r}, not the class it names")
    return cls
