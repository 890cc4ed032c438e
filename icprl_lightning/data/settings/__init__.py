"""Data recipes (settings), each written once for every family: I-PRL step preferences, T-PRL trajectory
pairs, DPT reward contexts, DIT reward trajectories; and the dueling bandits' own recipe."""

from icprl_lightning.data.settings.bandit_duels import BanditDuels
from icprl_lightning.data.settings.base import MDPSetting
from icprl_lightning.data.settings.reward_contexts import RewardContexts
from icprl_lightning.data.settings.step_preferences import StepPreferences
from icprl_lightning.data.settings.trajectory_pairs import RewardTrajectories, TrajectoryPairs

__all__ = ["BanditDuels", "MDPSetting", "RewardContexts", "RewardTrajectories", "StepPreferences", "TrajectoryPairs"]
