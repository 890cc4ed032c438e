"""icprl_lightning: in-context preference-based reinforcement learning with PyTorch Lightning."""

from icprl_lightning.contexts import (
    RewardContext,
    RewardTrajectoryContext,
    StepPreferenceContext,
    TrajectoryPreferenceContext,
)
from icprl_lightning.deploy import Agent, load_agent
from icprl_lightning.online import OnlineAgent

__version__ = "0.1.0"
__all__ = ["Agent", "OnlineAgent", "RewardContext", "RewardTrajectoryContext", "StepPreferenceContext",
           "TrajectoryPreferenceContext", "load_agent"]
