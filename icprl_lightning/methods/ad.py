"""Algorithm Distillation (AD; Laskin et al. 2022, "In-context Reinforcement Learning with Algorithm
Distillation"): a causal transformer trained to predict a learning algorithm's next action from its history.

Data: learning histories of a reward-driven source learner (on DarkRoom, tabular Q-learning,
``families/darkroom/learning_histories.py``), served as windows of T consecutive steps (s_h, a_h, r_h) that run
across episode boundaries (``data/learning_histories.py``). AD minimizes the cross-entropy

    L(θ) = − Σ_h log T_θ(a_h | s_h, (s_1, a_1, r_1), …, (s_{h−1}, a_{h−1}, r_{h−1}))

of every action of the window given the steps before it. The targets are the learner's own actions, not the
optimal ones: imitating the whole history, improvement included, is what makes the model improve in context
when it is deployed on an unseen goal with an empty context.

The policy is the shared ``InContextPolicy`` on a ``reward_trajectory`` context with the ``merged`` layout
(``models/policy.py``): token j holds step j's (s, a, r) plus the next state, so one plain causal pass over a
window scores all T predictions (``next_step_outputs``), and deployment appends one token per step to the KV cache.
AD sees rewards: it is a reward-based in-context baseline beside DPT and DIT, not a preference method.

Deployment (``HistoryAgent``, what ``make_agent`` and ``load_agent`` return): the context starts empty and grows by
the agent's own (s, a, r) at every step, across episodes; the model acts by sampling T_θ by default, as the paper
does (its exploration is in the sampled actions). A window holds at most ``max_context − 1`` steps, since the query
sits at the position after the last step and training scores positions 0..max_context − 1; past that the oldest
steps are dropped (``slide`` at a time) and the kept ones re-encoded.

On dueling bandits (``context_kind: step_preference``; docs/ad_bandit.md) the source learner is Double Thompson
Sampling (``families/dueling_bandit/learning_histories.py``, ``data/duel_histories.py``) and a history is its duels
and their outcomes only — token h holds (a_h, a'_h, y_h), the bandit's ``StepPreferenceContext`` with states of
width 0 — so this AD is reward-free, a competitor of ICPO asked online. The target is the next *duel*, one
categorical over the A² ordered pairs (a, a') (pair index a·A + a'), from a head of A² logits in place of the
policy's A:

    L(θ) = − Σ_h log T_θ((a_h, a'_h) | (a_1, a'_1, y_1), …, (a_{h−1}, a'_{h−1}, y_{h−1}))

A joint categorical because DTS's challenger a' is drawn from the champion a's column (it depends on a): two
independent heads would sample pairs DTS never plays, and a factorized head p(a) p(a' | a) would need a second
pass per duel; the joint keeps the policy's single head, so training (``next_step_outputs``), the KV cache and
online deployment run unchanged. ``DuelHistoryAgent`` deploys it: each round it samples a duel from T_θ, the
environment answers, and the answered duel enters its context as one token (``OnlineAgent.observe``).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from icprl_lightning.contexts import RewardTrajectoryContext, as_tensor
from icprl_lightning.deploy import Agent
from icprl_lightning.methods.base import InContextModule
from icprl_lightning.methods.losses import supervised_action_loss
from icprl_lightning.models.config import DEFAULT_BACKBONE, DEFAULT_OPTIMIZER, OptimizerConfig, TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.online import OnlineAgent, PairRule
from icprl_lightning.samples import Samples
from icprl_lightning.validation import HyperparameterError, check_choice, check_int

HISTORY_FIELDS = ("states", "actions", "rewards")
DUEL_FIELDS = ("actions", "alt_actions", "preferred")  # a duel and its outcome
HISTORY_KINDS = ("reward_trajectory", "step_preference")  # a learner's (s, a, r) steps; a dueling learner's duels


def pair_index(first: Tensor, second: Tensor, n_actions: int) -> Tensor:
    """The ordered pair (a, a') as one class a·A + a' of the duel head's A² (``divmod`` by A inverts it)."""
    return first * n_actions + second


class ADModule(InContextModule):
    """AD: next-action cross-entropy over windows of a learner's history (see the module docstring).

    ``context_kind``: ``reward_trajectory`` (a learner's (s, a, r) steps; the target is its next action) or
    ``step_preference`` (a dueling-bandit learner's duels and outcomes; the target is its next duel, the pair
    index over A² ordered pairs; discrete actions only).
    """

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 context_kind: str = "reward_trajectory", backbone: TransformerConfig = DEFAULT_BACKBONE,
                 optimizer: OptimizerConfig = DEFAULT_OPTIMIZER, normalize_inputs: bool = False) -> None:
        check_choice(type(self).__name__, "context_kind", context_kind, HISTORY_KINDS)
        if context_kind == "step_preference" and not discrete:
            raise HyperparameterError("ADModule: context_kind step_preference predicts the next duel as one of A² "
                                      "ordered pairs of discrete actions; this data's actions are continuous")
        super().__init__(context_kind, state_dim, action_dim, discrete, max_context, backbone=backbone,
                         optimizer=optimizer, normalize_inputs=normalize_inputs, layout="merged")
        if self.duels:  # one logit per ordered pair (a, a'): the policy's head, so every deployment path uses it
            self.policy.head = nn.Linear(self.backbone.n_embd, action_dim * action_dim)

    @property
    def duels(self) -> bool:
        """Whether the history is a dueling learner's duels (the target: the next pair) rather than (s, a, r)."""
        return self.context_kind == "step_preference"

    @property
    def needs_batch_fields(self) -> tuple[str, ...]:
        """The windows' own fields: data of two trajectories per row (RewardTrajectories, for DIT) holds
        states_a ... rewards_b instead, and the pairing check refuses it before a fit."""
        return DUEL_FIELDS if self.duels else HISTORY_FIELDS

    def loss(self, batch: Samples) -> tuple[Tensor, dict[str, Tensor]]:
        context = batch.context  # one window of a history [B, T, ...]
        outputs = self.policy.next_step_outputs(context)  # (B, T, A or A²): T_θ(· | s_h, steps before h)
        if self.duels:
            targets = pair_index(context.actions, context.alt_actions, self.action_spec.size)
            loss = supervised_action_loss(outputs, targets, True)
            first = outputs.unflatten(-1, (self.action_spec.size, -1)).logsumexp(-1).argmax(-1)
            return loss, {"pair_accuracy": (outputs.argmax(-1) == targets).float().mean(),
                          "first_arm_accuracy": (first == context.actions).float().mean()}
        loss = supervised_action_loss(outputs, context.actions, self.action_spec.discrete)
        metrics = {}
        if self.action_spec.discrete:
            metrics["action_accuracy"] = (outputs.argmax(-1) == context.actions).float().mean()
        return loss, metrics

    def make_agent(self, greedy: bool = False, use_cache: bool = True, seed: int | None = None, compile: bool = False,
                   slide: int = 1) -> HistoryAgent | DuelHistoryAgent:
        """A ``HistoryAgent`` (empty context, grown by ``observe``; samples a ~ T_θ by default), or on duels a
        ``DuelHistoryAgent`` (samples its next duel from T_θ; ``slide`` and ``compile`` are the step agent's)."""
        if self.duels:
            if compile or slide != 1:
                raise ValueError("compile and slide apply to AD on (s, a, r) histories; a DuelHistoryAgent grows its "
                                 "context to max_context and does not slide")
            return DuelHistoryAgent(self.policy, greedy=greedy, use_cache=use_cache, seed=seed)
        return HistoryAgent(self.policy, greedy=greedy, use_cache=use_cache, seed=seed, compile=compile, slide=slide)


class HistoryAgent(Agent):
    """An ``Agent`` whose context is its own history (s_h, a_h, r_h), grown by ``observe`` across episodes.

        agent = load_agent("ad.ckpt")            # a HistoryAgent
        agent.reset(B)                           # B tasks, empty histories (or reset(context))
        for each step: a = agent.act(obs); obs', r = env.step(a); agent.observe(obs, a, r)

    Episode boundaries need nothing: the next episode's first state is simply the next step's state. With
    ``use_cache`` each ``observe`` runs one token into the KV cache (``InContextPolicy.extend``); without it every
    output re-runs ``policy.forward`` over the whole history (the slow reference, equal to the cached one).
    ``slide``: how many of the oldest steps are dropped when the history outgrows its window of
    ``max_context − 1`` steps (1: an exact sliding window, re-encoded at every step once full; H: one re-encoding
    per episode).
    """

    context: RewardTrajectoryContext | None

    def __init__(self, policy: InContextPolicy, greedy: bool = False, use_cache: bool = True,
                 seed: int | None = None, compile: bool = False, slide: int = 1) -> None:
        if policy.context_kind != "reward_trajectory" or not policy.merged:
            raise ValueError(f"a HistoryAgent grows a reward_trajectory context in the merged layout (ADModule); "
                             f"this policy takes {policy.context_kind!r} contexts in the {policy.layout!r} layout")
        super().__init__(policy, greedy=greedy, use_cache=use_cache, seed=seed, compile=compile)
        self.slide = slide

    @property
    def slide(self) -> int:
        """Steps dropped at once when the history outgrows its window (checked as it is set: 1..``window``)."""
        return self._slide

    @slide.setter
    def slide(self, slide: int) -> None:
        self._slide = check_int("HistoryAgent", "slide", slide, 1, max(self.window, 1))

    @property
    def window(self) -> int:
        """The most steps the history holds: ``max_context − 1`` (the query takes the position after them)."""
        return self.max_context - 1

    @property
    def length(self) -> int:
        """Steps in the history so far."""
        if self.context is None:
            raise RuntimeError("call reset(batch_size) or reset(context) first")
        return self.context.states.shape[1]

    @torch.no_grad()
    def reset(self, context: RewardTrajectoryContext | int) -> None:
        """Start B tasks from an empty history (``context`` = B, an int) or from a given history (validated as by
        ``Agent.reset``, at most ``window`` steps)."""
        if isinstance(context, bool) or not isinstance(context, int | RewardTrajectoryContext):
            raise ValueError(f"reset takes a batch size (int >= 1) or a RewardTrajectoryContext, got {context!r}")
        if isinstance(context, RewardTrajectoryContext):
            super().reset(context)
            if self.length > self.window:
                steps = self.length
                self.context = None
                raise ValueError(f"context holds {steps} steps; this agent's window holds at most {self.window} "
                                 "(max_context − 1)")
            self.cache = self._encode() if self.use_cache else None
            return
        if context < 1:
            raise ValueError(f"batch_size must be >= 1, got {context}")
        d, spec = self.device, self.action_spec
        actions = (torch.zeros(context, 0, dtype=torch.int64, device=d) if spec.discrete
                   else torch.zeros(context, 0, spec.size, device=d))
        self.context = RewardTrajectoryContext(torch.zeros(context, 0, self.obs_dim, device=d), actions,
                                               torch.zeros(context, 0, device=d))
        self.cache = self.policy.empty_cache(context, d) if self.use_cache else None

    @torch.no_grad()
    def outputs(self, obs: Tensor) -> Tensor:
        """T_θ at obs [B, S] given the history so far: logits [B, n] (discrete) or means [B, A] (continuous)."""
        query = self._check_obs(obs)[:, None, :]  # (B, 1, S)
        if self.use_cache:
            return (self._compiled_query or self.policy.query)(self.cache, query)[:, 0]
        if self.length == 0:  # nothing to attend to but the query itself
            return self.policy.query(self.policy.empty_cache(query.shape[0], self.device), query)[:, 0]
        visible = torch.tensor([self.length], device=self.device)
        return self.policy(self.context, query, visible)[:, 0]

    @torch.no_grad()
    def act(self, obs: Tensor) -> Tensor:
        """obs [B, S] -> actions [B] (discrete) or [B, A] (continuous), conditioned on the history so far."""
        return self._choose(self.outputs(obs))

    @torch.no_grad()
    def observe(self, obs: Tensor, actions: Tensor, rewards: Tensor) -> None:
        """Append one step (obs [B, S], actions [B] or [B, A], rewards [B]; tensors or numpy arrays) to the history."""
        obs = self._check_obs(obs)
        columns = [as_tensor(name, x, "[B] or [B, A]") for name, x in (("actions", actions), ("rewards", rewards))]
        if any(c.dim() == 0 for c in columns):
            raise ValueError("observe: actions and rewards hold one value per task, shape [B] (or [B, A]), got a "
                             "scalar")
        step = RewardTrajectoryContext(obs[:, None], columns[0][:, None], columns[1][:, None])
        try:
            step = step.validate(self.obs_dim, self.action_spec)
        except ValueError as e:
            raise ValueError(f"observe: {e} (one step: T = 1)") from None
        if step.batch_size != self.context.batch_size:
            raise ValueError(f"observe: {step.batch_size} steps for {self.context.batch_size} tasks")
        step = step.to(self.device)
        grown = RewardTrajectoryContext(*(torch.cat([getattr(self.context, k), getattr(step, k)], dim=1)
                                          for k in HISTORY_FIELDS))
        if grown.states.shape[1] <= self.window:
            if self.use_cache:
                self.policy.extend(self.cache, step)
            self.context = grown
            return
        keep = self.window - self.slide + 1
        self.context = grown.map(lambda x: x[:, -keep:])
        self.cache = self._encode() if self.use_cache else None

    def _encode(self):
        """The KV cache of the current (non-empty) history; an empty one for an empty history."""
        if self.length == 0:
            return self.policy.empty_cache(self.context.batch_size, self.device)
        return self.policy.encode(self.context)


class DistilledPair:
    """The duel AD proposes: a pair index drawn from T_θ's A² logits (the argmax when greedy), as (a, a')."""

    discrete_only = True

    def __call__(self, agent: OnlineAgent, outputs: Tensor) -> tuple[Tensor, Tensor]:
        n = agent.policy.action_spec.size
        pair = Agent._choose(agent, outputs)  # a class of the A² pairs (Agent's: finite check, argmax or sample)
        return pair // n, pair % n


class DuelHistoryAgent(OnlineAgent):
    """AD on duels, deployed online: its context is its own answered duels (a, a', y), grown one token at a time.

        agent = load_agent("ad_bandit.ckpt")          # a DuelHistoryAgent (samples by default, as AD does)
        agent.reset(B)                                # B problems, no duels yet
        for each round: a, a2 = agent.propose(obs); agent.observe(obs, a, a2, label(a, a2))   # obs [B, 0]

    ``propose`` draws the next duel from T_θ over the A² ordered pairs (``DistilledPair``: the distilled learner
    picks both arms, so no other pair rule applies); ``act`` (and ``act_each_prefix``) give the first arm, from
    T_θ's marginal over first arms, Σ_{a'} T_θ(a, a'). ``observe`` appends one token to the KV cache
    (``OnlineAgent``); the context holds at most ``max_context`` duels, the window the model was trained on.
    """

    def __init__(self, policy: InContextPolicy, greedy: bool = False, use_cache: bool = True,
                 seed: int | None = None) -> None:
        n = policy.action_spec.size
        if not policy.merged or not policy.action_spec.discrete or policy.head.out_features != n * n:
            raise ValueError("a DuelHistoryAgent deploys AD on duels (ADModule with context_kind step_preference: "
                             "merged layout, one logit per ordered pair of discrete actions)")
        super().__init__(policy, greedy=greedy, use_cache=use_cache, seed=seed, pair_rule=DistilledPair())

    @property
    def pair_rule(self) -> PairRule:
        """Always ``DistilledPair``: AD's own duel (set to None or a ``DistilledPair``; anything else is refused)."""
        return self._pair_rule

    @pair_rule.setter
    def pair_rule(self, rule: PairRule | str | None) -> None:
        if rule is not None and not isinstance(rule, DistilledPair):
            raise ValueError(f"a DuelHistoryAgent proposes the duel AD distilled (DistilledPair); pair rule {rule!r} "
                             "does not apply to its A² pair logits")
        self._pair_rule = DistilledPair()

    def _choose(self, out: Tensor) -> Tensor:
        """Pair logits (..., A²) -> the first arm (...), argmax or a sample of T_θ's marginal over first arms."""
        n = self.policy.action_spec.size
        return super()._choose(out.unflatten(-1, (n, n)).logsumexp(-1))
