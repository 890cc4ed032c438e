"""icprl_lightning: in-context preference-based reinforcement learning with PyTorch Lightning.

The public names below are imported on first use (PEP 562 ``__getattr__``), not with the package: they
pull in torch (seconds to import), which ``icprl --help`` and a module that needs none of them (e.g. the
progress bars, the run-directory rules) should not wait for. ``from icprl_lightning import load_agent``
works as with eager imports.
"""

from __future__ import annotations

import importlib
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

__version__ = "0.1.0"
# public name -> the module that defines it
_EXPORTS = {
    "Agent": "icprl_lightning.deploy",
    "load_agent": "icprl_lightning.deploy",
    "OnlineAgent": "icprl_lightning.online",
    "RewardContext": "icprl_lightning.contexts",
    "RewardTrajectoryContext": "icprl_lightning.contexts",
    "StepPreferenceContext": "icprl_lightning.contexts",
    "TrajectoryPreferenceContext": "icprl_lightning.contexts",
}
# ``import icprl_lightning`` registers the Gymnasium ids (icprl/DarkRoom-v0, icprl/MetaWorldReach-v0): their entry
# points are strings, so this imports Gymnasium and numpy only, never torch or MuJoCo
from icprl_lightning.families import registration as _registration  # noqa: E402, F401

__all__ = ["Agent", "OnlineAgent", "RewardContext", "RewardTrajectoryContext", "StepPreferenceContext",
           "TrajectoryPreferenceContext", "load_agent"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'icprl_lightning' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
