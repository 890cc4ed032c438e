"""In-Context Reward Generation (ICRG): paper section 5.3 and Algorithm "ICRG Pipeline".

1. RewardGen (``methods/reward_gen.py``) learns R_ψ(s, a | D^T) from T-PRL pairs.
2. ``ICRGModule``: the frozen R_ψ labels the pretraining trajectories and DIT (``methods/dit.py``) learns
   T^R(a | s, D^R) on those labels, with neither true rewards nor optimal actions.
3. ``ICRGAgent`` (deployment, paper "ICRG Deployment"): given (ξ⁺, ξ⁻) and an unlabeled behavior
   trajectory of the test task, R_ψ labels the behavior trajectory and T^R acts on the labeled context.

Stage 1's checkpoint is named by ``reward_gen_checkpoint``. Its weights, architecture and output
standardization are copied into this module (the architecture into ``reward_gen_hparams``), so an ICRG
checkpoint deploys on its own. Labels are computed in each training step by the frozen R_ψ rather than
once ahead of training: the same labels, without a stored copy of the dataset per reward model. R_ψ is
conditioned on *another* pair of the same task (``data.pairs: true``): as at deployment, a trajectory is
never labeled by a context that contains it.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from icprl_lightning.checkpoints import read_checkpoint
from icprl_lightning.contexts import RewardTrajectoryContext, TrajectoryPreferenceContext, context_from_batch
from icprl_lightning.deploy import Agent
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.estimator import InContextRewardModel

ARCHITECTURE = ("n_layer", "n_embd", "n_head", "max_context", "dropout")


def read_reward_gen(checkpoint: str) -> tuple[dict[str, Any], dict[str, Tensor]]:
    """A RewardGen checkpoint's hyperparameters and R_ψ's weights, read from the file.

    Read directly rather than through ``RewardGenModule.load_from_checkpoint``: inside LightningCLI's
    instantiation, a module built there would record the CLI's (ICRG's) hyperparameters as its own. Read as
    untrusted, like every checkpoint (``checkpoints.py``: ``weights_only=True``, class and checksum checked).
    """
    try:
        ckpt = read_checkpoint(checkpoint, expected=RewardGenModule)
    except ValueError as e:
        raise ValueError(f"reward_gen_checkpoint: {e} (train one with configs/reward_gen_darkroom.yaml or "
                         "configs/reward_gen_metaworld.yaml)") from None
    except FileNotFoundError as e:
        raise FileNotFoundError(f"reward_gen_checkpoint: {e}") from None
    prefix = "reward."
    weights = {k[len(prefix):]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
    return dict(ckpt["hyper_parameters"]), weights


class ICRGModule(DITModule):
    """DIT on RewardGen's labels; see the module docstring.

    Args:
        reward_gen_checkpoint: a ``RewardGenModule`` checkpoint trained on the same task family (stage 1).
        reward_gen_hparams: R_ψ's architecture; filled in from the checkpoint and saved with this module
            (set it only to build the module without the file).
        Other arguments as ``DITModule``.

    Its policy conditions on reward trajectories, but it trains on T-PRL pairs (which R_ψ labels), each
    with another pair of its task (``data.pairs: true``).
    """

    consumes = ("trajectory_preference",)
    needs_pairs = True

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int,
                 reward_gen_checkpoint: str | None = None, reward_gen_hparams: dict[str, Any] | None = None,
                 gamma: float = 0.95, eta: float = 1.0, max_weight: float = 20.0, value_epochs: int = 2,
                 n_layer: int = 3, n_embd: int = 64, n_head: int = 4, dropout: float = 0.0, lr: float = 3e-4,
                 weight_decay: float = 0.0) -> None:
        super().__init__(state_dim, action_dim, discrete, max_context, gamma, eta, max_weight, value_epochs, n_layer,
                         n_embd, n_head, dropout, lr, weight_decay)
        weights = None
        if reward_gen_hparams is None:
            if reward_gen_checkpoint is None:
                raise ValueError("ICRG needs reward_gen_checkpoint: a RewardGenModule checkpoint (stage 1, "
                                 "configs/reward_gen_darkroom.yaml or configs/reward_gen_metaworld.yaml)")
            stage1, weights = read_reward_gen(reward_gen_checkpoint)
            for key, mine in (("state_dim", state_dim), ("action_dim", action_dim), ("discrete", discrete)):
                if stage1[key] != mine:
                    raise ValueError(f"{reward_gen_checkpoint} was trained with {key}={stage1[key]}, "
                                     f"this data has {key}={mine}")
            reward_gen_hparams = {k: stage1[k] for k in ARCHITECTURE}
            self.hparams["reward_gen_hparams"] = reward_gen_hparams
        self.reward_gen = InContextRewardModel(state_dim, self.action_spec, **reward_gen_hparams)
        if weights is not None:
            self.reward_gen.load_state_dict(weights)
        self.reward_gen.requires_grad_(False)

    def train(self, mode: bool = True):
        super().train(mode)
        self.reward_gen.eval()  # frozen: no dropout while it labels
        return self

    def labeled_trajectories(self, batch: dict[str, Tensor]) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
        """The sample's two trajectories with R_ψ's labels, R_ψ conditioned on another pair of their task."""
        if "pair_states_a" not in batch:
            raise KeyError("ICRG labels a pair with RewardGen conditioned on another pair of its task: set "
                           "data.init_args.pairs: true")
        pair = context_from_batch("trajectory_preference", batch)
        context = context_from_batch("trajectory_preference", batch, prefix="pair_")
        h = pair.states_a.shape[1]
        with torch.no_grad():
            r = self.reward_gen.label(context, torch.cat([pair.states_a, pair.states_b], 1),
                                      torch.cat([pair.actions_a, pair.actions_b], 1))
        return (RewardTrajectoryContext(pair.states_a, pair.actions_a, r[:, :h]),
                RewardTrajectoryContext(pair.states_b, pair.actions_b, r[:, h:]))

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None) -> ICRGAgent:
        return ICRGAgent(self.reward_gen, Agent(self.policy, greedy=greedy, use_cache=use_cache, seed=seed))


class ICRGAgent:
    """ICRG deployed on B tasks: ``reset`` labels the context's behavior trajectory, ``act`` runs T^R on it."""

    def __init__(self, reward_model: InContextRewardModel, policy_agent: Agent) -> None:
        self.reward_model = reward_model
        self.policy_agent = policy_agent
        self.labeled_context: RewardTrajectoryContext | None = None

    @torch.no_grad()
    def reset(self, context: TrajectoryPreferenceContext) -> None:
        """Label the behavior trajectory with R_ψ(s, a | ξ⁺, ξ⁻) and condition the policy on it."""
        if not isinstance(context, TrajectoryPreferenceContext):
            raise ValueError(f"this agent takes a TrajectoryPreferenceContext, got {type(context).__name__}")
        if context.behavior_states is None:
            raise ValueError("ICRG labels the context's unlabeled behavior trajectory: set behavior_states "
                             "[B, T, S] and behavior_actions")
        policy = self.policy_agent.policy
        context = context.validate(policy.state_dim, policy.action_spec)  # normalized (e.g. float64 -> float32)
        context = context.to(self.policy_agent.device)
        rewards = self.reward_model.label(context, context.behavior_states, context.behavior_actions)
        self.labeled_context = RewardTrajectoryContext(context.behavior_states, context.behavior_actions, rewards)
        self.policy_agent.reset(self.labeled_context)

    def act(self, obs: Tensor) -> Tensor:
        """obs [B, S] -> actions [B] (discrete) | [B, A], from T^R(a | s, D^R) on the labeled context."""
        return self.policy_agent.act(obs)
