"""What a person is asked to compare: one ``PairSource`` per view (``VIEWS``), drawing pairs from a family's
held-out tasks.

``build`` draws ``n`` pairs once, with its seed, as the arrays the session keeps (``queue.npz``): the compared
items in the store's field names, ``task_index``, ``goal`` (shown to the person, never in an exported context)
and ``utility_first`` / ``utility_second``, the latent ordering the answers are compared with (A*(s, a), the
latent return, or θᵀφ(arm)). ``show`` turns pair ``i`` into what the page draws; the page never sees the
utilities.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from icprl_lightning.families.darkroom.family import DarkRoomFamily

HAND = slice(0, 3)  # Meta-World's end-effector (TCP) position in the observation


def _mixing(n: int, rng: np.random.Generator) -> np.ndarray:
    """Behavior mixing levels of n episodes: from near-random to near-expert, so that pairs differ."""
    return rng.uniform(0.1, 0.9, size=n)


class PairSource:
    """Pairs of one view; subclasses set ``kind``, ``discrete``, ``action_size`` and implement the two methods."""

    kind: ClassVar[str]  # the recorded-preference kind an export writes (``data/importer.py`` KINDS)
    discrete: ClassVar[bool] = True
    action_size: ClassVar[int]
    stateless: ClassVar[bool] = False  # no state to store (a duel): no recorded dataset is exported

    def build(self, n: int, seed: int) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def show(self, arrays: dict[str, np.ndarray], i: int) -> dict[str, Any]:
        raise NotImplementedError


class DarkRoomSteps(PairSource):
    kind = "step_preference"
    action_size = DarkRoomFamily.n_actions

    def build(self, n: int, seed: int) -> dict[str, np.ndarray]:
        family, rng = DarkRoomFamily(), np.random.default_rng(seed)
        task_index = np.arange(n) % family.n_test_tasks
        goals = family.tasks("test")[task_index]
        with family.independent_state_rollouts(goals, rng) as roll:
            state, obs = roll.oracle_state(), roll.observations()
            first = family.oracle.uniform_actions(state, rng)
            second = (first + rng.integers(1, family.n_actions, size=n)) % family.n_actions  # a different action
            u = family.oracle.utility(state, np.stack([first, second]))
        return {"states": obs[:, None], "actions": first[:, None].astype(np.int8),
                "alt_actions": second[:, None].astype(np.int8), "task_index": task_index.astype(np.int32),
                "goal": goals.astype(np.float32), "utility_first": u[0], "utility_second": u[1]}

    def show(self, arrays: dict[str, np.ndarray], i: int) -> dict[str, Any]:
        return {"size": DarkRoomFamily.size, "goal": arrays["goal"][i].tolist(),
                "cell": arrays["states"][i, 0].tolist(),
                "first": int(arrays["actions"][i, 0]), "second": int(arrays["alt_actions"][i, 0])}


class TrajectoryPairs(PairSource):
    """Two behavior episodes per pair on the same held-out task, with their latent returns."""

    kind = "trajectory_preference"

    def family(self) -> Any:
        raise NotImplementedError

    def build(self, n: int, seed: int) -> dict[str, np.ndarray]:
        from icprl_lightning.data.settings.base import rollout_behavior

        family, rng = self.family(), np.random.default_rng(seed)
        tasks = family.tasks("test")
        task_index = np.arange(n) % len(tasks)
        both = np.concatenate([tasks[task_index], tasks[task_index]])
        out = rollout_behavior(family, both, _mixing(2 * n, rng), rng, episodes=True, progress=False,
                               description="labelling pairs")
        returns = out["rewards"].sum(1)
        return {"states_a": out["states"][:n], "actions_a": out["actions"][:n], "states_b": out["states"][n:],
                "actions_b": out["actions"][n:], "task_index": task_index.astype(np.int32),
                "goal": tasks[task_index].astype(np.float32), "utility_first": returns[:n],
                "utility_second": returns[n:]}


class DarkRoomTrajectories(TrajectoryPairs):
    action_size = DarkRoomFamily.n_actions

    def family(self) -> DarkRoomFamily:
        return DarkRoomFamily()

    def show(self, arrays: dict[str, np.ndarray], i: int) -> dict[str, Any]:
        return {"size": DarkRoomFamily.size, "goal": arrays["goal"][i].tolist(),
                "first": arrays["states_a"][i].astype(int).tolist(),
                "second": arrays["states_b"][i].astype(int).tolist()}


class ReachTrajectories(TrajectoryPairs):
    discrete = False
    action_size = 4

    def family(self) -> Any:
        from icprl_lightning.families.metaworld_reach.family import ReachTaskFamily

        return ReachTaskFamily(num_workers=0)

    def show(self, arrays: dict[str, np.ndarray], i: int) -> dict[str, Any]:
        def hand(states: np.ndarray) -> list:
            return np.round(states[i][:, HAND].astype(float), 4).tolist()

        return {"goal": np.round(arrays["goal"][i].astype(float), 4).tolist(), "first": hand(arrays["states_a"]),
                "second": hand(arrays["states_b"])}


class BanditDuels(PairSource):
    kind = "step_preference"
    action_size = 20
    stateless = True

    def build(self, n: int, seed: int) -> dict[str, np.ndarray]:
        from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily

        family, rng = LinearDuelingBanditFamily(n_arms=self.action_size), np.random.default_rng(seed)
        n_tasks = max(1, n // 10)
        theta = family.sample_tasks(n_tasks, rng)
        task_index = np.arange(n) % n_tasks
        first = rng.integers(0, family.n_arms, size=n)
        second = (first + rng.integers(1, family.n_arms, size=n)) % family.n_arms
        rewards = family.expected_rewards(theta)[task_index]
        rows = np.arange(n)
        return {"states": np.zeros((n, 1, 0), dtype=np.float32), "actions": first[:, None].astype(np.int8),
                "alt_actions": second[:, None].astype(np.int8), "task_index": task_index.astype(np.int32),
                "goal": theta[task_index].astype(np.float32), "features": family.features.astype(np.float32),
                "utility_first": rewards[rows, first], "utility_second": rewards[rows, second]}

    def show(self, arrays: dict[str, np.ndarray], i: int) -> dict[str, Any]:
        first, second = int(arrays["actions"][i, 0]), int(arrays["alt_actions"][i, 0])
        return {"goal": np.round(arrays["goal"][i].astype(float), 4).tolist(), "arms": [first, second],
                "first": np.round(arrays["features"][first].astype(float), 4).tolist(),
                "second": np.round(arrays["features"][second].astype(float), 4).tolist()}


VIEWS: dict[str, type[PairSource]] = {"darkroom_steps": DarkRoomSteps, "darkroom_trajectories": DarkRoomTrajectories,
                                      "reach_trajectories": ReachTrajectories, "bandit_duels": BanditDuels}
