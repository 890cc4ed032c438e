"""icprl_lightning: in-context preference-based reinforcement learning with PyTorch Lightning.

The public names below are imported on first use (PEP 562 ``__getattr__``), not with the package: they
pull in torch (seconds to import), which ``icprl --help`` and a module that needs none of them (e.g. the
progress bars, the run-directory rules) should not wait for. ``from icprl_lightning import load_agent``
works as with eager imports.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.metadata
import importlib.util
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time ``__getattr__`` imports on demand
    from icprl_lightning.contexts import (
        RewardContext,
        RewardTrajectoryContext,
        StepPreferenceContext,
        TrajectoryPreferenceContext,
    )
    from icprl_lightning.deploy import Agent, load_agent
    from icprl_lightning.online import OnlineAgent
    from icprl_lightning.registry import register_evaluation, register_method

__version__ = importlib.metadata.version("icprl_lightning")  # pyproject.toml's, as installed
# public name -> the module that defines it
_EXPORTS = {
    "Agent": "icprl_lightning.deploy",
    "load_agent": "icprl_lightning.deploy",
    "OnlineAgent": "icprl_lightning.online",
    "register_method": "icprl_lightning.registry",
    "register_evaluation": "icprl_lightning.registry",
    "RewardContext": "icprl_lightning.contexts",
    "RewardTrajectoryContext": "icprl_lightning.contexts",
    "StepPreferenceContext": "icprl_lightning.contexts",
    "TrajectoryPreferenceContext": "icprl_lightning.contexts",
}


class _RegisterWithGymnasium(importlib.abc.MetaPathFinder):
    """Registers the ``icprl/`` Gymnasium ids (``families/registration.py``) right after Gymnasium is imported,
    so ``import icprl_lightning`` makes ``gymnasium.make("icprl/DarkRoom-v0")`` work, before or after
    ``import gymnasium``, without importing Gymnasium and numpy into ``icprl --help``."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            execute = spec.loader.exec_module

            def exec_module(module: Any) -> None:
                execute(module)
                importlib.import_module("icprl_lightning.families.registration")

            spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


if "gymnasium" in sys.modules:
    importlib.import_module("icprl_lightning.families.registration")
elif not any(isinstance(f, _RegisterWithGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWithGymnasium())

__all__ = ["Agent", "OnlineAgent", "RewardContext", "RewardTrajectoryContext", "StepPreferenceContext",
           "TrajectoryPreferenceContext", "load_agent", "register_evaluation",
           "register_method"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'icprl_lightning' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
