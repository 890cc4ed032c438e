"""Context diagnostics: what a deployed policy reads from its context.

A preference method should infer the task from the *labels* of its context. Each diagnostic changes an
evaluation context in exactly one stated way, all else equal (states, actions, task, episode seed):

* ``own`` — the context as generated (the paper's evaluation);
* ``flipped_labels`` — y → 1 − y: a policy that reads the labels should fall towards, or below, random;
* ``random_labels`` — fair coin labels (the diagnostic's seed): what is earned here comes from states and actions;
* ``other_task`` — the context of the next held-out task, same quality: what is earned here needs no context;
* ``shuffled_order`` — the steps in a random order per row (I-PRL, DPT's reward contexts, bandit duels). The
  paper's D is a set; a policy that reads it as one earns the same. One trained on shuffled orders (ICPO's
  ``pair_steps: shuffled``) is deployed on the episode-ordered context, which this turns back into its kind.

So own − random_labels is what the labels add, random_labels − other_task what the rest of the context adds.
The label diagnostics apply to contexts with labels (I-PRL steps, T-PRL pairs, bandit duels), not to DPT's or
DIT's reward contexts.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import torch

from icprl_lightning.contexts import RewardContext, StepPreferenceContext

DIAGNOSTICS = ("own", "random_labels", "flipped_labels", "other_task", "shuffled_order")
LABEL_DIAGNOSTICS = ("random_labels", "flipped_labels")
ORDER_DIAGNOSTICS = ("shuffled_order",)


def has_labels(context: Any) -> bool:
    return getattr(context, "preferred", None) is not None


def flipped_labels(context: Any) -> Any:
    """The context with every label inverted: y → 1 − y (same dtype)."""
    return replace(context, preferred=1 - context.preferred)


def random_labels(context: Any, seed: int) -> Any:
    """The context with every label a fair coin flip drawn from ``seed`` (same shape and dtype)."""
    generator = torch.Generator().manual_seed(seed)
    coins = torch.randint(0, 2, context.preferred.shape, generator=generator)
    return replace(context, preferred=coins.to(context.preferred.dtype))


def has_step_order(context: Any) -> bool:
    """Contexts whose every field is indexed [row, step, ...]: per-step comparisons or transitions."""
    return isinstance(context, StepPreferenceContext | RewardContext)


def shuffled_order(context: Any, seed: int) -> Any:
    """The context with each row's steps in a random order drawn from ``seed`` (the same steps, reordered)."""
    b, t = context.states.shape[:2]
    order = torch.rand(b, t, generator=torch.Generator().manual_seed(seed)).argsort(-1)
    rows = torch.arange(b)[:, None]
    return context.map(lambda x: x[rows, order.to(x.device)])


def other_task(context: Any, task_index: np.ndarray) -> Any:
    """Each row's context replaced by the same row of the *next* task (rows task-major, equal counts per task)."""
    per_task = int(np.bincount(task_index).max())
    if np.any(np.roll(task_index, per_task) == task_index):
        raise ValueError("other-task contexts need task-major rows with the same count per task and ≥ 2 tasks")
    return context.map(lambda x: torch.roll(x, per_task, dims=0))


def diagnose(context: Any, diagnostic: str, task_index: np.ndarray, seed: int = 0) -> Any:
    """``context`` changed as ``diagnostic`` states (see the module docstring)."""
    if diagnostic not in DIAGNOSTICS:
        raise ValueError(f"unknown context diagnostic {diagnostic!r}; known: {list(DIAGNOSTICS)}")
    if diagnostic in LABEL_DIAGNOSTICS and not has_labels(context):
        raise ValueError(f"{diagnostic} needs a context with preference labels; {type(context).__name__} has none")
    if diagnostic in ORDER_DIAGNOSTICS and not has_step_order(context):
        raise ValueError(f"{diagnostic} needs a context of steps ([row, step, ...] fields); "
                         f"{type(context).__name__} is not one")
    change = {"own": lambda: context, "flipped_labels": lambda: flipped_labels(context),
              "random_labels": lambda: random_labels(context, seed),
              "other_task": lambda: other_task(context, task_index),
              "shuffled_order": lambda: shuffled_order(context, seed)}
    return change[diagnostic]()


def checked_contexts(contexts: Any) -> list[str]:
    """``own`` and diagnostics as given, each once; one named is neither is a ``ValueError``."""
    unknown = [c for c in contexts if c not in DIAGNOSTICS]
    if unknown:
        raise ValueError(f"contexts: {unknown[0]!r} is not own or a diagnostic ({', '.join(DIAGNOSTICS[1:])})")
    return list(dict.fromkeys(contexts))


def applicable(context: Any, diagnostics: tuple[str, ...] | list[str]) -> list[str]:
    """The diagnostics that apply to ``context`` (label ones only where it has labels, order ones only where it
    has steps), in order."""
    return [d for d in diagnostics if (d not in LABEL_DIAGNOSTICS or has_labels(context))
            and (d not in ORDER_DIAGNOSTICS or has_step_order(context))]


def diagnose_suite(suite: Any, diagnostic: str, seed: int = 0) -> Any:
    """An ``EvalSuite`` or ``BanditSuite`` whose context is changed as ``diagnostic`` states.

    A bandit suite holds one problem per row, so its other-task context is the next problem's.
    """
    task_index = getattr(suite, "task_index", None)
    if task_index is None:
        task_index = np.arange(suite.context.batch_size)
    return replace(suite, context=diagnose(suite.context, diagnostic, task_index, seed))
