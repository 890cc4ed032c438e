"""Context diagnostics change an evaluation context only as stated."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from icprl_lightning.contexts import RewardContext, StepPreferenceContext, TrajectoryPreferenceContext
from icprl_lightning.evaluation.diagnostics import DIAGNOSTICS, applicable, diagnose


def _step_context(b: int = 6, t: int = 40) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(0)
    return StepPreferenceContext(states=torch.rand(b, t, 2, generator=g),
                                 actions=torch.randint(0, 5, (b, t), generator=g),
                                 alt_actions=torch.randint(0, 5, (b, t), generator=g),
                                 preferred=torch.randint(0, 2, (b, t), generator=g).float())


def _same_except_labels(a, b) -> None:
    for name in ("states", "actions", "alt_actions"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


def test_flipped_labels_invert_every_label_and_nothing_else():
    context = _step_context()
    flipped = diagnose(context, "flipped_labels", np.repeat(np.arange(3), 2))
    _same_except_labels(context, flipped)
    assert torch.equal(flipped.preferred, 1 - context.preferred) and flipped.preferred.dtype == context.preferred.dtype


def test_random_labels_are_fair_coins_fixed_by_the_seed():
    context = _step_context(b=50, t=100)
    tasks = np.repeat(np.arange(25), 2)
    first, again, other = (diagnose(context, "random_labels", tasks, seed=s) for s in (0, 0, 1))
    _same_except_labels(context, first)
    assert torch.equal(first.preferred, again.preferred) and not torch.equal(first.preferred, other.preferred)
    assert set(first.preferred.unique().tolist()) <= {0.0, 1.0}
    assert first.preferred.mean().item() == pytest.approx(0.5, abs=0.02)  # 5,000 coins: sem ≈ 0.007
    # independent of the original labels: agreement with them is at chance
    assert (first.preferred == context.preferred).float().mean().item() == pytest.approx(0.5, abs=0.03)


def test_other_task_moves_every_field_to_the_next_task():
    context = _step_context()
    tasks = np.repeat(np.arange(3), 2)
    moved = diagnose(context, "other_task", tasks)
    for name in ("states", "actions", "alt_actions", "preferred"):
        assert torch.equal(getattr(moved, name), torch.roll(getattr(context, name), 2, dims=0))
    with pytest.raises(ValueError, match="task-major"):
        diagnose(context, "other_task", np.zeros(6, dtype=int))


def test_trajectory_pairs_flip_their_one_label():
    g = torch.Generator().manual_seed(0)
    pair = TrajectoryPreferenceContext(states_a=torch.rand(4, 5, 2, generator=g), actions_a=torch.zeros(4, 5).long(),
                                       states_b=torch.rand(4, 5, 2, generator=g), actions_b=torch.ones(4, 5).long(),
                                       preferred=torch.tensor([1.0, 0.0, 1.0, 1.0]))
    flipped = diagnose(pair, "flipped_labels", np.arange(4))
    assert torch.equal(flipped.preferred, torch.tensor([0.0, 1.0, 0.0, 0.0]))
    assert torch.equal(flipped.states_a, pair.states_a) and torch.equal(flipped.actions_b, pair.actions_b)


def test_reward_contexts_have_no_label_diagnostics():
    context = RewardContext(states=torch.zeros(2, 3, 2), actions=torch.zeros(2, 3).long(),
                            rewards=torch.zeros(2, 3), next_states=torch.zeros(2, 3, 2))
    assert applicable(context, DIAGNOSTICS) == ["own", "other_task", "shuffled_order"]
    with pytest.raises(ValueError, match="no"):
        diagnose(context, "flipped_labels", np.arange(2))
    with pytest.raises(ValueError, match="unknown context diagnostic"):
        diagnose(context, "shuffled", np.arange(2))


def test_shuffled_order_permutes_each_rows_steps_together():
    context = _step_context()
    tasks = np.repeat(np.arange(3), 2)
    first, again, other = (diagnose(context, "shuffled_order", tasks, seed=s) for s in (0, 0, 1))
    assert torch.equal(first.states, again.states) and not torch.equal(first.states, other.states)
    assert not torch.equal(first.states, context.states)
    for row in range(context.batch_size):  # the same (state, actions, label) steps, each kept whole
        def step(c, t, row=row):
            return (int(c.actions[row, t]), int(c.alt_actions[row, t]), float(c.preferred[row, t]))
        steps = {tuple(context.states[row, t].tolist()): step(context, t) for t in range(context.states.shape[1])}
        for t in range(context.states.shape[1]):
            assert steps[tuple(first.states[row, t].tolist())] == step(first, t)
        assert torch.equal(first.states[row].sort(0).values, context.states[row].sort(0).values)
    # each row has its own order: where each shuffled step came from differs between rows
    def origin(row: int) -> list[int]:
        stored = [tuple(x.tolist()) for x in context.states[row]]
        return [stored.index(tuple(x.tolist())) for x in first.states[row]]
    assert origin(0) != origin(1)


def test_trajectory_pairs_have_no_order_diagnostic():
    g = torch.Generator().manual_seed(0)
    pair = TrajectoryPreferenceContext(states_a=torch.rand(4, 5, 2, generator=g), actions_a=torch.zeros(4, 5).long(),
                                       states_b=torch.rand(4, 5, 2, generator=g), actions_b=torch.ones(4, 5).long(),
                                       preferred=torch.tensor([1.0, 0.0, 1.0, 1.0]))
    assert "shuffled_order" not in applicable(pair, DIAGNOSTICS)
    with pytest.raises(ValueError, match="context of steps"):
        diagnose(pair, "shuffled_order", np.arange(4))
