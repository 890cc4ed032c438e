"""One env per evaluation suite (``evaluation.rollout.suite_env``): reusing it gives the episodes fresh envs give.

``icprl evaluate`` and the rollout callback reset one env for every checkpoint, context diagnostic and episode
seed instead of building one each time (a Meta-World env starts worker processes, which costs more than an
episode). That is only sound if ``reset(seed=s)`` alone fixes an episode; these tests check it on DarkRoom and
on Meta-World Reach, whose resets draw puck positions, with seeds in another order than the fresh runs'.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from factories import reach_data

from icprl_lightning.evaluation import diagnose_suite, rollout_in_context, rollout_seeds, suite_env


class HashPolicy:
    """A deterministic agent whose actions depend on every observation (and on the context it is given)."""

    def __init__(self, n_actions: int | None = None, action_dim: int | None = None) -> None:
        self.n_actions, self.action_dim = n_actions, action_dim

    def reset(self, context) -> None:
        self.offset = float(context.states.float().mean())

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        mix = torch.sin(obs.float() @ torch.linspace(1.0, 3.0, obs.shape[-1]) + self.offset)
        if self.n_actions is not None:
            return ((mix + 1) * 0.5 * self.n_actions).long().clamp_max(self.n_actions - 1)
        return mix[:, None] * torch.linspace(-1.0, 1.0, self.action_dim)


def _same_episodes(suite, agent) -> dict[int, dict[str, np.ndarray]]:
    fresh = {seed: rollout_in_context(agent, suite, seed=seed) for seed in (0, 1)}
    changed = diagnose_suite(suite, "other_task")
    with suite_env(suite) as env:
        reused = {seed: rollout_in_context(agent, suite, seed=seed, env=env) for seed in (1, 0)}
        other_reused = rollout_in_context(agent, changed, seed=0, env=env)
        seeds_reused = rollout_seeds(lambda seed: agent, suite, [0, 1], env=env)
    for seed in (0, 1):
        for key, values in fresh[seed].items():
            np.testing.assert_array_equal(reused[seed][key], values, err_msg=f"{key}, seed {seed}")
    np.testing.assert_array_equal(seeds_reused["return"], np.concatenate([fresh[0]["return"], fresh[1]["return"]]))
    np.testing.assert_array_equal(other_reused["return"], rollout_in_context(agent, changed, seed=0)["return"])
    return fresh


def test_a_reused_darkroom_env_gives_the_episodes_of_fresh_ones(tiny_ipref):
    suite = tiny_ipref.held_out("rollouts")[0]
    _same_episodes(suite, HashPolicy(n_actions=5))


def test_a_reused_env_must_match_the_suite(tiny_ipref):
    low, high = tiny_ipref.held_out("rollouts")[0], tiny_ipref.held_out("rollouts")[2]
    wrong = type(low)(**{**low.__dict__, "task_index": np.concatenate([low.task_index, low.task_index])})
    with suite_env(high) as env, pytest.raises(ValueError, match="env: .* envs for a suite of"):
        rollout_in_context(HashPolicy(n_actions=5), wrong, env=env)


def test_a_reused_reach_env_gives_the_episodes_of_fresh_ones(tmp_path):
    pytest.importorskip("metaworld")
    dm = reach_data(root_dir=str(tmp_path), horizon=15, n_train_tasks=2, n_test_tasks=2,
                    trajectories_per_task=2, val_trajectories_per_task=1, eval_contexts_per_task=2,
                    calibration_episodes=2, reference_episodes=2, num_workers=0, progress=False, batch_size=2)
    dm.prepare_data()
    suite = dm.held_out("rollouts")[0]
    fresh = _same_episodes(suite, HashPolicy(action_dim=4))
    assert not np.array_equal(fresh[0]["return"], fresh[1]["return"])  # the seed moves the pucks: a real check
