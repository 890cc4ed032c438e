"""The one extension point: a task family and its privileged oracle (DESIGN.md, "Task families").

The generic recipes of ``icprl_lightning.data.settings`` need from a family only what ``TaskFamily`` and
``Oracle`` declare here, so a new environment is one class of each (``docs/extending.md``). ``Family`` is
what every family has, MDP or not (the dueling bandits are a ``Family`` with their own setting).

Base classes rather than ``typing.Protocol``: jsonargparse accepts a Protocol only when every method's
signature matches it exactly, which makes a user's family fail with an opaque "does not implement
protocol"; a subclass gets the defaults below and a clear error for what it lacks.

A *mixing level* p names a behavior policy: the oracle's optimal/expert action with probability p, else a
uniform one (paper, appendix "Pretraining Data Generation"). The *utility* of an action is what Bradley–Terry
labels compare: A*(s, a) up to a per-state constant (paper, eq. (i-prl-pref)). The oracle is privileged (goals,
simulator state): ``methods/`` and ``models/`` never import a family (tested by import inspection).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from icprl_lightning.contexts import ActionSpec

QUALITIES = ("low", "medium", "high")  # context qualities: behavior policies at ≈ 20/40/80% of optimal


class Rollouts(Protocol):
    """N trajectories of a family stepping together (data generation); a context manager."""

    def observations(self) -> np.ndarray:
        """What a learner sees now: float32 [N, S] (goals hidden)."""

    def oracle_state(self) -> Any:
        """The privileged state the oracle reads (positions, goals, steps taken)."""

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply actions [N] | [N, A]; returns (observation after the action [N, S], latent reward [N])."""

    def __enter__(self) -> Rollouts: ...

    def __exit__(self, *exc: object) -> None: ...


class Oracle(ABC):
    """Privileged knowledge of a family: uniform and optimal actions, the utility of an action."""

    @abstractmethod
    def uniform_actions(self, state: Any, rng: np.random.Generator) -> np.ndarray:
        """One uniformly random action per trajectory of ``state``."""

    @abstractmethod
    def optimal_actions(self, state: Any) -> np.ndarray:
        """The optimal (or expert) action per trajectory: DPT/DP²T's labels and the mixture's good side."""

    def behavior_actions(self, state: Any, mixing: np.ndarray | float, rng: np.random.Generator) -> np.ndarray:
        """The mixed behavior policy π_p: ``optimal_actions`` with probability p (per row), else uniform.

        Draws, in order: one coin per row, then the uniform actions (the order is part of a dataset's bytes).
        """
        optimal = self.optimal_actions(state)
        follow = rng.random(len(optimal)) < np.asarray(mixing)
        uniform = self.uniform_actions(state, rng)
        return np.where(follow.reshape(-1, *[1] * (optimal.ndim - 1)), optimal, uniform)

    @abstractmethod
    def utility(self, state: Any, actions: np.ndarray) -> np.ndarray:
        """Utility of K candidate actions [K, N, ...] -> [K, N]: A*(s, a) up to a per-state constant."""

    def query_labels(self, tasks: np.ndarray, visited_states: np.ndarray, visited_optimal: np.ndarray,
                     horizon: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """DPT/DP²T supervision: ``query_states`` [N, H, S] and ``optimal_actions`` there.

        ``tasks`` [N, ...] are the rows' tasks; ``visited_states`` [N, V, S] and ``visited_optimal``
        [N, V, ...] what the context's trajectories visited. By default: H of the V visited states per
        row, without replacement and in random order (a query's position then says nothing about where
        its state sits in the context), with the optimal actions there.
        """
        n, v = visited_states.shape[:2]
        step = rng.permuted(np.tile(np.arange(v), (n, 1)), axis=1)[:, :horizon]  # [N, H]
        rows = np.arange(n)[:, None]
        return {"query_states": visited_states[rows, step], "optimal_actions": visited_optimal[rows, step]}


class Family(ABC):
    """What every family has, MDP or bandit: the sizes a model is built with and what names its data."""

    name: str = "family"         # names dataset directories
    metric_env: str = "env"      # names logged metrics: val/<metric_env>/<quality>/...
    obs_dim: int
    horizon: int                 # steps per context: the model's ``max_context``
    seed: int                    # fixes the task split and every draw of a dataset made on it

    @property
    @abstractmethod
    def action_spec(self) -> ActionSpec: ...

    @abstractmethod
    def config(self) -> dict[str, Any]:
        """Everything about the family that determines a dataset's bytes (recorded in the manifest)."""


class TaskFamily(Family):
    """An MDP family: the seeded task split, vectorized environments and the oracle. The defaults fit a family
    whose contexts are episodes of its vector env (DarkRoom overrides ``context_rollouts``)."""

    task_name: str = "tasks"     # names the stored task arrays: tasks/train_<task_name>.npy
    max_parallel: int | None = None  # at most this many trajectories simulated at once (None: all)

    @property
    def action_dtype(self) -> np.dtype:
        """How actions are stored on disk: the smallest int for discrete, float32 for continuous."""
        if not self.action_spec.discrete:
            return np.dtype(np.float32)
        return np.dtype(np.int8 if self.action_spec.size <= 127 else np.int16)

    @property
    @abstractmethod
    def oracle(self) -> Oracle: ...

    @abstractmethod
    def tasks(self, split: str) -> np.ndarray:
        """The seeded ``"train"`` or ``"test"`` (held-out) tasks, one per row; disjoint."""

    @abstractmethod
    def make_env(self, tasks: np.ndarray) -> Any:
        """A Gymnasium-style vector env with one episode per row of ``tasks``, offering ``oracle_state()``."""

    def episode_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> Rollouts:
        """Episodes of ``make_env(tasks)`` (T-PRL pairs): reset with a seed drawn from ``rng``."""
        return EnvRollouts(self.make_env(tasks), rng)

    def context_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> Rollouts:
        """H steps of the behavior process per row, for I-PRL and reward contexts: one episode each."""
        return self.episode_rollouts(tasks, rng)

    def independent_state_rollouts(self, tasks: np.ndarray, rng: np.random.Generator) -> Rollouts:
        """H steps per row whose state is drawn afresh at every step, independently of the task and of the
        actions taken (``state_source="uniform"``): a model can then read the task only from the labels (or
        rewards) of its context. ``step`` returns where the action leads; the next ``observations()`` are a
        new draw. A family that can place its simulator in a drawn state overrides this.
        """
        raise NotImplementedError(
            f"{type(self).__name__} does not draw states independently of its trajectories: "
            "state_source='uniform' needs the family to implement independent_state_rollouts(tasks, rng); "
            "use state_source='rollout'")

    def calibrate(self, targets: Mapping[str, float], episodes: int, seed: int) -> dict[str, dict[str, float]]:
        """Mixing level per named target share of the optimal return: ``{name: {"mixing": p, ...}}``, by
        simulation (``calibration.calibrate_by_simulation``). The built-in families override it, each giving its
        reason, tested to agree with this simulation within its noise."""
        from icprl_lightning.families.calibration import calibrate_by_simulation

        return calibrate_by_simulation(self, targets, episodes, seed)

    def references(self, tasks: np.ndarray, mixing: Mapping[str, float], episodes: int,
                   rng: np.random.Generator) -> dict[str, Any]:
        """Held-out references ``{"test_reference": {quality: {...}}, ...}`` by simulation
        (``calibration.references_by_simulation``; overridden as ``calibrate`` is)."""
        from icprl_lightning.families.calibration import references_by_simulation

        return references_by_simulation(self, tasks, mixing, episodes, rng)

    def reference_groups(self, qualities: tuple[str, ...]) -> list[tuple[str, ...]]:
        """Which qualities' references are measured together, each group after its last evaluation split."""
        return [tuple(qualities)]

    def normalizer(self, info: Mapping[str, Any], quality: str, task_index: np.ndarray) -> Callable:
        """Maps returns [B] of episodes on held-out tasks ``task_index`` to normalized returns.

        (R − R_uniform) / (R_optimal − R_uniform) with each episode's own task's references when the
        manifest has them per task (Meta-World's "optimal" is its expert: ``expert_return``), else
        R / R_optimal (DarkRoom's closed-form optimum).
        """
        per_task = info.get("test_reference_per_task")
        if per_task is None:
            optimal = info["test_reference"][quality]["optimal_return"]
            return lambda returns: returns / optimal
        uniform = np.asarray(per_task["uniform_return"])[task_index]
        best = np.asarray(per_task.get("optimal_return", per_task.get("expert_return")))[task_index]
        return lambda returns: (returns - uniform) / (best - uniform)


class EnvRollouts:
    """``Rollouts`` over a family's vector env (offering ``oracle_state()``): reset once with a seed drawn from
    ``rng``, then step."""

    def __init__(self, env: Any, rng: np.random.Generator) -> None:
        self.env = env
        self._obs, _ = env.reset(seed=int(rng.integers(2**31)))

    def observations(self) -> np.ndarray:
        return self._obs

    def oracle_state(self) -> Any:
        return self.env.oracle_state()

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._obs, reward, *_ = self.env.step(actions)
        return self._obs, reward

    def __enter__(self) -> EnvRollouts:
        return self

    def __exit__(self, *exc: object) -> None:
        if hasattr(self.env, "close"):
            self.env.close()
