"""Linear dueling-bandit datasets: the bandit family's own setting (paper, appendix "Dueling Bandit Experiments").

A dueling bandit is I-PRL without states: a context D^I = {(a_h, a'_h, y_h)}_{h ≤ H} is a
``StepPreferenceContext`` whose states have shape ``[B, H, 0]`` (``state_dim = 0``). The policy's query
token is then a constant (``nn.Linear(0, D)`` outputs its bias) plus the position embedding of the
context size it sees, so T_θ(a | D_{1:h}) needs no state at all. Arms are discrete actions (|A| = 20).

Splits written to disk (see ``data/store.py``):

* ``tasks``: ``train_theta``, ``val_theta``, ``test_theta`` — read only by evaluation, never batched;
* ``train``: ``contexts_per_problem`` uniformly-random-pair contexts of H duels per pretraining problem,
  task-major (the paper's pretraining data; two or more per problem so that ICPO's default loss pairs,
  another context of the same problem, exist);
* ``val``: the same on fresh validation problems, for the validation loss;
* ``eval_uniform`` / ``eval_dirichlet`` / ``eval_dts``: one context per held-out problem from each
  behaviour policy, plus ``next_actions`` / ``next_alt_actions`` [n, H] (column h − 1 is the duel the
  behaviour policy plays after h comparisons, i.e. its duel h + 1) and ``expected_rewards`` [n, A]. These
  splits are read only by ``bandit_suites`` (the ``duels`` evaluation); the dataloaders never touch them.

``annotator`` (``icprl_lightning.annotators``, e.g. B-Pref's ``ScriptedTeacher``) relabels the
*pretraining* duels (train and val): it sees each duel's two arms and their expected rewards as utilities
(states are empty), and its EQUAL / SKIP answers become fair coins, as in the MDP settings. The held-out
contexts keep the family's own Bradley–Terry labels, so a model trained on a noisy teacher is evaluated on
the same contexts as one trained on clean labels. Without an annotator nothing changes (same bytes).

Problem parameters come from independent seed streams per split, so the held-out problems do not change
with the training-set size. The manifest records each split's label agreement (the share of BT labels
that agree with the true reward order): with θ, φ ~ N(0, I/d) reward gaps are small and it is only
≈ 0.6 — the labels are very noisy, which is what makes the paper's problems hard.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from icprl_lightning.annotators.base import Annotator, StepQueries
from icprl_lightning.annotators.labels import stored_labels
from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.settings.base import Setting
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.data.suites import BanditSuite
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.preferences import label_agreement
from icprl_lightning.progress import track
from icprl_lightning.validation import HyperparameterError, check_int

EVAL_SOURCES = ("uniform", "dirichlet", "dts")
_CHUNK = 10_000  # problems generated per step, bounding memory at paper scale (100k contexts)


class BanditDuels(Setting):
    """Dueling-bandit I-PRL contexts (states of shape [.., 0]); see the module docstring.

    A dueling bandit has no states and no episodes, so the MDP recipe (calibrated mixtures, rollouts)
    does not apply: this is the paper's separate bandit recipe, used with the same
    ``PreferenceDataModule``.

    Args:
        n_train_problems: pretraining problems (paper: 100k contexts in all; here contexts = problems ×
            ``contexts_per_problem``).
        contexts_per_problem: uniform-pair contexts per pretraining problem (≥ 2 for ICPO's pairs).
        n_val_problems / val_contexts_per_problem: fresh problems for the validation loss.
        n_eval_problems: held-out problems, each with one context per source in ``eval_sources``.
    """

    kind = "step_preference"
    family_type = LinearDuelingBanditFamily
    per_task_keys = ("contexts_per_problem", "val_contexts_per_problem")
    evaluations = frozenset({"duels"})  # weak regret, not rollouts
    # has_folds and has_query_labels stay False: the val problems are not the training ones, and a bandit has
    # no query states nor optimal-action labels

    def __init__(self, n_train_problems: int = 2000, contexts_per_problem: int = 2, n_val_problems: int = 64,
                 val_contexts_per_problem: int = 2, n_eval_problems: int = 200,
                 eval_sources: tuple[str, ...] = EVAL_SOURCES, annotator: Annotator | None = None) -> None:
        if annotator is not None and not isinstance(annotator, Annotator):
            raise HyperparameterError(f"BanditDuels: annotator must be an Annotator (icprl_lightning.annotators), "
                                      f"got {type(annotator).__name__}")
        self.annotator = annotator
        self.answers = {"skip_count": 0, "equal_count": 0}  # the annotator's undecided answers (pretraining)
        unknown = set(eval_sources) - set(EVAL_SOURCES)
        if unknown:
            raise HyperparameterError(f"BanditDuels: eval_sources must be a subset of {list(EVAL_SOURCES)}, "
                                      f"got unknown {sorted(unknown)}")
        if not eval_sources:
            raise HyperparameterError(f"BanditDuels: eval_sources must name at least one of {list(EVAL_SOURCES)}, "
                                      "got []")
        for key, value in (("n_train_problems", n_train_problems), ("contexts_per_problem", contexts_per_problem),
                           ("n_val_problems", n_val_problems), ("val_contexts_per_problem", val_contexts_per_problem),
                           ("n_eval_problems", n_eval_problems)):
            check_int("BanditDuels", key, value, 1)
        self.n_problems = {"train": n_train_problems, "val": n_val_problems, "test": n_eval_problems}
        self.per_task = (contexts_per_problem, val_contexts_per_problem)
        self.eval_sources = tuple(eval_sources)

    def config(self) -> dict[str, Any]:
        return {"setting": type(self).__name__, "context_kind": self.kind,
                "n_train_problems": self.n_problems["train"], "contexts_per_problem": self.per_task[0],
                "n_val_problems": self.n_problems["val"], "val_contexts_per_problem": self.per_task[1],
                "n_eval_problems": self.n_problems["test"], "eval_sources": list(self.eval_sources),
                **({} if self.annotator is None else {"annotator": self.annotator.config()})}

    # ---- generation --------------------------------------------------------------------------------
    def _pretraining_split(self, family: LinearDuelingBanditFamily, theta: np.ndarray, per_problem: int,
                           rng: np.random.Generator, description: str, progress: bool
                           ) -> tuple[dict[str, np.ndarray], float]:
        """``per_problem`` uniform-pair contexts per row of ``theta``, task-major."""
        task_index = np.repeat(np.arange(len(theta)), per_problem).astype(np.int32)
        chunks, agree = [], []
        starts = range(0, len(task_index), _CHUNK)
        for start in track(starts, description, unit="chunk", enabled=progress):
            rows = theta[task_index[start:start + _CHUNK]]
            context = family.uniform_pairs_context(rows, rng)
            if self.annotator is not None:
                context["preferred"] = self._annotate(family, rows, context, rng)
            chunks.append(context)
            agree.append(self._agreement(family, rows, context))
        context = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
        arrays = self._as_step_preferences(context)
        arrays["task_index"] = task_index
        rates, weights = zip(*agree, strict=True)
        return arrays, float(np.average(rates, weights=weights))

    def _annotate(self, family: LinearDuelingBanditFamily, theta: np.ndarray, context: dict[str, np.ndarray],
                  rng: np.random.Generator) -> np.ndarray:
        """The annotator's labels [n, H] for the context's duels (EQUAL / SKIP resolved to coins, counted)."""
        first, second = context["arms_first"], context["arms_second"]
        rewards = family.expected_rewards(theta)
        n, h = first.shape
        queries = StepQueries(np.zeros((n * h, 0), dtype=np.float32), first.reshape(-1), second.reshape(-1),
                              np.take_along_axis(rewards, first, axis=1).reshape(-1),
                              np.take_along_axis(rewards, second, axis=1).reshape(-1),
                              np.repeat(theta, h, axis=0))
        return stored_labels(self.annotator.label_steps(queries, rng), n * h, type(self.annotator).__name__, rng,
                             self.answers).reshape(n, h)

    def _agreement(self, family: LinearDuelingBanditFamily, theta: np.ndarray,
                   context: dict[str, np.ndarray]) -> tuple[float, int]:
        """(label agreement rate, number of duels between arms of different reward)."""
        rewards = family.expected_rewards(theta)
        first = np.take_along_axis(rewards, context["arms_first"], axis=1)
        second = np.take_along_axis(rewards, context["arms_second"], axis=1)
        return label_agreement(first, second, context["preferred"]), int((first != second).sum())

    def _as_step_preferences(self, context: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        n, h = context["preferred"].shape
        return {"states": np.zeros((n, h, 0), dtype=np.float32),
                "actions": context["arms_first"].astype(np.int16),
                "alt_actions": context["arms_second"].astype(np.int16),
                "preferred": context["preferred"].astype(np.uint8)}

    def _eval_split(self, family: LinearDuelingBanditFamily, source: str, theta: np.ndarray,
                    rng: np.random.Generator) -> tuple[dict[str, np.ndarray], float]:
        """One context of H + 1 duels per held-out problem: H to condition on, shifted by one as the behaviour."""
        # the same features with one more step: the behaviour's duel after the H-th comparison
        full = family.with_horizon(family.horizon + 1).make_context(source, theta, rng)
        context = {k: v[:, :family.horizon] for k, v in full.items()}
        arrays = self._as_step_preferences(context)
        arrays["next_actions"] = full["arms_first"][:, 1:].astype(np.int16)
        arrays["next_alt_actions"] = full["arms_second"][:, 1:].astype(np.int16)
        arrays["expected_rewards"] = family.expected_rewards(theta)
        return arrays, self._agreement(family, theta, context)[0]

    def generate(self, family: LinearDuelingBanditFamily, progress: bool = True
                 ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        self.answers = {"skip_count": 0, "equal_count": 0}  # this generation's undecided answers only
        train_seq, val_seq, test_seq = np.random.SeedSequence(family.seed).spawn(3)
        thetas, rngs = {}, {}
        for split, seq in (("train", train_seq), ("val", val_seq), ("test", test_seq)):
            rngs[split] = np.random.default_rng(seq)
            thetas[split] = family.sample_tasks(self.n_problems[split], rngs[split])
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {f"{k}_theta": v for k, v in thetas.items()}}
        agreement: dict[str, float] = {}
        splits["train"], agreement["train"] = self._pretraining_split(family, thetas["train"], self.per_task[0],
                                                                      rngs["train"], "bandit train contexts", progress)
        splits["val"], agreement["val"] = self._pretraining_split(family, thetas["val"], self.per_task[1], rngs["val"],
                                                                  "bandit val contexts", progress)
        # One stream per source, so that adding a source leaves the others' contexts unchanged.
        for source, seq in zip(EVAL_SOURCES, test_seq.spawn(len(EVAL_SOURCES)), strict=True):
            if source in self.eval_sources:
                name = f"eval_{source}"
                rng = np.random.default_rng(seq)
                splits[name], agreement[name] = self._eval_split(family, source, thetas["test"], rng)
        info = {"label_agreement": agreement,
                "label_note": "share of BT labels agreeing with the true reward order (ties, i.e. DTS "
                              "self-duels, left out); 0.5 would be pure noise"}
        if self.annotator is not None:
            info["annotator"] = self.annotator.config()
            info["annotator_answers"] = dict(self.answers)
            info["label_note"] = ("share of stored labels agreeing with the true reward order; train and val "
                                  "labeled by the annotator, the eval_* splits by the family's Bradley-Terry model")
        return splits, info

    # ---- evaluation (no environment rollouts: a bandit is evaluated by weak regret) ---------------------
    def bandit_suites(self, family: LinearDuelingBanditFamily, data: StoredDataset) -> list[BanditSuite]:
        """One weak-regret evaluation per context source, on the held-out problems."""
        suites = []
        for source in self.eval_sources:
            split = data[f"eval_{source}"]
            arrays = {k: to_tensor(np.array(v)) for k, v in split.items()}
            context = StepPreferenceContext(states=arrays["states"], actions=arrays["actions"],
                                            alt_actions=arrays["alt_actions"], preferred=arrays["preferred"])
            suites.append(BanditSuite(source=source, context=context,
                                      expected_rewards=torch.from_numpy(np.array(split["expected_rewards"])),
                                      behavior_first=arrays["next_actions"],
                                      behavior_second=arrays["next_alt_actions"], dts_alpha=family.dts_alpha))
        return suites
