"""icprl_lightning: in-context preference-based reinforcement learning with PyTorch Lightning."""

from icprl_lightning.contexts import (
    RewardContext,
    RewardTrajectoryContext,
    StepPreferenceContext,
    TrajectoryPreferenceContext,
)
from icprl_lightning.deploy import Agent, load_agent

__version__ = "0.1.0"
__all__ = ["Agent", "RewardContext", "RewardTrajectoryContext", "StepPreferenceContext", "TrajectoryPreferenceContext",
           "load_agent"]
