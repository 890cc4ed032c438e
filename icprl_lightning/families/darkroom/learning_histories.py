"""Learning histories on DarkRoom: tabular Q-learning from scratch, many goals at once (the data of Algorithm
Distillation, Laskin et al. 2022, "In-context Reinforcement Learning with Algorithm Distillation").

AD's training data are the whole learning histories of a source learner, every (s_h, a_h, r_h) from its first,
uninformed episode to its last. The source is one-step tabular Q-learning (Watkins) with ε-greedy exploration
(ties broken uniformly, so the first episodes are random walks), Q(s, a) ← Q(s, a) + α (r + γ max_a' Q(s', a')
− Q(s, a)); the episode's last step is a time limit, not a terminal state, so it bootstraps too. One Q table per
goal, all N learners stepping together as integer arrays. The default knobs make the mean return rise over the
whole history (``tests/methods/test_ad.py``): AD can only distill the improvement the history shows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from icprl_lightning.families.darkroom.env import N_ACTIONS, step_reward, transition
from icprl_lightning.validation import HyperparameterError, check_int, check_interval

if TYPE_CHECKING:
    from icprl_lightning.families.darkroom.family import DarkRoomFamily


@dataclass(frozen=True)
class QLearningHistories:
    """ε-greedy tabular Q-learning on DarkRoom goals, recorded step by step (see the module docstring).

    Args:
        episodes: episodes per learning history (each H steps of the family).
        learning_rate: α of the Q update (the environment is deterministic, so a large α is stable).
        discount: γ of the Q target.
        epsilon_start / epsilon_end: the exploration rate of the first episode and after the decay.
        epsilon_decay_episodes: episodes over which ε falls linearly from ``epsilon_start`` to ``epsilon_end``.
    """

    episodes: int = 60
    learning_rate: float = 0.5
    discount: float = 0.9
    epsilon_start: float = 1.0
    epsilon_end: float = 0.05
    epsilon_decay_episodes: int = 40

    def __post_init__(self) -> None:
        owner = type(self).__name__
        check_int(owner, "episodes", self.episodes, 1)
        check_interval(owner, "learning_rate", self.learning_rate, 0.0, 1.0, closed="right")
        check_interval(owner, "discount", self.discount, 0.0, 1.0, closed="left")
        check_interval(owner, "epsilon_start", self.epsilon_start, 0.0, 1.0)
        check_interval(owner, "epsilon_end", self.epsilon_end, 0.0, 1.0)
        check_int(owner, "epsilon_decay_episodes", self.epsilon_decay_episodes, 1)

    def epsilons(self) -> np.ndarray:
        """ε of every episode [episodes]: linear from ``epsilon_start`` to ``epsilon_end``, then constant."""
        progress = np.minimum(np.arange(self.episodes) / self.epsilon_decay_episodes, 1.0)
        return self.epsilon_start + (self.epsilon_end - self.epsilon_start) * progress

    def config(self) -> dict[str, Any]:
        return {"learner": type(self).__name__, "episodes": self.episodes, "learning_rate": self.learning_rate,
                "discount": self.discount, "epsilon_start": self.epsilon_start, "epsilon_end": self.epsilon_end,
                "epsilon_decay_episodes": self.epsilon_decay_episodes}

    def run(self, family: DarkRoomFamily, goals: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """One learning history per row of ``goals`` [N, 2], every learner from an empty Q table.

        Returns ``states`` [N, E·H, 2] float32 (s_h before acting), ``actions`` [N, E·H] int64, ``rewards``
        [N, E·H] float32 and ``episode_returns`` [N, E] float32, E = ``episodes``, H the family's horizon; step
        e·H + h is step h of episode e. Every draw comes from ``rng``, in a fixed order.
        """
        if family.terminate_on_goal:
            raise HyperparameterError("QLearningHistories: DarkRoomFamily.terminate_on_goal must be false (learning "
                                      "histories are recorded under the default reward, r = 1 on every step on the "
                                      "goal), got true")
        goals = np.asarray(goals, dtype=np.int64)
        if goals.ndim != 2 or goals.shape[1] != 2:
            raise ValueError(f"goals must have shape [N, 2], got {list(goals.shape)}")
        n, horizon, size = len(goals), family.horizon, family.size
        steps = self.episodes * horizon
        q = np.zeros((n, size, size, N_ACTIONS))
        rows = np.arange(n)
        out = {"states": np.empty((n, steps, 2), dtype=np.float32),
               "actions": np.empty((n, steps), dtype=np.int64),
               "rewards": np.empty((n, steps), dtype=np.float32)}
        alpha, gamma = self.learning_rate, self.discount
        for episode, epsilon in enumerate(self.epsilons()):
            cells = family.sample_starts(goals, rng)
            for h in range(horizon):
                t = episode * horizon + h
                values = q[rows, cells[:, 0], cells[:, 1]]  # (N, 5)
                ties = values == values.max(-1, keepdims=True)
                greedy = np.argmax(ties * rng.random(values.shape), axis=-1)  # uniform among the maxima
                explore = rng.random(n) < epsilon
                actions = np.where(explore, rng.integers(0, N_ACTIONS, n), greedy)
                nxt = transition(cells, actions, size)
                reward = step_reward(nxt, goals)
                target = reward + gamma * q[rows, nxt[:, 0], nxt[:, 1]].max(-1)
                q[rows, cells[:, 0], cells[:, 1], actions] += alpha * (target - values[rows, actions])
                out["states"][:, t], out["actions"][:, t], out["rewards"][:, t] = cells, actions, reward
                cells = nxt
        out["episode_returns"] = out["rewards"].reshape(n, self.episodes, horizon).sum(-1)
        return out
