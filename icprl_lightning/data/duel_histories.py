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

What it shares with ``data/learning_histories.py`` (the ``HistoryWindows`` Dataset, the storage, the loaders and
the refusals of the data contract) is ``HistoryWindowDataModule`` (``data/history_windows.py``); here are the
problems, DTS, the window and the duel context. The targets are in the windows themselves: AD scores each duel
(a_h, a'_h) given the duels before it (``ADModule.loss``). No held-out suites are offered (``offers`` is empty): AD
plays online, evaluated by ``evaluation.online_bandit`` (``icprl evaluate online --ad-ckpt``), not from a stored
context.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from icprl_lightning.contexts import StepPreferenceContext
from icprl_lightning.data.history_windows import HistoryWindowDataModule
from icprl_lightning.families.dueling_bandit.env import LinearDuelingBanditFamily
from icprl_lightning.families.dueling_bandit.learning_histories import HISTORY_FIELDS, DTSHistories
from icprl_lightning.progress import track
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


class DuelHistoryDataModule(HistoryWindowDataModule):
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

    family_type = LinearDuelingBanditFamily
    learner_type = DTSHistories
    kind = KIND
    fields = HISTORY_FIELDS
    served = SERVED
    store_name = "dts_history"
    histories = "DTS histories"
    generating = "DTS learning histories"
    offers_note = " (AD is evaluated online: icprl evaluate online --ad-ckpt)"
    unique_val_offsets = True  # distinct offsets: a window is a whole history by default

    def __init__(self, family: LinearDuelingBanditFamily, learner: DTSHistories | None = None,
                 n_train_problems: int = 1000, n_val_problems: int = 64, n_eval_problems: int = 200,
                 window: int | None = None, windows_per_epoch: int = 2048, val_windows_per_history: int = 1,
                 batch_size: int = 32, data_dir: str | None = None, root_dir: str = "data", overwrite: bool = False,
                 verify_checksums: bool = True, progress: bool = True) -> None:
        counts = {"n_train_problems": n_train_problems, "n_val_problems": n_val_problems,
                  "n_eval_problems": n_eval_problems}
        super().__init__(family, learner, counts, windows_per_epoch, val_windows_per_history, batch_size, data_dir,
                         root_dir, overwrite, verify_checksums, progress)
        rounds = self.learner.rounds
        if window is not None:
            check_int(type(self).__name__, "window", window, 1)
            if window > rounds:
                raise HyperparameterError(f"{type(self).__name__}: window must be <= the learner's rounds ({rounds}): "
                                          f"a window lies inside one history, got {window}")
        self.n_problems = {"train": n_train_problems, "val": n_val_problems, "test": n_eval_problems}
        self.window = rounds if window is None else window

    @property
    def context_length(self) -> int:
        """Rounds per window (the model's ``max_context``)."""
        return self.window

    def train_arrays(self) -> dict[str, np.ndarray]:
        """The training histories as the served fields (states of width 0; arms memory-mapped)."""
        train = self.load()["train"]
        first = train["arms_first"]
        return {"states": np.zeros((*first.shape, 0), dtype=np.float32), "actions": first,
                "alt_actions": train["arms_second"], "preferred": train["preferred"]}

    # ---- storage -------------------------------------------------------------------------------------
    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        return {**self.family.config(), **self.learner.config(), "setting": "DTSHistories",
                **{f"n_{split}_problems": n for split, n in self.n_problems.items()}}

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

    def required_fields(self) -> dict[str, list[str]]:
        return {"tasks": [f"{s}_theta" for s in SPLITS], **dict.fromkeys(("train", "val"),
                                                                         [*HISTORY_FIELDS, "task_index"])}

    # ---- batches -------------------------------------------------------------------------------------
    def histories_per_task(self, split: str) -> int:
        return 1  # one DTS history per problem

    def window_context(self, window: dict[str, Tensor]) -> StepPreferenceContext:
        return duel_window(window)
