"""Dueling-bandit learning histories as training data: the LightningDataModule of Algorithm Distillation on duels
(``methods/ad.py`` with ``context_kind: step_preference``; docs/ad_bandit.md).

AD (Laskin et al. 2022) distills a learner from its whole learning histories. Here the learner is Double Thompson
Sampling (Wu & Liu 2016; ``families/dueling_bandit/learning_histories.py``) and a history is its duels and their
outcomes, round by round: no rewards, utilities or θ reach a batch, so the AD trained on it is reward-free.

* ``prepare_data()`` draws the problems as ``BanditDuels`` does (one seed stream per split from the family's
  ``seed``: ``train``, ``val`` and the held-out ``test`` problems, so ``tasks/test_theta`` are the same problems
  as ``configs/icpo_bandit.yaml``'s for the same ``n_eval_problems``), runs DTS on every training and validation
  problem (one history each) and writes the histories atomically with their manifest under the dataset's lock
  (``data/store.py``), in ``<root_dir>/dueling_bandit-dts_history-<hash of the config>``. Splits: ``tasks``
  (``train_theta``, ``val_theta``, ``test_theta``: read by the evaluation only, never batched), ``train`` and
  ``val`` (``arms_first``, ``arms_second`` int16 [N, rounds], ``preferred`` uint8 [N, rounds], ``task_index``
  [N]). The manifest's info holds DTS's mean weak and strong regret over its first and last 20 rounds (computed
  from θ at generation; a check that the histories show learning, not something a model reads). A dataset made
  with another config is an error naming the keys that differ.
* A batch is B windows of ``window`` consecutive rounds (default: the whole history, which is what deployment
  sees: AD plays from an empty context), each from a uniformly drawn history at a uniformly drawn offset
  (``torch``'s generator), served as ``ContextSamples`` of a ``StepPreferenceContext`` with states of shape
  [B, T, 0] (the bandit context kind: token h holds duel h and its outcome); ``windows_per_epoch`` windows make
  an epoch. Validation windows are fixed: ``val_windows_per_history`` evenly spaced offsets per val history.

The targets are in the windows themselves: AD scores each duel (a_h, a'_h) given the duels before it
(``ADModule.loss``). No held-out suites are offered (``offers`` is empty): AD plays online, evaluated by
``evaluation.online_bandit`` (``icprl evaluate online --ad-ckpt``), not from a stored context.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler

from icprl_lightning.contexts import ActionSpec, StepPreferenceContext
from icprl_lightning.data.learning_histories import HistoryWindows
from icprl_lightning.data.store import (
    StoredDataset,
    check_replaceable_dataset,
    dataset_lock,
    load_dataset,
    write_dataset,
)
from icprl_lightning.data_contract import EVALUATIONS
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.learning_histories import HISTORY_FIELDS, DTSHistories
from icprl_lightning.progress import track
from icprl_lightning.samples import ContextSamples
from icprl_lightning.validation import HyperparameterError, check_int

KIND = "step_preference"
SERVED = ("states", "actions", "alt_actions", "preferred")  # a window's context fields (states of width 0)
SPLITS = ("train", "val", "test")
CHUNK = 250  # problems per DTS run: progress and bounded memory
REPORT_ROUNDS = 20  # the manifest's first/last-rounds regret


def duel_window(window: dict[str, Tensor]) -> StepPreferenceContext:
    """A window of recorded duels as the bandit's ``StepPreferenceContext`` (states [B, T, 0])."""
    first = window["arms_first"]
    return StepPreferenceContext(torch.zeros(*first.shape, 0), first, window["arms_second"], window["preferred"])


class DuelHistoryDataModule(L.LightningDataModule):
    """DTS's learning histories on ``family``'s training problems, served as windows; see the module docstring.

    Args:
        family: the linear dueling bandit (its ``seed`` fixes the problems and every draw of the histories; its
            ``dts_alpha`` is DTS's).
        learner: the source learner whose histories AD distills (``rounds`` per history).
        n_train_problems / n_val_problems: problems with one DTS history each, for training / the validation loss.
        n_eval_problems: held-out problems (``tasks/test_theta``), only drawn, for the online evaluation.
        window: rounds per window, the model's ``max_context`` (None: the learner's ``rounds``, a whole history).
        windows_per_epoch: training windows per epoch (drawn afresh each epoch).
        val_windows_per_history: fixed validation windows per val history (1 when a window is a whole history).
        batch_size: windows per batch.
        data_dir: the dataset's directory (default: under ``root_dir``, named by the config's hash).
        overwrite: regenerate even if the dataset exists.
        verify_checksums: check every file's SHA-256 when loading.
        progress: a progress bar while DTS runs.
    """

    pairs = False          # a window is its own context and its own targets: nothing served beside it
    query_labels = False
    offers: frozenset[str] = frozenset()  # played online (evaluation/online_bandit.py), not on stored contexts

    def __init__(self, family: LinearDuelingBanditFamily, learner: DTSHistories | None = None,
                 n_train_problems: int = 1000, n_val_problems: int = 64, n_eval_problems: int = 200,
                 window: int | None = None, windows_per_epoch: int = 2048, val_windows_per_history: int = 1,
                 batch_size: int = 32, data_dir: str | None = None, root_dir: str = "data", overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        owner = type(self).__name__
        if not isinstance(family, LinearDuelingBanditFamily):
            raise HyperparameterError(f"{owner}: family must be a LinearDuelingBanditFamily, got "
                                      f"{type(family).__name__}")
        learner = DTSHistories() if learner is None else learner
        if not isinstance(learner, DTSHistories):
            raise HyperparameterError(f"{owner}: learner must be a DTSHistories, got {type(learner).__name__}")
        for key, value in (("n_train_problems", n_train_problems), ("n_val_problems", n_val_problems),
                           ("n_eval_problems", n_eval_problems), ("windows_per_epoch", windows_per_epoch),
                           ("val_windows_per_history", val_windows_per_history), ("batch_size", batch_size)):
            check_int(owner, key, value, 1)
        if window is not None:
            check_int(owner, "window", window, 1)
            if window > learner.rounds:
                raise HyperparameterError(f"{owner}: window must be <= the learner's rounds ({learner.rounds}): a "
                                          f"window lies inside one history, got {window}")
        super().__init__()
        self.family, self.learner = family, learner
        self.n_problems = {"train": n_train_problems, "val": n_val_problems, "test": n_eval_problems}
        self.window = learner.rounds if window is None else window
        self.windows_per_epoch, self.val_windows_per_history = windows_per_epoch, val_windows_per_history
        self.batch_size = batch_size
        self.data_dir, self.root_dir = data_dir, root_dir
        self.overwrite, self.verify_checksums, self.progress = overwrite, verify_checksums, progress
        self.dataset: StoredDataset | None = None

    # ---- the data contract (data_contract.PreferenceData) ----------------------------------------------
    @property
    def context_kind(self) -> str:
        return KIND

    @property
    def state_dim(self) -> int:
        return 0

    @property
    def action_spec(self) -> ActionSpec:
        return self.family.action_spec

    @property
    def context_length(self) -> int:
        """Rounds per window (the model's ``max_context``)."""
        return self.window

    @property
    def metric_env(self) -> str:
        return self.family.metric_env

    def batch_fields(self) -> tuple[str, ...]:
        return SERVED

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training histories as the served fields (states of width 0; arms memory-mapped)."""
        train = self.load()["train"]
        first = train["arms_first"]
        return {"states": np.zeros((*first.shape, 0), dtype=np.float32), "actions": first,
                "alt_actions": train["arms_second"], "preferred": train["preferred"]}

    def evaluation_suites(self) -> list:
        """None: AD plays online (``evaluation.online_bandit``), not on a stored context."""
        return []

    def bandit_suites(self) -> list:
        raise ValueError(f"DTS histories offer no bandit_suites; it needs {EVALUATIONS['bandit_suites']} (AD is "
                         "evaluated online: icprl evaluate online --ad-ckpt)")

    def heldout_pairs(self) -> dict[str, ContextSamples]:
        raise ValueError(f"DTS histories offer no heldout_pairs; it needs {EVALUATIONS['heldout_pairs']}")

    # ---- storage -------------------------------------------------------------------------------------
    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.learner.config(), "setting": "DTSHistories",
                **{f"n_{split}_problems": n for split, n in self.n_problems.items()}}

    @property
    def path(self) -> Path:
        if self.data_dir is not None:
            return Path(self.data_dir)
        digest = hashlib.sha256(json.dumps(self.generator_config(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root_dir) / f"{self.family.name}-dts_history-{digest}"

    @property
    def regenerate_hint(self) -> str:
        return f"delete {self.path} (or pass --data.init_args.overwrite true); fit generates a missing dataset"

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        """``tasks``, ``train`` and ``val`` (one seed stream per split, as ``BanditDuels``) and the manifest's info."""
        thetas, rngs = {}, {}
        for split, seq in zip(SPLITS, np.random.SeedSequence(self.family.seed).spawn(len(SPLITS)), strict=True):
            rngs[split] = np.random.default_rng(seq)
            thetas[split] = self.family.sample_tasks(self.n_problems[split], rngs[split])
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {f"{k}_theta": v for k, v in thetas.items()}}
        info = {}
        for split in ("train", "val"):
            theta = thetas[split]
            chunks = [self.learner.run(self.family, theta[start:start + CHUNK], rngs[split]) for start in
                      track(range(0, len(theta), CHUNK), f"DTS histories ({split})", unit="chunk",
                            enabled=self.progress)]
            history = {k: np.concatenate([c[k] for c in chunks]) for k in HISTORY_FIELDS}
            info[split] = self._regret_info(theta, history)
            history["arms_first"] = history["arms_first"].astype(np.int16)
            history["arms_second"] = history["arms_second"].astype(np.int16)
            history["task_index"] = np.arange(len(theta), dtype=np.int32)
            splits[split] = history
        return splits, {"dts_regret": info}

    def _regret_info(self, theta: np.ndarray, history: dict[str, np.ndarray]) -> dict[str, float]:
        """DTS's mean weak and strong regret over its first and last ``REPORT_ROUNDS`` rounds."""
        rewards = self.family.expected_rewards(theta)
        gaps = rewards.max(1, keepdims=True) - rewards
        first = np.take_along_axis(gaps, history["arms_first"], 1)
        second = np.take_along_axis(gaps, history["arms_second"], 1)
        n = min(REPORT_ROUNDS, first.shape[1])
        out = {}
        for name, regret in (("weak", np.minimum(first, second)), ("strong", (first + second) / 2)):
            out[f"first_{n}_rounds_{name}_regret"] = round(float(regret[:, :n].mean()), 4)
            out[f"last_{n}_rounds_{name}_regret"] = round(float(regret[:, -n:].mean()), 4)
        return out

    def prepare_data(self) -> None:
        path = self.path
        with dataset_lock(path):  # a second process waits here, then finds the dataset made by the first
            if not self.overwrite and (path.exists() or path.is_symlink()):
                self._read(verify=False)
                return
            check_replaceable_dataset(path)
            if self.progress:
                print(f"generating DTS learning histories -> {path}", flush=True)
            splits, info = self.generate()
            write_dataset(path, splits, self.generator_config(), info=info, overwrite=True)
        self.overwrite = False

    def _read(self, verify: bool) -> StoredDataset:
        data = load_dataset(self.path, self.generator_config(), verify=verify, regenerate_hint=self.regenerate_hint)
        needs = {"tasks": [f"{s}_theta" for s in SPLITS], **dict.fromkeys(("train", "val"),
                                                                            [*HISTORY_FIELDS, "task_index"])}
        data.require(needs, self.regenerate_hint)
        return data

    def load(self) -> StoredDataset:
        if self.dataset is None:
            self.dataset = self._read(verify=self.verify_checksums)
        return self.dataset

    # ---- batches -------------------------------------------------------------------------------------
    def val_offsets(self) -> np.ndarray:
        """(row, offset) of every validation window [M, 2]: evenly spaced (distinct) offsets in each val history."""
        rows, rounds = self.load()["val"]["arms_first"].shape
        starts = np.unique(np.linspace(0, rounds - self.window, self.val_windows_per_history).astype(np.int64))
        return np.stack(np.meshgrid(np.arange(rows), starts, indexing="ij"), axis=-1).reshape(-1, 2)

    def _windows(self, split: str, size: int, offsets: np.ndarray | None) -> HistoryWindows:
        return HistoryWindows(self.load()[split], self.window, 1, size, offsets, fields=HISTORY_FIELDS,
                              build=duel_window)

    def train_dataloader(self) -> DataLoader:
        data = self._windows("train", self.windows_per_epoch, None)
        sampler = BatchSampler(RandomSampler(data), self.batch_size, drop_last=len(data) >= self.batch_size)
        return DataLoader(data, sampler=sampler, batch_size=None)

    def val_dataloader(self) -> DataLoader:
        data = self._windows("val", 0, self.val_offsets())
        return DataLoader(data, sampler=BatchSampler(SequentialSampler(data), self.batch_size, drop_last=False),
                          batch_size=None)
