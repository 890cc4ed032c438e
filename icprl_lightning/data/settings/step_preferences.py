"""I-PRL step preferences, for every family (paper, section 4.1 and appendix "Pretraining Data Generation").

At every step h of a context one action comes from each of two policies, in shuffled slots so that a
slot carries no information, and the label is drawn from the Bradley–Terry model on the oracle's
utility (A* up to a per-state constant), eq. (i-prl-pref):

    P(y_h = 1 | s_h, a_h, a'_h) = σ((A*(s_h, a_h) − A*(s_h, a'_h)) / bt_temperature).

The knobs are the paper's choices made explicit:

* ``first_policy``: the policy of one side of every pair — ``"uniform"`` (the paper's DarkRoom recipe)
  or a calibrated policy's name (``"low"``, Meta-World's 20% policy);
* ``second_policy``: the other side — ``"behavior"``, the context's own quality (training rows:
  ``train_policy``; the paper's), or ``"uniform"``. With the paper's choice the *unlabeled* pairs point to
  the goal (one side is optimal with probability p); with both sides uniform and ``state_source: uniform``
  nothing in a context but its labels depends on the task: the *label-only* recipe
  (``configs/overlays/label_only.yaml``; ``icprl analyze label-ceiling`` measures what each part holds);
* ``annotator``: who labels the pairs (``annotators/``: B-Pref's scripted teachers, a function, an
  HTTP endpoint, a person); by default the Bradley–Terry oracle above at ``bt_temperature`` (paper: 1;
  Meta-World's per-step differences need ≈ 0.02). Its EQUAL and SKIP answers are stored as fair coins
  (``annotators/labels.py``) and counted in the statistics (``skip_count``, ``equal_count``);
* ``next_state_follows``: which action the trajectory continues with — ``"preferred"`` (the paper's),
  ``"rejected"``, ``"behavior"`` (the behavior policy's proposal, whatever the label) or ``"first"``
  (the ``first_policy`` side). With the paper's choice the state trajectory walks towards the goal
  through the labels, so a model can read the task from the states alone and ignore the labels;
  ``"first"`` with a uniform first policy gives states that carry no task information;
* ``state_source``: ``"rollout"`` (the states of that trajectory) or ``"uniform"`` (every state drawn
  independently over the state space, as DPT's own DarkRoom data; ``next_state_follows`` then only
  decides the reported next state). With states that carry no task information the labels are a
  model's only signal about the states, but the pairs still carry the behavior policy's unless
  ``second_policy`` is ``"uniform"``.

The context arrays are ``states`` [N, H, S] float32, ``actions`` / ``alt_actions`` (the two slots),
``preferred`` [N, H] uint8 (1 = ``actions`` won), plus the oracle's query labels for DPT/DP²T.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icprl_lightning.annotators.base import Annotator, StepQueries
from icprl_lightning.annotators.labels import stored_labels
from icprl_lightning.data.settings.base import (
    STATE_SOURCES,
    MDPSetting,
    annotator_knobs,
    choose_annotator,
    chunks,
    context_process,
    steps,
)
from icprl_lightning.families.base import TaskFamily
from icprl_lightning.preferences import AgreementTally
from icprl_lightning.validation import check_choice

FOLLOW = ("preferred", "rejected", "behavior", "first")
SECOND_POLICIES = ("behavior", "uniform")


class StepPreferences(MDPSetting):
    """I-PRL contexts; see the module docstring. The other arguments as ``MDPSetting``."""

    kind = "step_preference"

    def __init__(self, first_policy: str = "uniform", bt_temperature: float = 1.0,
                 next_state_follows: str = "preferred", state_source: str = "rollout",
                 annotator: Annotator | None = None, second_policy: str = "behavior", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        owner = type(self).__name__
        check_choice(owner, "first_policy", first_policy, ("uniform", *self.policy_names()))
        check_choice(owner, "next_state_follows", next_state_follows, FOLLOW)
        self.annotator = choose_annotator(owner, annotator, bt_temperature)
        self.state_source = check_choice(owner, "state_source", state_source, STATE_SOURCES)
        self.second_policy = check_choice(owner, "second_policy", second_policy, SECOND_POLICIES)
        self.first_policy = first_policy
        self.next_state_follows = next_state_follows

    @property
    def bt_temperature(self) -> float | None:
        """The Bradley–Terry annotator's temperature; None for another annotator."""
        return annotator_knobs(self.annotator).get("bt_temperature")

    def knobs(self) -> dict[str, Any]:
        return {"first_policy": self.first_policy, **annotator_knobs(self.annotator),
                "next_state_follows": self.next_state_follows, "state_source": self.state_source,
                # recorded only when set, so the paper's recipe keeps its config (and its dataset's directory)
                **({} if self.second_policy == "behavior" else {"second_policy": self.second_policy})}

    def annotation(self) -> dict[str, Any]:
        return {"annotator": self.annotator.config()}

    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        n, horizon, oracle = len(tasks), family.horizon, family.oracle
        spec = family.action_spec
        act_shape = () if spec.discrete else (spec.size,)
        # time-major buffers [H, N, ...]: each step writes one contiguous block (row-major [N, H, ...]
        # would scatter every step's rows H elements apart); transposed once at the end
        states = np.empty((horizon, n, family.obs_dim), dtype=np.float32)
        pair = np.empty((2, horizon, n, *act_shape), dtype=family.action_dtype)
        optimal = np.empty((horizon, n, *act_shape), dtype=family.action_dtype)
        preferred = np.empty((horizon, n), dtype=np.uint8)
        tally = AgreementTally()  # label statistics, step by step (the utilities are not kept)
        answers = {"skip_count": 0, "equal_count": 0}
        second_p = mixing[quality]
        first_p = None if self.first_policy == "uniform" else mixing[self.policy_names().index(self.first_policy)]
        for rows, label in chunks(n, family.max_parallel, description):
            m = rows.stop - rows.start
            with context_process(family, tasks[rows], rng, self.state_source) as roll:
                for h in steps(horizon, label, progress):
                    state = roll.oracle_state()
                    first = (oracle.uniform_actions(state, rng) if first_p is None
                             else oracle.behavior_actions(state, np.full(m, first_p), rng))
                    second = (oracle.uniform_actions(state, rng) if self.second_policy == "uniform"
                              else oracle.behavior_actions(state, second_p[rows], rng))
                    swap = _column(rng.random(m) < 0.5, first.ndim)
                    both = np.stack([np.where(swap, second, first), np.where(swap, first, second)])
                    u = oracle.utility(state, both)  # [2, m]
                    obs = roll.observations()
                    queries = StepQueries(obs, both[0], both[1], u[0], u[1], tasks[rows])
                    y = stored_labels(self.annotator.label_steps(queries, rng), m, type(self.annotator).__name__,
                                      rng, answers)
                    states[h, rows], pair[:, h, rows], optimal[h, rows] = obs, both, oracle.optimal_actions(state)
                    preferred[h, rows] = y
                    tally.add(u[0], u[1], y)
                    roll.step(self._next_action(y, both, first, second))
        stats = {**tally.summary(), **answers}
        states, optimal = _row_major(states), _row_major(optimal)
        arrays = {"states": states, "actions": _row_major(pair[0]), "alt_actions": _row_major(pair[1]),
                  "preferred": _row_major(preferred)}
        arrays.update(oracle.query_labels(tasks, states, optimal, horizon, rng))
        return arrays, stats

    def _next_action(self, y: np.ndarray, both: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        if self.next_state_follows == "first":
            return first
        if self.next_state_follows == "behavior":
            return second
        won = _column(y == 1, both.ndim - 1)
        if self.next_state_follows == "preferred":
            return np.where(won, both[0], both[1])
        return np.where(won, both[1], both[0])


def _column(mask: np.ndarray, ndim: int) -> np.ndarray:
    """A per-row mask [N] shaped to broadcast against actions of ``ndim`` dims ([N] or [N, A])."""
    return mask.reshape(-1, *[1] * (ndim - 1))


def _row_major(steps_first: np.ndarray) -> np.ndarray:
    """A C-contiguous time-major buffer [H, N, ...] as the stored C-contiguous [N, H, ...].

    Each element's trailing values (a state's coordinates, a continuous action) move as one raw item:
    NumPy copies such an item with one memcpy, several times faster than transposing value by value.
    """
    horizon, n, *trailing = steps_first.shape
    width = int(np.prod(trailing, dtype=np.int64))
    if width == 0:  # nothing to move (e.g. zero-dimensional observations)
        return np.empty((n, horizon, *trailing), dtype=steps_first.dtype)
    items = steps_first.reshape(horizon, n, width).view(np.dtype((np.void, steps_first.itemsize * width)))
    moved = np.ascontiguousarray(items[..., 0].T)
    return moved.view(steps_first.dtype).reshape(n, horizon, *trailing)
