"""Linear dueling-bandit datasets as a LightningDataModule (paper, appendix "Dueling Bandit Experiments").

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
  splits are read only by ``bandit_suites`` (the evaluation); the dataloaders never touch them.

Problem parameters come from independent seed streams per split, so the held-out problems do not change
with the training-set size. The manifest records each split's label agreement (the share of BT labels
that agree with the true reward order): with θ, φ ~ N(0, I/d) reward gaps are small and it is only
≈ 0.6 — the labels are very noisy, which is what makes the paper's problems hard.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from rich.progress import track

from icprl_lightning.contexts import ActionSpec, StepPreferenceContext
from icprl_lightning.data.batches import to_tensor
from icprl_lightning.data.datamodule import InContextDataModule
from icprl_lightning.data.suites import BanditSuite, EvalSuite
from icprl_lightning.envs.dueling_bandit import LinearDuelingBanditFamily
from icprl_lightning.preferences import label_agreement

EVAL_SOURCES = ("uniform", "dirichlet", "dts")
_CHUNK = 10_000  # problems generated per step, bounding memory at paper scale (100k contexts)


class DuelingBanditDataModule(InContextDataModule):
    """Dueling-bandit I-PRL contexts; see the module docstring.

    Args:
        n_train_problems: pretraining problems (paper: 100k contexts in all; here contexts = problems ×
            ``contexts_per_problem``).
        contexts_per_problem: uniform-pair contexts per pretraining problem (≥ 2 for ICPO's pairs).
        n_val_problems / val_contexts_per_problem: fresh problems for the validation loss.
        n_eval_problems: held-out problems, each with one context per source in ``eval_sources``.
        n_arms, dim, horizon: |A|, d and H (paper: 20, 10, 200).
        bt_temperature: Bradley–Terry temperature (paper: 1).
        dts_alpha: DTS confidence scale, for the DTS contexts and the DTS baseline.
        seed: fixes the arm features φ and every problem and context.
    """

    family_name = "dueling_bandit"

    def __init__(self, n_train_problems: int = 2000, contexts_per_problem: int = 2, n_val_problems: int = 64,
                 val_contexts_per_problem: int = 2, n_eval_problems: int = 200,
                 eval_sources: tuple[str, ...] = EVAL_SOURCES, n_arms: int = 20, dim: int = 10,
                 horizon: int = 200, bt_temperature: float = 1.0, dts_alpha: float = 0.51, seed: int = 0,
                 data_dir: str | None = None, root_dir: str = "data", batch_size: int = 32, pairs: bool = True,
                 overwrite: bool = False, verify_checksums: bool = True, progress: bool = True) -> None:
        super().__init__(data_dir=data_dir, root_dir=root_dir, batch_size=batch_size, pairs=pairs,
                         query_labels=False, overwrite=overwrite, verify_checksums=verify_checksums,
                         progress=progress)
        # Saved so that a checkpoint alone rebuilds this DataModule (scripts/bandit_results.py).
        self.save_hyperparameters()
        unknown = set(eval_sources) - set(EVAL_SOURCES)
        if unknown:
            raise ValueError(f"unknown eval_sources {sorted(unknown)}; expected a subset of {EVAL_SOURCES}")
        if min(n_train_problems, n_val_problems, n_eval_problems) < 1:
            raise ValueError("n_train_problems, n_val_problems and n_eval_problems must be >= 1")
        self.family = LinearDuelingBanditFamily(n_arms=n_arms, dim=dim, horizon=horizon, seed=seed,
                                                bt_temperature=bt_temperature, dts_alpha=dts_alpha)
        # The same features with one more step: the behaviour's duel after the H-th comparison.
        self.eval_family = LinearDuelingBanditFamily(n_arms=n_arms, dim=dim, horizon=horizon + 1, seed=seed,
                                                     bt_temperature=bt_temperature, dts_alpha=dts_alpha)
        self.n_problems = {"train": n_train_problems, "val": n_val_problems, "test": n_eval_problems}
        self.per_task = (contexts_per_problem, val_contexts_per_problem)
        self.eval_sources = tuple(eval_sources)
        self.seed = seed

    @property
    def context_kind(self) -> str:
        return "step_preference"

    @property
    def state_dim(self) -> int:
        return 0

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=True, size=self.family.n_arms)

    def generator_config(self) -> dict[str, Any]:
        f = self.family
        return {"family": "dueling_bandit", "context_kind": "step_preference", "n_arms": f.n_arms, "dim": f.dim,
                "horizon": f.horizon, "bt_temperature": f.bt_temperature, "dts_alpha": f.dts_alpha,
                "n_train_problems": self.n_problems["train"], "contexts_per_problem": self.per_task[0],
                "n_val_problems": self.n_problems["val"], "val_contexts_per_problem": self.per_task[1],
                "n_eval_problems": self.n_problems["test"], "eval_sources": list(self.eval_sources),
                "seed": self.seed}

    # ---- generation --------------------------------------------------------------------------------
    def _pretraining_split(self, theta: np.ndarray, per_problem: int, rng: np.random.Generator,
                           description: str) -> tuple[dict[str, np.ndarray], float]:
        """``per_problem`` uniform-pair contexts per row of ``theta``, task-major."""
        task_index = np.repeat(np.arange(len(theta)), per_problem).astype(np.int32)
        chunks, agree = [], []
        starts = range(0, len(task_index), _CHUNK)
        for start in track(starts, description=description, disable=not self.progress, transient=True):
            rows = theta[task_index[start:start + _CHUNK]]
            context = self.family.uniform_pairs_context(rows, rng)
            chunks.append(context)
            agree.append(self._agreement(rows, context))
        context = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
        arrays = self._as_step_preferences(context)
        arrays["task_index"] = task_index
        rates, weights = zip(*agree, strict=True)
        return arrays, float(np.average(rates, weights=weights))

    def _agreement(self, theta: np.ndarray, context: dict[str, np.ndarray]) -> tuple[float, int]:
        """(label agreement rate, number of duels between arms of different reward)."""
        rewards = self.family.expected_rewards(theta)
        first = np.take_along_axis(rewards, context["arms_first"], axis=1)
        second = np.take_along_axis(rewards, context["arms_second"], axis=1)
        return label_agreement(first, second, context["preferred"]), int((first != second).sum())

    def _as_step_preferences(self, context: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        n, h = context["preferred"].shape
        return {"states": np.zeros((n, h, 0), dtype=np.float32),
                "actions": context["arms_first"].astype(np.int16),
                "alt_actions": context["arms_second"].astype(np.int16),
                "preferred": context["preferred"].astype(np.uint8)}

    def _eval_split(self, source: str, theta: np.ndarray, rng: np.random.Generator) -> tuple[dict[str, np.ndarray],
                                                                                              float]:
        """One context of H + 1 duels per held-out problem: H to condition on, shifted by one as the behaviour."""
        full = self.eval_family.make_context(source, theta, rng)
        context = {k: v[:, :self.family.horizon] for k, v in full.items()}
        arrays = self._as_step_preferences(context)
        arrays["next_actions"] = full["arms_first"][:, 1:].astype(np.int16)
        arrays["next_alt_actions"] = full["arms_second"][:, 1:].astype(np.int16)
        arrays["expected_rewards"] = self.family.expected_rewards(theta)
        return arrays, self._agreement(theta, context)[0]

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        train_seq, val_seq, test_seq = np.random.SeedSequence(self.seed).spawn(3)
        thetas, rngs = {}, {}
        for split, seq in (("train", train_seq), ("val", val_seq), ("test", test_seq)):
            rngs[split] = np.random.default_rng(seq)
            thetas[split] = self.family.sample_tasks(self.n_problems[split], rngs[split])
        splits: dict[str, dict[str, np.ndarray]] = {"tasks": {f"{k}_theta": v for k, v in thetas.items()}}
        agreement: dict[str, float] = {}
        splits["train"], agreement["train"] = self._pretraining_split(thetas["train"], self.per_task[0],
                                                                      rngs["train"], "bandit train contexts")
        splits["val"], agreement["val"] = self._pretraining_split(thetas["val"], self.per_task[1], rngs["val"],
                                                                  "bandit val contexts")
        # One stream per source, so that adding a source leaves the others' contexts unchanged.
        for source, seq in zip(EVAL_SOURCES, test_seq.spawn(len(EVAL_SOURCES)), strict=True):
            if source in self.eval_sources:
                name = f"eval_{source}"
                splits[name], agreement[name] = self._eval_split(source, thetas["test"], np.random.default_rng(seq))
        info = {"label_agreement": agreement,
                "label_note": "share of BT labels agreeing with the true reward order (ties, i.e. DTS "
                              "self-duels, left out); 0.5 would be pure noise"}
        return splits, info

    # ---- evaluation --------------------------------------------------------------------------------
    def evaluation_suites(self) -> list[EvalSuite]:
        """No environment rollouts: a bandit is evaluated by weak regret (``bandit_suites``)."""
        return []

    def bandit_suites(self) -> list[BanditSuite]:
        """One weak-regret evaluation per context source, on the held-out problems."""
        data = self.load()
        suites = []
        for source in self.eval_sources:
            split = data[f"eval_{source}"]
            arrays = {k: to_tensor(np.array(v)) for k, v in split.items()}
            context = StepPreferenceContext(states=arrays["states"], actions=arrays["actions"],
                                            alt_actions=arrays["alt_actions"], preferred=arrays["preferred"])
            suites.append(BanditSuite(source=source, context=context,
                                      expected_rewards=torch.from_numpy(np.array(split["expected_rewards"])),
                                      behavior_first=arrays["next_actions"],
                                      behavior_second=arrays["next_alt_actions"], dts_alpha=self.family.dts_alpha))
        return suites
