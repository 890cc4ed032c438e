"""Typed training samples (``samples.py``) as ``data/batches.py`` builds them from stored rows, and as Lightning moves
them to a device: a NamedTuple of typed contexts and tensors, every field moved, the types kept."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lightning.fabric.utilities.apply_func import move_data_to_device

from icprl_lightning.contexts import RewardTrajectoryContext, StepPreferenceContext
from icprl_lightning.data.batches import ContextBatches, stored_context
from icprl_lightning.samples import ContextSamples, RewardTrajectorySamples

N, T = 6, 4  # rows (3 tasks × 2 trajectories, task-major), steps


def _step_rows() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {"states": rng.random((N, T, 2), dtype=np.float32), "actions": rng.integers(0, 5, (N, T)).astype(np.int16),
            "alt_actions": rng.integers(0, 5, (N, T)).astype(np.int16),
            "preferred": rng.integers(0, 2, (N, T)).astype(np.uint8),
            "query_states": rng.random((N, T, 2), dtype=np.float32),
            "optimal_actions": rng.integers(0, 5, (N, T)).astype(np.int16)}


def test_step_rows_become_a_context_another_of_its_task_labels_and_the_task():
    arrays = _step_rows()
    fields = ("states", "actions", "alt_actions", "preferred")
    torch.manual_seed(0)
    batch = ContextBatches(arrays, fields, 2, pairs=True, query_labels=True, tasks=True, kind="step_preference")[
        [5, 0, 3]]
    assert isinstance(batch, ContextSamples) and batch.batch_size == 3
    assert isinstance(batch.context, StepPreferenceContext) and isinstance(batch.pair, StepPreferenceContext)
    np.testing.assert_array_equal(batch.context.states.numpy(), arrays["states"][[0, 3, 5]])  # rows sorted
    np.testing.assert_array_equal(batch.pair.states.numpy(), arrays["states"][[1, 2, 4]])  # the task's other row
    assert batch.context.actions.dtype == torch.int64 and batch.context.preferred.dtype == torch.float32
    np.testing.assert_array_equal(batch.optimal_actions.numpy(), arrays["optimal_actions"][[0, 3, 5]])
    assert batch.task.tolist() == [0, 1, 2]
    plain = ContextBatches(arrays, fields, 2, pairs=False, query_labels=False, kind="step_preference")[[1]]
    assert plain.pair is None and plain.query_states is None and plain.optimal_actions is None and plain.task is None


def test_reward_trajectory_rows_become_two_labeled_trajectories():
    rng = np.random.default_rng(1)
    arrays = {f"{k}_{side}": v for side in "ab" for k, v in (
        ("states", rng.random((N, T, 2), dtype=np.float32)), ("actions", rng.integers(0, 5, (N, T))),
        ("rewards", rng.random((N, T), dtype=np.float32)), ("advantages", rng.random((N, T), dtype=np.float32)))}
    batch = ContextBatches(arrays, tuple(arrays), 2, pairs=False, query_labels=False, tasks=True,
                           kind="reward_trajectory")[[2, 3]]
    assert isinstance(batch, RewardTrajectorySamples) and batch.batch_size == 2
    assert isinstance(batch.trajectory_b, RewardTrajectoryContext)
    np.testing.assert_array_equal(batch.trajectory_b.rewards.numpy(), arrays["rewards_b"][[2, 3]])
    np.testing.assert_array_equal(batch.advantages_a.numpy(), arrays["advantages_a"][[2, 3]])
    assert batch.task.tolist() == [1, 1]
    with pytest.raises(ValueError, match="set pairs and query_labels false"):
        ContextBatches(arrays, tuple(arrays), 2, pairs=True, query_labels=False, kind="reward_trajectory")
    with pytest.raises(ValueError, match="unknown context kind 'rewards'"):
        ContextBatches(arrays, tuple(arrays), 2, pairs=False, query_labels=False, kind="rewards")


def test_lightning_moves_every_field_and_keeps_the_types():
    arrays = _step_rows()
    context = stored_context("step_preference", arrays, np.arange(3))
    batch = ContextSamples(context, context.map(torch.clone), torch.zeros(3, T, 2), torch.zeros(3, T), None)
    moved = move_data_to_device(batch, torch.device("meta"))
    assert type(moved) is ContextSamples and type(moved.context) is StepPreferenceContext and moved.task is None
    tensors = [*vars(moved.context).values(), *vars(moved.pair).values(), moved.query_states, moved.optimal_actions]
    assert all(t.device.type == "meta" for t in tensors)
    trajectories = RewardTrajectorySamples(*(RewardTrajectoryContext(torch.zeros(2, T, 2), torch.zeros(2, T),
                                                                     torch.zeros(2, T)) for _ in "ab"))
    moved = move_data_to_device(trajectories, torch.device("meta"))
    assert type(moved.trajectory_a) is RewardTrajectoryContext and moved.trajectory_b.rewards.device.type == "meta"
