"""ICPO on linear dueling bandits: the DataModule, weak-regret evaluation, the configs, a learning test."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from icprl_lightning.bandit_evaluation import (
    dts_duels,
    icpo_duels,
    regret_curve,
    summarize_regret,
)
from icprl_lightning.baselines.dts import DoubleThompsonSampling
from icprl_lightning.callbacks.bandit_regret import BanditRegretCallback
from icprl_lightning.cli import run_cli
from icprl_lightning.contexts import ActionSpec, StepPreferenceContext
from icprl_lightning.data.bandit_datamodule import EVAL_SOURCES, DuelingBanditDataModule
from icprl_lightning.deploy import Agent
from icprl_lightning.models.policy import InContextPolicy

TINY = dict(n_train_problems=6, contexts_per_problem=2, n_val_problems=2, val_contexts_per_problem=2,
            n_eval_problems=5, batch_size=4, progress=False)
CONTEXT_KEYS = {"states", "actions", "alt_actions", "preferred"}


@pytest.fixture(scope="module")
def tiny_bandit(tmp_path_factory) -> DuelingBanditDataModule:
    dm = DuelingBanditDataModule(root_dir=str(tmp_path_factory.mktemp("bandit")), **TINY)
    dm.prepare_data()
    return dm


def _digests(dm: DuelingBanditDataModule) -> list[tuple[str, str]]:
    """SHA-256 of every stored array that holds random draws (not the empty states or the task indices)."""
    files = dm.load().manifest["files"].items()
    return sorted((k, v["sha256"]) for k, v in files if not k.endswith(("states.npy", "task_index.npy")))


# ---- the DataModule --------------------------------------------------------------------------------

def test_batches_are_stateless_duels_with_pairs_and_no_task_information(tiny_bandit):
    assert tiny_bandit.state_dim == 0 and tiny_bandit.action_spec == ActionSpec(True, 20)
    assert tiny_bandit.context_length == 200
    for loader in (tiny_bandit.train_dataloader(), tiny_bandit.val_dataloader()):
        batch = next(iter(loader))
        assert set(batch) == CONTEXT_KEYS | {f"pair_{k}" for k in CONTEXT_KEYS}  # no θ, no rewards
        assert batch["states"].shape == (4, 200, 0) and batch["states"].dtype == torch.float32
        assert batch["actions"].shape == (4, 200) and batch["actions"].dtype == torch.int64
        assert (batch["actions"] != batch["alt_actions"]).all()  # uniform pretraining pairs are distinct
        assert set(batch["preferred"].unique().tolist()) <= {0.0, 1.0}
        StepPreferenceContext(**{k: batch[k] for k in CONTEXT_KEYS}).validate(0, tiny_bandit.action_spec)


def test_eval_splits_hold_behaviour_next_duels_and_rewards_for_evaluation_only(tiny_bandit):
    data = tiny_bandit.load()
    test_theta = np.asarray(data["tasks"]["test_theta"])
    assert not np.isin(test_theta, np.asarray(data["tasks"]["train_theta"])).any()
    suites = tiny_bandit.bandit_suites()
    assert [s.source for s in suites] == list(EVAL_SOURCES)
    for suite in suites:
        split = data[f"eval_{suite.source}"]
        assert set(vars(suite.context)) == CONTEXT_KEYS  # what a policy sees: duels only
        assert suite.context.states.shape == (5, 200, 0)
        # column h - 1 of the behaviour duels is the context's duel h + 1
        np.testing.assert_array_equal(np.asarray(split["next_actions"])[:, :-1], np.asarray(split["actions"])[:, 1:])
        np.testing.assert_allclose(suite.expected_rewards.numpy(), tiny_bandit.family.expected_rewards(test_theta))
    agreement = data.manifest["info"]["label_agreement"]
    assert set(agreement) == {"train", "val", *(f"eval_{s}" for s in EVAL_SOURCES)}
    assert all(0.5 < v < 0.7 for v in agreement.values()), agreement  # noisy labels, but not coin flips


def test_same_seed_same_bytes_and_held_out_problems_independent_of_training_size(tmp_path, tiny_bandit):
    again = DuelingBanditDataModule(data_dir=str(tmp_path / "again"), **TINY)
    again.prepare_data()
    assert _digests(again) == _digests(tiny_bandit)
    bigger = DuelingBanditDataModule(data_dir=str(tmp_path / "bigger"), **{**TINY, "n_train_problems": 9})
    bigger.prepare_data()
    assert [d for d in _digests(bigger) if d[0].startswith("eval_")] == \
        [d for d in _digests(tiny_bandit) if d[0].startswith("eval_")]
    other = DuelingBanditDataModule(data_dir=str(tmp_path / "other"), **{**TINY, "seed": 1})
    other.prepare_data()
    assert not set(_digests(other)) & set(_digests(tiny_bandit))


# ---- weak-regret evaluation ------------------------------------------------------------------------

def test_regret_curve_and_summary_by_hand():
    rewards = torch.tensor([[0.0, 1.0, 3.0], [2.0, 2.0, 0.0]], dtype=torch.float64)
    first = torch.tensor([[0, 2], [2, 0]])
    second = torch.tensor([[1, 0], [2, 1]])
    curve = regret_curve(rewards, (first, second))
    # problem 0: (0, 1) -> min(3, 2) = 2, (2, 0) -> 0; problem 1 (R* = 2): (2, 2) -> 2, (0, 1) -> 0
    torch.testing.assert_close(curve, torch.tensor([[2.0, 0.0], [2.0, 0.0]], dtype=torch.float64))
    summary = summarize_regret(curve)
    assert summary["weak_regret"] == 0.0 and summary["weak_regret_sem"] == 0.0
    assert summary["weak_regret_auc"] == 1.0 and summary["weak_regret_auc_sem"] == 0.0


class PrefixArmPolicy(nn.Module):
    """Prefers arm (h − 1) mod A after h comparisons: reveals which prefix each query saw."""

    state_dim = 0

    def __init__(self, n_arms: int) -> None:
        super().__init__()
        self.action_spec = ActionSpec(True, n_arms)
        self.unused = nn.Parameter(torch.zeros(()))

    def forward(self, context: StepPreferenceContext, queries: Tensor, visible: Tensor) -> Tensor:
        assert queries.shape == (context.batch_size, len(visible), 0)
        logits = nn.functional.one_hot((visible - 1) % self.action_spec.size, self.action_spec.size).float()
        return logits.expand(context.batch_size, -1, -1)


def _random_context(b: int, h: int, n_arms: int, seed: int = 0) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(seed)
    first = torch.randint(0, n_arms, (b, h), generator=g)
    second = (first + torch.randint(1, n_arms, (b, h), generator=g)) % n_arms
    return StepPreferenceContext(torch.zeros(b, h, 0), first, second, torch.randint(0, 2, (b, h), generator=g).float())


def test_icpo_plays_the_argmax_after_each_prefix_and_a_uniform_other_arm():
    context = _random_context(b=5, h=12, n_arms=4)
    first, second = icpo_duels(PrefixArmPolicy(4), context, np.random.default_rng(0), chunk_size=2)
    torch.testing.assert_close(first, (torch.arange(12) % 4).expand(5, 12))
    assert (second != first).all() and second.min() >= 0 and second.max() < 4
    first_big, second_big = icpo_duels(PrefixArmPolicy(4), context, np.random.default_rng(0), chunk_size=32)
    assert torch.equal(first, first_big) and torch.equal(second, second_big)


def test_icpo_last_prefix_matches_the_deployed_agent_on_the_whole_context():
    torch.manual_seed(0)
    policy = InContextPolicy("step_preference", 0, ActionSpec(True, 6), 2, 32, 2, max_context=20)
    context = _random_context(b=7, h=20, n_arms=6)
    first, _ = icpo_duels(policy, context, np.random.default_rng(0))
    agent = Agent(policy, greedy=True)
    agent.reset(context)
    assert torch.equal(first[:, -1], agent.act(torch.zeros(7, 0)))


def test_incremental_dts_equals_dts_rerun_on_every_prefix():
    context = _random_context(b=6, h=15, n_arms=5)
    first, second = dts_duels(context, 5, np.random.default_rng(3))
    rng = np.random.default_rng(3)
    arrays = [x.numpy() for x in (context.actions, context.alt_actions)] + [context.preferred.numpy().astype(np.uint8)]
    for h in range(1, 16):
        dts = DoubleThompsonSampling(5, 6, rng=rng)
        dts.observe_context(*(x[:, :h] for x in arrays))
        ref_first, ref_second = dts.select()
        np.testing.assert_array_equal(first[:, h - 1].numpy(), ref_first)
        np.testing.assert_array_equal(second[:, h - 1].numpy(), ref_second)


# ---- configs ---------------------------------------------------------------------------------------

def _tiny_cli_args(root) -> list[str]:
    args = ["--data.init_args.root_dir", str(root)]
    for key, value in TINY.items():
        args += [f"--data.init_args.{key}", str(value).lower() if isinstance(value, bool) else str(value)]
    return args


def test_config_runs_under_fast_dev_run_and_logs_weak_regret(tmp_path):
    # default_root_dir: Lightning 2.6 still writes last.ckpt under fast_dev_run; keep it out of the repo.
    cli = run_cli(["fit", "--config", "configs/icpo_bandit.yaml", "--trainer.fast_dev_run", "1",
                   "--trainer.logger", "false", "--trainer.default_root_dir", str(tmp_path),
                   *_tiny_cli_args(tmp_path)])
    assert cli.trainer.state.finished
    assert cli.model.hparams.state_dim == 0 and cli.model.hparams.max_context == 200  # linked from the data
    callback = next(c for c in cli.trainer.callbacks if isinstance(c, BanditRegretCallback))
    expected = {f"val/bandit/{s}/{m}weak_regret{auc}" for s in EVAL_SOURCES for m in ("", "dts_", "behavior_")
                for auc in ("", "_auc")}
    assert set(callback.last_results) == expected
    assert all(np.isfinite(v) and v >= 0 for v in callback.last_results.values())


def test_paper_config_has_the_paper_sizes():
    cli = run_cli(["--config", "configs/paper/icpo_bandit.yaml", "--trainer.logger", "false"], run=False)
    hp, dm = cli.model.hparams, cli.datamodule
    assert (hp.n_layer, hp.n_embd, hp.n_head, hp.lr, dm.batch_size) == (6, 256, 8, 3e-4, 32)
    assert dm.n_problems["train"] * dm.trajectories_per_task[0] == 100_000
    assert (dm.family.n_arms, dm.family.dim, dm.context_length, hp.state_dim) == (20, 10, 200, 0)


# ---- learning --------------------------------------------------------------------------------------

def _uniform_pair_regret(rewards: np.ndarray) -> np.ndarray:
    """Exact expected weak regret of a uniformly random pair of distinct arms, per problem."""
    gaps = rewards.max(axis=1, keepdims=True) - rewards
    pair = np.minimum(gaps[:, :, None], gaps[:, None, :])
    n_arms = rewards.shape[1]
    return (pair.sum(axis=(1, 2)) - gaps.sum(axis=1)) / (n_arms * (n_arms - 1))


@pytest.mark.slow
def test_icpo_beats_uniform_random_duels_on_held_out_problems(tmp_path):
    """A small, less noisy bandit (6 arms, d = 4, H = 40, BT temperature 0.3) trained for one epoch (125 steps)."""
    data = ["--data.init_args.root_dir", str(tmp_path), "--data.init_args.n_arms", "6", "--data.init_args.dim", "4",
            "--data.init_args.horizon", "40", "--data.init_args.bt_temperature", "0.3",
            "--data.init_args.n_train_problems", "2000", "--data.init_args.n_eval_problems", "300",
            "--data.init_args.eval_sources", "[uniform]", "--data.init_args.progress", "false"]
    cli = run_cli(["fit", "--config", "configs/icpo_bandit.yaml", "--trainer.logger", "false",
                   "--trainer.max_epochs", "1", "--trainer.enable_checkpointing", "false",
                   "--trainer.enable_progress_bar", "false", "--trainer.callbacks", "[]",
                   "--trainer.default_root_dir", str(tmp_path), *data])
    suite = cli.datamodule.bandit_suites()[0]
    first, second = icpo_duels(cli.model.policy, suite.context, np.random.default_rng(0))
    icpo = regret_curve(suite.expected_rewards, (first, second))[:, -1].numpy()
    uniform = _uniform_pair_regret(suite.expected_rewards.numpy())
    diff = uniform - icpo
    assert diff.mean() > 3 * diff.std(ddof=1) / np.sqrt(len(diff)), (icpo.mean(), uniform.mean())
    assert icpo.mean() < 0.6 * uniform.mean(), (icpo.mean(), uniform.mean())  # measured: 0.05 vs 0.26
