"""The extension points that files and commands name: methods and held-out evaluations, ours and a user's.

A file never names code to import. A checkpoint's ``icprl_class_path`` (a model directory's ``method``) is looked
up in ``METHODS`` as a plain string, and a name that is not registered is refused before anything is imported;
``icprl evaluate --evaluation NAME`` and an experiment file's ``evaluation: NAME`` are looked up in ``EVALUATIONS``
the same way. Each registry is the union of

* the built-in entries (fixed names, imported only when one is used);
* the entry points of its group (``icprl_lightning.methods``, ``icprl_lightning.evaluations``) of installed
  packages, as Gymnasium and pytest find their plug-ins:
  ``[project.entry-points."icprl_lightning.methods"] my_method = "my_pkg.module:MyMethod"`` registers
  ``my_pkg.module.MyMethod``; its package is imported only when a file names exactly that class;
* classes passed to ``register_method(cls)`` / ``register_evaluation(cls)`` in this process (a script, a test).

A method is keyed by its class path (what a checkpoint stores); an evaluation by its ``name`` (what a command line
and a results JSON say). What each must provide: ``docs/extending_methods.md``, ``docs/extending_evaluations.md``.
This module imports nothing of the package.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points


def class_path(cls: type) -> str:
    """``module.QualName``: the string a checkpoint stores for the class that rebuilds it."""
    return f"{cls.__module__}.{cls.__qualname__}"


class Registry:
    """Names -> classes of one extension point (see the module docstring)."""

    def __init__(self, what: str, group: str, builtins: dict[str, str], key: Callable[[type], str],
                 needs: tuple[str, ...], guide: str) -> None:
        self.what, self.group, self.builtins, self.key = what, group, builtins, key
        self.needs, self.guide = needs, guide
        self._registered: dict[str, type] = {}

    def register(self, cls: type) -> type:
        """Register ``cls`` in this process (usable as a class decorator); returns it."""
        if not isinstance(cls, type):
            raise TypeError(f"register_{self.what} takes a class, got {type(cls).__name__}")
        missing = [name for name in self.needs if getattr(cls, name, None) is None]
        if missing:
            raise TypeError(f"register_{self.what}: {cls.__name__} has no {' or '.join(missing)} ({self.guide})")
        self._registered[self.key(cls)] = cls
        return cls

    def forget(self, name: str) -> None:
        """Undo ``register`` (tests)."""
        self._registered.pop(name, None)

    def _entry_points(self) -> dict[str, EntryPoint]:
        points = entry_points(group=self.group)
        if self.key is class_path:  # keyed by the class path the entry point's value spells (module:Class)
            return {ep.value.replace(":", ".").replace(" ", ""): ep for ep in points}
        return {ep.name: ep for ep in points}

    def names(self) -> tuple[str, ...]:
        """Every registered name: built-in, installed (entry points, not imported) and registered here."""
        return tuple(dict.fromkeys([*self.builtins, *self._entry_points(), *self._registered]))

    def short_names(self, names: tuple[str, ...] | None = None) -> str:
        """The registered names' last parts, comma-separated, for error messages."""
        return ", ".join(name.rpartition(".")[2] for name in (self.names() if names is None else names))

    def get(self, name: object) -> type:
        """The class registered under ``name``; a name that is not registered is a ``ValueError`` and is never
        imported. An entry point whose object is not the class it names is refused too."""
        if not isinstance(name, str) or name not in self.names():
            raise ValueError(f"{name!r} is not a registered {self.what} ({self.short_names()}); a file never names "
                             f"code to import: install or register the {self.what} first ({self.guide})")
        if name in self._registered:
            return self._registered[name]
        if name in self.builtins:
            module, _, attr = self.builtins[name].rpartition(".")
            return getattr(importlib.import_module(module), attr)
        cls = self._entry_points()[name].load()
        if not isinstance(cls, type) or self.key(cls) != name:
            raise ValueError(f"the entry point {name!r} of group {self.group!r} loads {cls!r}, not the class it names")
        return cls


_BUILTIN_METHODS = ("icprl_lightning.methods.dpt.DPTModule", "icprl_lightning.methods.dpt.DP2TModule",
                    "icprl_lightning.methods.icpo.ICPOModule", "icprl_lightning.methods.reward_gen.RewardGenModule",
                    "icprl_lightning.methods.dit.DITModule", "icprl_lightning.methods.icrg.ICRGModule",
                    "icprl_lightning.methods.ad.ADModule")
METHODS = Registry("method", "icprl_lightning.methods", {name: name for name in _BUILTIN_METHODS}, class_path,
                   ("make_agent", "on_save_checkpoint"),
                   "subclass icprl_lightning.methods.base.InContextModule; docs/extending_methods.md")
_BUILTIN_EVALUATIONS = {"rollouts": "icprl_lightning.evaluation.heldout_rollouts.HeldOutRollouts",
                        "duels": "icprl_lightning.evaluation.weak_regret.WeakRegret",
                        "pair_accuracy": "icprl_lightning.evaluation.pair_accuracy.PairAccuracy",
                        "online": "icprl_lightning.evaluation.online_mdp.OnlineMDP",
                        "online_duels": "icprl_lightning.evaluation.online_bandit.OnlineBandit",
                        "ad": "icprl_lightning.evaluation.ad_command.ADEpisodes",
                        "comparison_budget": "icprl_lightning.evaluation.comparison_budget.ComparisonBudget"}
EVALUATIONS = Registry("evaluation", "icprl_lightning.evaluations", _BUILTIN_EVALUATIONS, lambda cls: cls.name,
                       ("name", "run", "markdown"),
                       "subclass icprl_lightning.evaluation.base.HeldOutEvaluation; docs/extending_evaluations.md")

ENTRY_POINT_GROUP = METHODS.group
BUILTIN_METHODS = _BUILTIN_METHODS
register_method = METHODS.register
register_evaluation = EVALUATIONS.register
method_names = METHODS.names
method_class = METHODS.get
short_names = METHODS.short_names
