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

Cross-fitting (``cross_fit_checkpoints``). A RewardGen fitted on the training tasks labels their trajectories
in-sample: it has seen those tasks' pairs, so its labels are sharper than those it gives an unseen test task
at deployment, and T^R would learn on better labels than it acts on. With k ≥ 2 RewardGens, checkpoint i
trained with ``--data.init_args.folds k --data.init_args.holdout_fold i`` (``data/datamodule.py``: the
tasks t with t % k == i left out), each row of training task t is labeled by model t % k, which never saw
task t; the batch's ``task`` field says which (only the rows of fold i go through model i). The fold
settings are read from each checkpoint (the DataModule's record, ``FOLDS_RECORD``) and a list out of order
or of other k is refused. The k models are copied into this module like R_ψ (``cross_fit_hparams``).
Deployment is unchanged: ``reward_gen_checkpoint``, fitted on every training task, labels the test tasks.
Without ``cross_fit_checkpoints`` R_ψ labels in-sample, as before.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from icprl_lightning.checkpoints import hyperparameters, read_checkpoint
from icprl_lightning.contexts import ActionSpec, RewardTrajectoryContext, TrajectoryPreferenceContext
from icprl_lightning.deploy import Agent
from icprl_lightning.methods.dit import DITModule
from icprl_lightning.methods.reward_gen import RewardGenModule
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.estimator import InContextRewardModel
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError

# R_ψ's architecture: what ``InContextRewardModel`` is built from besides the data's sizes (the backbone as a dict)
ARCHITECTURE = ("backbone", "max_context", "causal", "reward_range", "normalize_inputs")


# where a fit's checkpoint holds PreferenceDataModule's state_dict, its fold settings (Lightning names the
# entry by the DataModule's class; methods/ may not import data/, so the name is written here)
FOLDS_RECORD = "PreferenceDataModule"


def read_reward_gen(checkpoint: str, field: str = "reward_gen_checkpoint"
                    ) -> tuple[dict[str, Any], dict[str, Tensor], tuple[Any, Any] | None]:
    """A RewardGen checkpoint's hyperparameters, R_ψ's weights and its data's (folds, holdout_fold) (None if
    the checkpoint holds no record), read from the file; errors start with ``field``.

    Read directly rather than through ``RewardGenModule.load_from_checkpoint``: inside LightningCLI's
    instantiation, a module built there would record the CLI's (ICRG's) hyperparameters as its own. Read as
    untrusted, like every checkpoint (``checkpoints.py``: ``weights_only=True``, class and checksum checked).
    """
    try:
        ckpt = read_checkpoint(checkpoint, expected=RewardGenModule)
    except ValueError as e:
        raise ValueError(f"{field}: {e} (train one with configs/reward_gen_darkroom.yaml or "
                         "configs/reward_gen_metaworld.yaml)") from None
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{field}: {e}") from None
    prefix = "reward."
    weights = {k[len(prefix):]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
    record = ckpt.get(FOLDS_RECORD)
    folds = (record.get("folds"), record.get("holdout_fold")) if isinstance(record, dict) else None
    return hyperparameters(ckpt), weights, folds


def check_stage1(checkpoint: str, hparams: dict[str, Any], sizes: dict[str, Any]) -> dict[str, Any]:
    """R_ψ's architecture, after checking the checkpoint was trained on data of these ``sizes``."""
    for key, mine in sizes.items():
        if hparams[key] != mine:
            raise ValueError(f"{checkpoint} was trained with {key}={hparams[key]}, this data has {key}={mine}")
    # a RewardGen saved before its reading rule existed has no ``causal``: it read the whole context (the default)
    return {k: hparams[k] for k in ARCHITECTURE if k in hparams}


def reward_architecture(architecture: Any) -> dict[str, Any]:
    """A RewardGen architecture (``ARCHITECTURE``) as this module saves it: its backbone a plain dict (checked)."""
    if not isinstance(architecture, dict) or "backbone" not in architecture or set(architecture) - set(ARCHITECTURE):
        got = sorted(architecture) if isinstance(architecture, dict) else repr(architecture)
        raise HyperparameterError(f"ICRGModule: a RewardGen architecture is a dict of {list(ARCHITECTURE)} (backbone "
                                  f"required), got {got}")
    return {**architecture, "backbone": TransformerConfig.coerce(architecture["backbone"]).as_dict()}


def build_reward_model(state_dim: int, action_spec: ActionSpec, architecture: dict[str, Any]) -> InContextRewardModel:
    """R_ψ built from its architecture (``reward_architecture``)."""
    architecture = reward_architecture(architecture)
    backbone = TransformerConfig(**architecture["backbone"])
    return InContextRewardModel(state_dim, action_spec, **{**architecture, "backbone": backbone})


def read_cross_fit(checkpoints: Any, sizes: dict[str, Any]) -> tuple[list[dict[str, Any]], list[dict[str, Tensor]]]:
    """The k RewardGens of cross-fitting (architectures, weights): entry i must hold out fold i of k."""
    field = "cross_fit_checkpoints"
    if not isinstance(checkpoints, list | tuple) or len(checkpoints) < 2:
        raise HyperparameterError(f"ICRGModule: {field} must be a list of k >= 2 RewardGen checkpoints, entry i "
                                  "trained with --data.init_args.folds k --data.init_args.holdout_fold i, got "
                                  f"{checkpoints!r}")
    k, archs, weights = len(checkpoints), [], []
    for i, path in enumerate(checkpoints):
        hparams, w, folds = read_reward_gen(path, f"{field}[{i}]")
        if folds != (k, i):
            got = ("records no fold settings (not trained by PreferenceDataModule with folds / holdout_fold)"
                   if folds is None else f"was trained with folds={folds[0]}, holdout_fold={folds[1]}")
            raise ValueError(f"{field}[{i}]: {path} {got}; entry {i} of {k} must be trained with "
                             f"--data.init_args.folds {k} --data.init_args.holdout_fold {i}")
        archs.append(check_stage1(path, hparams, sizes))
        weights.append(w)
    return archs, weights


class ICRGModule(DITModule):
    """DIT on RewardGen's labels; see the module docstring.

    Args:
        reward_gen_checkpoint: a ``RewardGenModule`` checkpoint trained on the same task family (stage 1).
        reward_gen_hparams: R_ψ's architecture; filled in from the checkpoint and saved with this module
            (set it only to build the module without the file).
        cross_fit_checkpoints: k >= 2 RewardGen checkpoints, entry i trained with ``folds: k, holdout_fold: i``
            on the same data; each training row of task t is then labeled by entry t % k (module docstring).
        cross_fit_hparams: their architectures; filled in from the files and saved like ``reward_gen_hparams``.
        Other arguments as ``DITModule``.

    Its policy conditions on reward trajectories, but it trains on T-PRL pairs (which R_ψ labels), each
    with another pair of its task (``data.pairs: true``).
    """

    consumes = ("trajectory_preference",)
    needs_pairs = True

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 reward_gen_checkpoint: str | None = None, reward_gen_hparams: dict[str, Any] | None = None,
                 cross_fit_checkpoints: list[str] | None = None,
                 cross_fit_hparams: list[dict[str, Any]] | None = None, gamma: float = 0.95, eta: float = 1.0,
                 max_weight: float = 20.0, value_epochs: int = 2, backbone: TransformerConfig = DEFAULT_BACKBONE,
                 optimizer: OptimizerConfig = DEFAULT_OPTIMIZER, center_advantages: bool = True,
                 advantage: str = "q_minus_v", normalize_inputs: bool = False) -> None:
        if advantage == "oracle":
            raise HyperparameterError("ICRGModule: advantage 'oracle' reads the oracle's A*, which a preference "
                                      "method never receives; it is for DIT on true rewards (DITModule)")
        super().__init__(state_dim, action_dim, discrete, max_context, gamma=gamma, eta=eta, max_weight=max_weight,
                         value_epochs=value_epochs, backbone=backbone, optimizer=optimizer,
                         center_advantages=center_advantages, advantage=advantage, normalize_inputs=normalize_inputs)
        weights = None
        sizes = {"state_dim": state_dim, "action_dim": action_dim, "discrete": discrete}
        if reward_gen_hparams is None:
            if reward_gen_checkpoint is None:
                raise ValueError("ICRG needs reward_gen_checkpoint: a RewardGenModule checkpoint (stage 1, "
                                 "configs/reward_gen_darkroom.yaml or configs/reward_gen_metaworld.yaml)")
            stage1, weights, folds = read_reward_gen(reward_gen_checkpoint)
            if folds is not None and folds[1] is not None:
                raise ValueError(f"reward_gen_checkpoint: {reward_gen_checkpoint} was trained with holdout_fold="
                                 f"{folds[1]} (fold {folds[1]} of {folds[0]} left out); the deployed RewardGen is "
                                 "fitted on every training task: train it without --data.init_args.holdout_fold "
                                 "(fold models go in cross_fit_checkpoints)")
            reward_gen_hparams = check_stage1(reward_gen_checkpoint, stage1, sizes)
        reward_gen_hparams = self.hparams["reward_gen_hparams"] = reward_architecture(reward_gen_hparams)
        self.reward_gen = build_reward_model(state_dim, self.action_spec, reward_gen_hparams)
        if weights is not None:
            self.reward_gen.load_state_dict(weights)
        self.reward_gen.requires_grad_(False)
        fold_weights = None
        if cross_fit_hparams is None and cross_fit_checkpoints is not None:
            cross_fit_hparams, fold_weights = read_cross_fit(cross_fit_checkpoints, sizes)
            self.hparams["cross_fit_hparams"] = cross_fit_hparams
        self.cross_fit: nn.ModuleList | None = None
        if cross_fit_hparams is not None:
            if not isinstance(cross_fit_hparams, list | tuple) or len(cross_fit_hparams) < 2 or not all(
                    isinstance(h, dict) for h in cross_fit_hparams):
                raise HyperparameterError("ICRGModule: cross_fit_hparams must be a list of k >= 2 architectures "
                                          f"(dicts, filled in from cross_fit_checkpoints), got {cross_fit_hparams!r}")
            cross_fit_hparams = self.hparams["cross_fit_hparams"] = [reward_architecture(h) for h in cross_fit_hparams]
            self.cross_fit = nn.ModuleList(build_reward_model(state_dim, self.action_spec, h)
                                           for h in cross_fit_hparams)
            for model, w in zip(self.cross_fit, fold_weights or [], strict=False):
                model.load_state_dict(w)
            self.cross_fit.requires_grad_(False)

    def train(self, mode: bool = True):
        super().train(mode)
        self.reward_gen.eval()  # frozen: no dropout while it labels
        if self.cross_fit is not None:
            self.cross_fit.eval()
        return self

    def on_train_start(self) -> None:
        # Lightning (>= 2.2) keeps each submodule's mode through fit and never calls train() on the whole module,
        # so the override above alone would leave the labelers' dropout on; here, not in __init__, so that fit's
        # "modules in eval mode at the start of training" warning (checked just before this hook) stays quiet
        self.train(self.training)

    def labeled_trajectories(self, batch: ContextSamples) -> tuple[RewardTrajectoryContext, RewardTrajectoryContext]:
        """The sample's two trajectories (``batch.context``) with R_ψ's labels (cross-fitted: the fold model of each
        row's task), R_ψ conditioned on another pair of their task (``batch.pair``)."""
        pair, context = batch.context, batch.pair
        h = pair.states_a.shape[1]
        with torch.no_grad():
            r = self.label(batch, context, torch.cat([pair.states_a, pair.states_b], 1),
                           torch.cat([pair.actions_a, pair.actions_b], 1))
        return (RewardTrajectoryContext(pair.states_a, pair.actions_a, r[:, :h]),
                RewardTrajectoryContext(pair.states_b, pair.actions_b, r[:, h:]))

    def label(self, batch: ContextSamples, context: TrajectoryPreferenceContext, states: Tensor,
              actions: Tensor) -> Tensor:
        """Standardized rewards (B, Q) of ``states`` (B, Q, S), ``actions``: R_ψ's, or with cross-fitting each
        row's by the model of its task's fold (``batch.task % k``), each model on its own rows only."""
        if self.cross_fit is None:
            return self.reward_gen.label(context, states, actions)
        if batch.task is None:  # recorded data serves no task index, and the pairing check does not see this
            raise ValueError("ICRG with cross_fit_checkpoints labels each row with the RewardGen not fitted on its "
                             "task, so its samples need task, the training-task index, which this data does not "
                             "serve (PreferenceDataModule serves it with an MDP setting)")
        fold = batch.task % len(self.cross_fit)
        rewards = None
        for i, model in enumerate(self.cross_fit):
            rows = torch.nonzero(fold == i).squeeze(1)
            if len(rows) == 0:
                continue
            out = model.label(context.map(lambda x, rows=rows: x[rows]), states[rows], actions[rows])
            if rewards is None:
                rewards = out.new_empty((states.shape[0], *out.shape[1:]))
            rewards[rows] = out
        return rewards

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None, compile: bool = False
                   ) -> ICRGAgent:
        return ICRGAgent(self.reward_gen, Agent(self.policy, greedy=greedy, use_cache=use_cache, seed=seed,
                                                compile=compile))


class ICRGAgent:
    """ICRG deployed on B tasks: ``reset`` labels the context's behavior trajectory, ``act`` runs T^R on it."""

    def __init__(self, reward_model: InContextRewardModel, policy_agent: Agent) -> None:
        self.reward_model = reward_model
        self.policy_agent = policy_agent
        self.labeled_context: RewardTrajectoryContext | None = None

    # what Agent exposes, for the context this agent takes (trajectory pairs and a behavior trajectory)
    obs_dim = property(lambda self: self.policy_agent.obs_dim, doc="S, as ``Agent.obs_dim``")
    action_spec = property(lambda self: self.policy_agent.action_spec, doc="as ``Agent.action_spec``")
    max_context = property(lambda self: self.policy_agent.max_context, doc="the most behavior steps reset accepts")
    context_kind = property(lambda self: "trajectory_preference", doc="reset takes a TrajectoryPreferenceContext")

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
