"""What every MDP setting shares: the dataset recipe around its context generator (paper, appendix
"Pretraining Data Generation").

``MDPSetting.generate(family)`` is written once for every family and setting:

1. calibrate the behavior policies: the mixing level p of each named target share of the optimal
   return (low/medium/high = ``quality_targets``, plus what the setting adds, e.g. T-PRL's 50% policy);
2. the ``train`` and ``val`` splits on the training tasks: ``trajectories_per_task`` /
   ``val_trajectories_per_task`` contexts per task, task-major, the quality of row j of a task chosen by
   ``train_policy`` (``"cycle"``: j mod 3; or one policy's name for all rows);
3. ``eval_<quality>`` splits on the held-out tasks, ``eval_contexts_per_task`` per task and quality;
4. the held-out references (behavior and optimal/expert returns), measured by the family's oracle.

A labeled setting's manifest ``info`` also records its ``annotator`` (``annotation()``: class path and
init args), beside each split's label statistics (agreement with the latent ordering, skip/equal counts).

All draws come from one generator seeded by ``family.seed``, in this order: the order is part of a
dataset's bytes. A setting subclass says how one split's contexts are generated (``contexts``), what a
training sample serves (``batch_fields``, ``pair_fields``) and how an evaluation split becomes a typed
context (``eval_context``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np

from icprl_lightning.annotators.base import Annotator
from icprl_lightning.annotators.bradley_terry import BradleyTerryAnnotator
from icprl_lightning.contexts import context_fields, context_from_fields
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.store import StoredDataset
from icprl_lightning.data.suites import BanditSuite, EvalSuite
from icprl_lightning.families.base import QUALITIES, Family, TaskFamily
from icprl_lightning.progress import track
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_choice, check_increasing, check_int, check_positive

PRETRAINING = "pretraining"  # name of a setting's extra calibrated policy (T-PRL's 50% policy)
STATE_SOURCES = ("rollout", "uniform")  # where per-step contexts' states come from (``context_process``)


def context_process(family: TaskFamily, tasks: np.ndarray, rng: np.random.Generator, state_source: str):
    """The rollouts a per-step context (I-PRL, reward) is drawn from.

    ``"rollout"``: the family's behavior process (the paper's; states follow the actions taken);
    ``"uniform"``: every state drawn independently over the state space (DPT's DarkRoom data), so the
    states carry no information about the task (``TaskFamily.independent_state_rollouts``).
    """
    if state_source == "uniform":
        return family.independent_state_rollouts(tasks, rng)
    return family.context_rollouts(tasks, rng)


def choose_annotator(owner: str, annotator: Annotator | None, bt_temperature: float) -> Annotator:
    """A labeled setting's annotator: ``annotator``, or by default Bradley–Terry at ``bt_temperature``.

    ``bt_temperature`` is the default annotator's knob only: changing it beside an ``annotator`` is an
    error naming both (its default, 1.0, cannot be told apart from not giving it).
    """
    check_positive(owner, "bt_temperature", bt_temperature)
    if annotator is None:
        return BradleyTerryAnnotator(bt_temperature)
    if not isinstance(annotator, Annotator):
        raise HyperparameterError(f"{owner}: annotator must be an Annotator (icprl_lightning.annotators), got "
                                  f"{type(annotator).__name__}")
    if bt_temperature != 1.0:
        raise HyperparameterError(
            f"{owner}: bt_temperature ({bt_temperature}) and annotator ({type(annotator).__name__}) were both "
            "given; bt_temperature sets the default Bradley-Terry annotator only: give one of them (for "
            "Bradley-Terry labels at another temperature: annotator "
            "{class_path: icprl_lightning.annotators.BradleyTerryAnnotator, init_args: {temperature: ...}})")
    return annotator


def annotator_knobs(annotator: Annotator) -> dict[str, Any]:
    """What the config (and so the dataset's hash) records of the annotator.

    A Bradley–Terry annotator is recorded as ``bt_temperature``, as before annotators were a choice, so
    the datasets it makes keep their config and directory; any other as ``annotator: {class_path,
    init_args}``.
    """
    if type(annotator) is BradleyTerryAnnotator:
        return {"bt_temperature": annotator.temperature}
    return {"annotator": annotator.config()}


def steps(horizon: int, description: str, progress: bool) -> Iterator[int]:
    """range(horizon), counted by ``progress.track``: a transient bar in a terminal, plain lines in a log."""
    return track(range(horizon), description, enabled=progress)


def chunks(n: int, limit: int | None, description: str) -> Iterator[tuple[slice, str]]:
    """Row slices of at most ``limit`` trajectories (all rows when None), each with its progress label."""
    size = n if limit is None else limit
    starts = range(0, n, max(size, 1))
    for i, lo in enumerate(starts):
        label = description if len(starts) == 1 else f"{description} ({i + 1}/{len(starts)})"
        yield slice(lo, min(lo + size, n)), label


def rollout_behavior(family: TaskFamily, tasks: np.ndarray, mixing: np.ndarray, rng: np.random.Generator,
                     episodes: bool, progress: bool, description: str, state_source: str = "rollout",
                     advantages: bool = False) -> dict[str, np.ndarray]:
    """One trajectory of the mixed policy π_p per row of ``tasks`` (p per row in ``mixing``).

    ``episodes`` picks the family's episode rollouts (T-PRL) or its context process (reward contexts,
    whose states come from ``state_source``, see ``context_process``).
    Returns ``states`` [N, H, S] (s_h before acting), ``actions`` [N, H, ...], latent ``rewards`` [N, H],
    ``next_states`` [N, H, S] and the oracle's actions at the visited states ``optimal`` (oracle only); with
    ``advantages``, also the optimal advantage of each behavior action, A*(s_h, a_h) = u(s_h, a_h) − u(s_h, π*(s_h))
    [N, H] with u the oracle's ``utility`` (oracle only; it draws nothing from ``rng``).
    """
    n, horizon, oracle = len(tasks), family.horizon, family.oracle
    spec = family.action_spec
    act_shape = () if spec.discrete else (spec.size,)
    out = {"states": np.empty((n, horizon, family.obs_dim), dtype=np.float32),
           "actions": np.empty((n, horizon, *act_shape), dtype=family.action_dtype),
           "rewards": np.empty((n, horizon), dtype=np.float32),
           "next_states": np.empty((n, horizon, family.obs_dim), dtype=np.float32),
           "optimal": np.empty((n, horizon, *act_shape), dtype=family.action_dtype)}
    if advantages:
        out["advantages"] = np.empty((n, horizon), dtype=np.float32)
    for rows, label in chunks(n, family.max_parallel, description):
        roll = (family.episode_rollouts(tasks[rows], rng) if episodes
                else context_process(family, tasks[rows], rng, state_source))
        with roll:
            for h in steps(horizon, label, progress):
                state = roll.oracle_state()
                out["states"][rows, h] = roll.observations()
                a = oracle.behavior_actions(state, mixing[rows], rng)
                optimal = oracle.optimal_actions(state)
                out["actions"][rows, h], out["optimal"][rows, h] = a, optimal
                if advantages:
                    utility = oracle.utility(state, np.stack([a, optimal]))
                    out["advantages"][rows, h] = utility[0] - utility[1]
                out["next_states"][rows, h], out["rewards"][rows, h] = roll.step(a)
    return out


class Setting(ABC):
    """A data recipe: ``generate(family)`` returns the splits and the manifest's info (see ``datamodule.py``).

    What its data offers is declared on the class, so that the DataModule and the pairing check read the
    declarations and never the setting's type:

    * ``kind``: the context kind a training sample holds (``contexts.CONTEXT_TYPES``);
    * ``family_type``: the family class the recipe runs on;
    * ``per_task_keys``: the names of the two arguments behind ``per_task`` (train, val), which ``pairs=True``
      needs >= 2 (another context of the same task);
    * ``has_folds``: train and val rows are contexts of the same training tasks, stored task-major, so each
      row has a training-task index: batches carry it as ``task`` and cross-fitting folds of the training
      tasks exist;
    * ``has_query_labels``: every split holds query states and their optimal actions (DPT/DP²T's labels);
    * ``evaluations``: the held-out evaluations its data offers (names from ``data_contract.EVALUATIONS``),
      each built by the method of that name.
    """

    kind: ClassVar[str]
    family_type: ClassVar[type[Family]] = Family
    per_task_keys: ClassVar[tuple[str, str]] = ("trajectories_per_task", "val_trajectories_per_task")
    has_folds: ClassVar[bool] = False
    has_query_labels: ClassVar[bool] = False
    evaluations: ClassVar[frozenset[str]] = frozenset()
    per_task: tuple[int, int]  # contexts per task in (train, val)

    @abstractmethod
    def generate(self, family: Family, progress: bool = True) -> tuple[dict[str, dict[str, np.ndarray]],
                                                                     dict[str, Any]]:
        """The dataset's splits (``{split: {field: array}}``) and the manifest's ``info``."""

    @abstractmethod
    def config(self) -> dict[str, Any]:
        """Everything about the recipe that determines the dataset's bytes."""

    def batch_fields(self) -> tuple[str, ...]:
        return context_fields(self.kind)

    @property
    def pair_fields(self) -> tuple[str, ...]:
        """What ``pairs=True`` serves from another row of the same task."""
        return context_fields("step_preference")

    def evaluation_suites(self, family: Family, data: StoredDataset) -> list[EvalSuite]:
        """The held-out in-context rollouts (offered with ``"rollouts"`` in ``evaluations``)."""
        return []

    def bandit_suites(self, family: Family, data: StoredDataset) -> list[BanditSuite]:
        """The held-out weak-regret evaluations (offered with ``"duels"`` in ``evaluations``)."""
        raise NotImplementedError(f"{type(self).__name__} declares no bandit_suites in its evaluations")

    def heldout_pairs(self, data: StoredDataset) -> dict[str, ContextSamples]:
        """Held-out pairs per quality (offered with ``"pair_accuracy"`` in ``evaluations``)."""
        raise NotImplementedError(f"{type(self).__name__} declares no heldout_pairs in its evaluations")


class MDPSetting(Setting):
    """Base of the MDP settings; see the module docstring. Each runs on any ``TaskFamily``, serves its rows'
    training tasks, the oracle's query labels and the held-out rollouts.

    Args:
        trajectories_per_task: training contexts per training task (paper: 1000 I-PRL, 5000 T-PRL pairs).
        val_trajectories_per_task: extra contexts per training task for the validation loss.
        eval_contexts_per_task: contexts (= evaluation episodes) per held-out task and quality.
        quality_targets: share of the optimal return of the low/medium/high behavior policies.
        train_policy: ``"cycle"`` (row j of a task at quality j mod 3) or the name of the one policy all
            training rows use (``"high"``, or ``"pretraining"`` for a setting's extra policy).
        calibration_episodes: episodes per training task (DarkRoom) or in all (Reach) per calibration p.
        reference_episodes: episodes per held-out task for the behavior/optimal references.
    """

    family_type: ClassVar[type[Family]] = TaskFamily
    has_folds: ClassVar[bool] = True
    has_query_labels: ClassVar[bool] = True
    evaluations: ClassVar[frozenset[str]] = frozenset({"rollouts"})

    def __init__(self, trajectories_per_task: int = 100, val_trajectories_per_task: int = 4,
                 eval_contexts_per_task: int = 5, quality_targets: tuple[float, float, float] = (0.2, 0.4, 0.8),
                 train_policy: str = "cycle", calibration_episodes: int = 25, reference_episodes: int = 25) -> None:
        owner = type(self).__name__
        for key, value in (("trajectories_per_task", trajectories_per_task),
                           ("val_trajectories_per_task", val_trajectories_per_task),
                           ("eval_contexts_per_task", eval_contexts_per_task),
                           ("calibration_episodes", calibration_episodes), ("reference_episodes", reference_episodes)):
            check_int(owner, key, value, 1)
        targets = check_increasing(owner, "quality_targets", quality_targets, 0.0, 1.0, length=len(QUALITIES))
        self.trajectories_per_task = trajectories_per_task
        self.val_trajectories_per_task = val_trajectories_per_task
        self.eval_contexts_per_task = eval_contexts_per_task
        self.quality_targets = dict(zip(QUALITIES, targets, strict=True))
        self.train_policy = train_policy
        self.calibration_episodes = calibration_episodes
        self.reference_episodes = reference_episodes
        check_choice(owner, "train_policy", train_policy, ("cycle", *self.policy_names()))

    # ---- what a subclass defines -------------------------------------------------------------------
    @abstractmethod
    def contexts(self, family: TaskFamily, tasks: np.ndarray, quality: np.ndarray, mixing: np.ndarray,
                 rng: np.random.Generator, evaluation: bool, progress: bool, description: str
                 ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """The stored arrays of one split (one row per element of ``tasks``) and its label statistics.

        Row i is a context of task ``tasks[i]`` whose behavior policy has mixing level
        ``mixing[quality[i]]``; ``evaluation`` rows may carry more (T-PRL: the behavior trajectory).
        """

    def extra_targets(self) -> dict[str, float]:
        """Calibrated policies beyond low/medium/high (name -> target share of the optimal return)."""
        return {}

    def knobs(self) -> dict[str, Any]:
        """The setting's own arguments that determine the data (recorded in the manifest)."""
        return {}

    def annotation(self) -> dict[str, Any]:
        """What the manifest's ``info`` records of who labeled the data (labeled settings: the annotator)."""
        return {}

    def eval_context(self, arrays: dict[str, Any]):
        return context_from_fields(self.kind, arrays)

    # ---- shared -------------------------------------------------------------------------------------
    def policy_names(self) -> tuple[str, ...]:
        return (*QUALITIES, *self.extra_targets())

    @property
    def per_task(self) -> tuple[int, int]:  # type: ignore[override]
        return self.trajectories_per_task, self.val_trajectories_per_task

    def config(self) -> dict[str, Any]:
        return {"setting": type(self).__name__, "context_kind": self.kind,
                "trajectories_per_task": self.trajectories_per_task,
                "val_trajectories_per_task": self.val_trajectories_per_task,
                "eval_contexts_per_task": self.eval_contexts_per_task, "quality_targets": self.quality_targets,
                "train_policy": self.train_policy, "calibration_episodes": self.calibration_episodes,
                "reference_episodes": self.reference_episodes, **self.knobs()}

    def _split(self, family: TaskFamily, tasks: np.ndarray, n_per_task: int, mixing: np.ndarray,
               rng: np.random.Generator, description: str, progress: bool, quality: int | None = None
               ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        task_index = np.repeat(np.arange(len(tasks)), n_per_task).astype(np.int32)
        if quality is not None:
            qual = np.full(len(task_index), quality)
        elif self.train_policy == "cycle":
            qual = np.tile(np.arange(n_per_task) % len(QUALITIES), len(tasks))
        else:
            qual = np.full(len(task_index), self.policy_names().index(self.train_policy))
        qual = qual.astype(np.int8)
        arrays, stats = self.contexts(family, tasks[task_index], qual, mixing, rng, quality is not None,
                                      progress, description)
        arrays.update(task_index=task_index, quality=qual)
        return arrays, stats

    def generate(self, family: TaskFamily, progress: bool = True, heldout_stream: dict[str, Any] | None = None
                 ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        """Every split (keeping the generator's state after the val split in ``self.heldout_stream``); given such a
        state, only the held-out splits, drawn from it: the whole generation's bytes, no training task simulated."""
        rng = np.random.default_rng(family.seed)
        targets = {**self.quality_targets, **self.extra_targets()}
        calibration = family.calibrate(targets, self.calibration_episodes, seed=int(rng.integers(2**31)))
        mixing = np.array([calibration[name]["mixing"] for name in targets])
        train, test = family.tasks("train"), family.tasks("test")
        splits: dict[str, dict[str, np.ndarray]] = {
            "tasks": {f"train_{family.task_name}": train, f"test_{family.task_name}": test}}
        info: dict[str, Any] = {"test_reference": {}, "calibration": calibration}
        if heldout_stream is None:
            n_train, n_val = self.per_task
            splits["train"], info["train_statistics"] = self._split(family, train, n_train, mixing, rng,
                                                                    "train contexts", progress)
            splits["val"], _ = self._split(family, train, n_val, mixing, rng, "val contexts", progress)
            self.heldout_stream = rng.bit_generator.state
        else:
            rng.bit_generator.state = heldout_stream
        eval_stats: dict[str, dict[str, float]] = {}
        groups = family.reference_groups(QUALITIES)
        for qi, q in enumerate(QUALITIES):
            splits[f"eval_{q}"], eval_stats[q] = self._split(family, test, self.eval_contexts_per_task, mixing,
                                                             rng, f"eval {q}", progress, quality=qi)
            for group in (g for g in groups if g[-1] == q):
                refs = family.references(test, {g: mixing[QUALITIES.index(g)] for g in group},
                                                self.reference_episodes, rng)
                info["test_reference"].update(refs.pop("test_reference"))
                info.update(refs)
        info.update(eval_statistics=eval_stats, **self.annotation())
        return splits, info

    def evaluation_suites(self, family: TaskFamily, data: StoredDataset) -> list[EvalSuite]:
        """One in-context rollout evaluation per quality on the held-out tasks."""
        test = np.asarray(data["tasks"][f"test_{family.task_name}"])
        info = data.manifest["info"]
        suites = []
        for q in QUALITIES:
            split = data[f"eval_{q}"]
            arrays = {k: to_tensor(np.asarray(v)) for k, v in split.items()}
            tasks = np.asarray(split["task_index"])
            suites.append(EvalSuite(
                env_name=family.metric_env, quality=q, context=self.eval_context(arrays),
                make_env=lambda tasks=test[tasks]: family.make_env(tasks), task_index=tasks,
                horizon=family.horizon, reference=info["test_reference"][q],
                normalize=family.normalizer(info, q, tasks)))
        return suites

