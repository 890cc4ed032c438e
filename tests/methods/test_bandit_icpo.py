"""ICPO on linear dueling bandits: the DataModule, weak-regret evaluation, the configs, a learning test."""

from __future__ import annotations

import json
import warnings

import lightning as L
import numpy as np
import pytest
import torch
import yaml
from factories import bandit_data, cli_data_args, config_args  # noqa: E402
from torch import Tensor, nn

from icprl_lightning.callbacks.bandit_regret import BanditRegretCallback
from icprl_lightning.commands import main, run_cli
from icprl_lightning.contexts import ActionSpec, StepPreferenceContext
from icprl_lightning.data import PreferenceDataModule  # noqa: E402
from icprl_lightning.data.settings.bandit_duels import EVAL_SOURCES  # noqa: E402
from icprl_lightning.deploy import Agent, load_agent
from icprl_lightning.evaluation import (
    agent_duels,
    dts_duels,
    evaluate_duels,
    method_name,
    regret_curve,
    summarize_regret,
)
from icprl_lightning.evaluation.duels import baseline_curves, regret_curves, summarize_regrets
from icprl_lightning.families.dueling_bandit.dts import DoubleThompsonSampling
from icprl_lightning.methods.icpo import ICPOModule
from icprl_lightning.metrics import WeakRegret
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.models.policy import InContextPolicy
from icprl_lightning.samples import ContextSamples

TINY = dict(n_train_problems=6, contexts_per_problem=2, n_val_problems=2, val_contexts_per_problem=2,
            n_eval_problems=5, batch_size=4, progress=False)
CONTEXT_KEYS = {"states", "actions", "alt_actions", "preferred"}


@pytest.fixture(scope="module")
def tiny_bandit(tmp_path_factory) -> PreferenceDataModule:
    dm = bandit_data(root_dir=str(tmp_path_factory.mktemp("bandit")), **TINY)
    dm.prepare_data()
    return dm


def _digests(dm: PreferenceDataModule) -> list[tuple[str, str]]:
    """SHA-256 of every stored array that holds random draws (not the empty states or the task indices)."""
    files = dm.load().manifest["files"].items()
    return sorted((k, v["sha256"]) for k, v in files if not k.endswith(("states.npy", "task_index.npy")))


# ---- the DataModule --------------------------------------------------------------------------------

def test_batches_are_stateless_duels_with_pairs_and_no_task_information(tiny_bandit):
    assert tiny_bandit.state_dim == 0 and tiny_bandit.action_spec == ActionSpec(True, 20)
    assert tiny_bandit.context_length == 200
    for loader in (tiny_bandit.train_dataloader(), tiny_bandit.val_dataloader()):
        batch = next(iter(loader))
        # a context and another of its problem, nothing else: no θ, no rewards, no task index
        assert isinstance(batch, ContextSamples) and batch.task is None and batch.query_states is None
        for ctx in (batch.context, batch.pair):
            assert isinstance(ctx, StepPreferenceContext)
            assert ctx.states.shape == (4, 200, 0) and ctx.states.dtype == torch.float32
            assert ctx.actions.shape == (4, 200) and ctx.actions.dtype == torch.int64
            assert (ctx.actions != ctx.alt_actions).all()  # uniform pretraining pairs are distinct
            assert set(ctx.preferred.unique().tolist()) <= {0.0, 1.0}
            ctx.validate(0, tiny_bandit.action_spec)


def test_eval_splits_hold_behaviour_next_duels_and_rewards_for_evaluation_only(tiny_bandit):
    data = tiny_bandit.load()
    test_theta = np.asarray(data["tasks"]["test_theta"])
    assert not np.isin(test_theta, np.asarray(data["tasks"]["train_theta"])).any()
    suites = tiny_bandit.held_out("duels")
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
    again = bandit_data(data_dir=str(tmp_path / "again"), **TINY)
    again.prepare_data()
    assert _digests(again) == _digests(tiny_bandit)
    bigger = bandit_data(data_dir=str(tmp_path / "bigger"), **{**TINY, "n_train_problems": 9})
    bigger.prepare_data()
    assert [d for d in _digests(bigger) if d[0].startswith("eval_")] == \
        [d for d in _digests(tiny_bandit) if d[0].startswith("eval_")]
    other = bandit_data(data_dir=str(tmp_path / "other"), **{**TINY, "seed": 1})
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
    context_kind = "step_preference"

    def __init__(self, n_arms: int, max_context: int = 200) -> None:
        super().__init__()
        self.action_spec = ActionSpec(True, n_arms)
        self.transformer = nn.Module()
        self.transformer.max_context = max_context  # what Agent.reset checks the context against
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


@torch.no_grad()
def _direct_forward_duels(policy: InContextPolicy, context: StepPreferenceContext, rng: np.random.Generator):
    """The pre-Agent evaluation: one full-prefix forward pass of the policy itself, argmax, uniform other arm."""
    b, h = context.preferred.shape
    first = policy(context, torch.zeros(b, h, 0), torch.arange(1, h + 1)).argmax(-1)
    offset = torch.from_numpy(rng.integers(1, policy.action_spec.size, size=(b, h)))
    return first, (first + offset) % policy.action_spec.size


def test_agent_plays_the_argmax_after_each_prefix_and_a_uniform_other_arm():
    context = _random_context(b=5, h=12, n_arms=4)
    agent = Agent(PrefixArmPolicy(4))
    first, second = agent_duels(agent, context, np.random.default_rng(0), batch_chunk=2)
    torch.testing.assert_close(first, (torch.arange(12) % 4).expand(5, 12))
    assert (second != first).all() and second.min() >= 0 and second.max() < 4
    first_big, second_big = agent_duels(agent, context, np.random.default_rng(0), batch_chunk=32)
    assert torch.equal(first, first_big) and torch.equal(second, second_big)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agent_duels_equal_the_direct_forward_pass_duels(seed):
    """Agent.act_each_prefix (chunked over problems) plays exactly the duels of the policy's own prefix pass."""
    torch.manual_seed(seed)
    policy = InContextPolicy("step_preference", 0, ActionSpec(True, 6), TransformerConfig(2, 32, 2), 20).eval()
    context = _random_context(b=7, h=20, n_arms=6, seed=seed)
    first, second = agent_duels(Agent(policy), context, np.random.default_rng(seed), batch_chunk=3)
    ref_first, ref_second = _direct_forward_duels(policy, context, np.random.default_rng(seed))
    assert torch.equal(first, ref_first) and torch.equal(second, ref_second)
    assert len(first.unique()) > 1  # a random policy's argmax moves with the prefix: the check is not vacuous


def test_last_prefix_matches_the_deployed_agent_on_the_whole_context():
    torch.manual_seed(0)
    policy = InContextPolicy("step_preference", 0, ActionSpec(True, 6), TransformerConfig(2, 32, 2), max_context=20)
    context = _random_context(b=7, h=20, n_arms=6)
    agent = Agent(policy, greedy=True)
    first, _ = agent_duels(agent, context, np.random.default_rng(0))
    agent.reset(context)
    assert torch.equal(first[:, -1], agent.act(torch.zeros(7, 0)))


def test_act_each_prefix_shapes_continuous_actions_and_errors():
    torch.manual_seed(0)
    policy = InContextPolicy("step_preference", 3, ActionSpec(False, 2), TransformerConfig(1, 16, 2), max_context=10)
    g = torch.Generator().manual_seed(0)
    context = StepPreferenceContext(torch.randn(4, 10, 3, generator=g), torch.rand(4, 10, 2, generator=g) * 2 - 1,
                                    torch.rand(4, 10, 2, generator=g) * 2 - 1, torch.randint(0, 2, (4, 10)).float())
    agent = Agent(policy)
    obs = torch.randn(4, 3, generator=g)
    with pytest.raises(RuntimeError, match="reset"):
        agent.act_each_prefix(obs)
    agent.reset(context)
    means = agent.act_each_prefix(obs, batch_chunk=3)  # (B, T, A): Gaussian means after each prefix
    assert means.shape == (4, 10, 2)
    torch.testing.assert_close(means[:, -1], agent.act(obs))
    for h in (1, 6):  # column h - 1 is the agent deployed on the first h steps only
        agent.reset(context.map(lambda x, h=h: x[:, :h]))
        torch.testing.assert_close(means[:, h - 1], agent.act(obs))
    with pytest.raises(ValueError, match=r"\[B=4, S=3\]"):
        agent.act_each_prefix(obs[:, :2])


def test_sampled_prefix_actions_follow_the_policy():
    """greedy=False draws each prefix's arm from softmax(logits): a near one-hot policy gives its argmax."""
    policy = PrefixArmPolicy(5)
    policy.forward = lambda context, queries, visible: 50 * PrefixArmPolicy.forward(policy, context, queries, visible)
    agent = Agent(policy, greedy=False, seed=0)
    agent.reset(_random_context(b=3, h=9, n_arms=5))
    torch.testing.assert_close(agent.act_each_prefix(torch.zeros(3, 0)), (torch.arange(9) % 5).expand(3, 9))


def test_method_names_come_from_the_module_class():
    assert method_name(ICPOModule) == "icpo"
    assert method_name("icprl_lightning.methods.dpt.DP2TModule") == "dp2t"
    with pytest.raises(ValueError, match="taken"):
        evaluate_duels(Agent(PrefixArmPolicy(4)), None, "dts")


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
    return cli_data_args("bandit", root_dir=str(root), **TINY)


def test_config_runs_under_fast_dev_run_logs_and_prints_weak_regret(tmp_path, capsys):
    # default_root_dir: Lightning 2.6 still writes last.ckpt under fast_dev_run; keep it out of the repo.
    cli = run_cli(["fit", "--config", "configs/icpo_bandit.yaml", "--trainer.fast_dev_run", "1",
                   "--trainer.logger", "false", "--trainer.default_root_dir", str(tmp_path),
                   *_tiny_cli_args(tmp_path)])
    assert cli.trainer.state.finished
    assert cli.model.hparams.state_dim == 0 and cli.model.hparams.max_context == 200  # linked from the data
    callback = next(c for c in cli.trainer.callbacks if isinstance(c, BanditRegretCallback))
    stats = {"weak_regret", "weak_regret_sem", "weak_regret_auc", "weak_regret_auc_sem"}
    # the method's own name (ICPOModule -> icpo) beside the DTS and behaviour rows
    rows = {f"val/bandit/{s}/{m}" for s in EVAL_SOURCES for m in ("icpo", "dts", "behavior")}
    assert set(callback.last_results) == rows
    assert all(set(r) == stats for r in callback.last_results.values())
    logged = cli.trainer.callback_metrics
    for suite in cli.datamodule.held_out("duels"):
        # the same numbers from the public Agent again, scored by the WeakRegret metric
        duels = evaluate_duels(cli.model.make_agent(seed=callback.seed), suite, "icpo", callback.seed)
        for name, (first, second) in duels.items():
            final, over_h = WeakRegret(), WeakRegret()
            final.update(suite.expected_rewards, first[:, -1], second[:, -1])
            over_h.update(suite.expected_rewards.repeat_interleave(first.shape[1], dim=0), first.reshape(-1),
                          second.reshape(-1))
            prefix = f"val/bandit/{suite.source}/{name}"
            assert callback.last_results[prefix]["weak_regret"] == pytest.approx(float(final.compute()), rel=1e-6)
            assert callback.last_results[prefix]["weak_regret_auc"] == pytest.approx(float(over_h.compute()), rel=1e-6)
            assert float(logged[f"{prefix}/weak_regret"]) == pytest.approx(float(final.compute()), rel=1e-6)
            assert float(final.compute()) >= 0
    printed = capsys.readouterr().err
    assert "Weak regret on held-out bandit problems" in printed
    assert "icpo final" in printed and "dts AUC" in printed and "dirichlet" in printed


def _bandit_run(tmp_path, tiny_bandit):
    """A config naming the tiny bandit data and a briefly trained ICPO checkpoint on it."""
    config = tmp_path / "bandit.yaml"
    family, setting = tiny_bandit.family, tiny_bandit.setting
    data = {"class_path": "icprl_lightning.data.PreferenceDataModule",
            "init_args": {"root_dir": tiny_bandit.root_dir, "pairs": True, "progress": False,
                          "family": {"class_path": f"{type(family).__module__}.{type(family).__qualname__}",
                                     "init_args": {k: v for k, v in family.config().items() if k != "family"}},
                          "setting": {"class_path": f"{type(setting).__module__}.{type(setting).__qualname__}",
                                      "init_args": {k: v for k, v in setting.config().items()
                                                    if k not in ("setting", "context_kind")}}}}
    config.write_text(yaml.safe_dump({"data": data}))
    torch.manual_seed(0)
    model = ICPOModule(state_dim=0, action_dim=20, discrete=True, max_context=200,
                       backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    trainer = L.Trainer(max_steps=3, limit_val_batches=0, logger=False, default_root_dir=tmp_path,
                        enable_progress_bar=False, enable_model_summary=False, enable_checkpointing=False)
    trainer.fit(model, datamodule=tiny_bandit)
    checkpoint = tmp_path / "icpo.ckpt"
    trainer.save_checkpoint(checkpoint)
    return config, checkpoint


def test_icprl_evaluate_writes_weak_and_strong_regret_of_the_run_and_every_baseline(tmp_path, tiny_bandit, capsys):
    config, checkpoint = _bandit_run(tmp_path, tiny_bandit)
    out = tmp_path / "bandit"
    main(["evaluate", "--seeds", "0", "1", "--title", "bandit", "--run", f"ICPO={config}:{checkpoint}",
          "--out", str(out)])
    table = json.loads(out.with_suffix(".json").read_text())
    assert list(table["results"]) == ["ICPO", "dts", "maxinp", "bt_thompson", "bayes", "behavior"]
    assert table["reference_rows_from"] == "ICPO" and (table["n_eval_problems"], table["horizon"]) == (5, 200)
    agent = load_agent(checkpoint)
    for i, suite in enumerate(tiny_bandit.held_out("duels")):
        # per problem, the curve averaged over the two seeds; then mean ± sem over problems
        per_seed = [{name: regret_curves(suite.expected_rewards, pair)
                     for name, pair in evaluate_duels(agent, suite, "ICPO", seed).items()} for seed in (0, 1)]
        if i == 0:  # the feature-aware rows replayed on one source (each replay costs seconds)
            for seed, played in zip((0, 1), per_seed, strict=True):
                played.update(baseline_curves(suite, tiny_bandit.family, seed))
        for name in per_seed[0]:
            curves = {r: torch.stack([p[name][r].double() for p in per_seed]).mean(0) for r in ("weak", "strong")}
            expected = summarize_regrets(curves, with_tasks=True)
            row = dict(table["results"][name][suite.source])
            assert row.pop("per_task") == {m: [pytest.approx(v)] for m, v in expected.pop("per_task").items()}
            assert row == pytest.approx(expected)
            assert {"weak_regret_h10", "strong_regret_h100", "strong_regret_auc"} <= set(row)
            for key, regret in (("curves", "weak_regret"), ("strong_curves", "strong_regret")):
                assert len(table[key][name][suite.source]["mean"]) == 200
                assert table[key][name][suite.source]["mean"][-1] == pytest.approx(expected[regret])
    markdown = out.with_suffix(".md").read_text()
    assert "weak regret at h = H:" in markdown and "| ICPO |" in markdown and "| dts |" in markdown
    assert "strong regret, mean over h = 1..H:" in markdown and "weak regret at h = 50:" in markdown
    assert "| maxinp |" in markdown and "| bt_thompson |" in markdown and "| bayes |" in markdown
    assert out.with_suffix(".png").stat().st_size > 0
    printed = capsys.readouterr().out  # the tables, columns aligned
    assert "weak regret at h = H:" in printed and "| ICPO " in printed and f"wrote {out}.json" in printed
    with pytest.raises(SystemExit):  # MDP-only options are refused for bandits
        main(["evaluate", "--seeds", "0", "--run", f"ICPO={config}:{checkpoint}", "--other-task-contexts",
              "--out", str(out)])


def test_paper_config_has_the_paper_sizes():
    cli = run_cli([*config_args("configs/paper/icpo_bandit.yaml"), "--trainer.logger", "false"], run=False)
    hp, dm = cli.model.hparams, cli.datamodule
    assert (hp.backbone, hp.optimizer["lr"], dm.batch_size) == (
        {"n_layer": 6, "n_embd": 256, "n_head": 8, "dropout": 0.0}, 3e-4, 32)
    assert cli.model.backbone == TransformerConfig(n_layer=6, n_embd=256, n_head=8)
    assert dm.setting.n_problems["train"] * dm.trajectories_per_task[0] == 100_000
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
    data = cli_data_args("bandit", root_dir=str(tmp_path), n_arms=6, dim=4, horizon=40, bt_temperature=0.3,
                         n_train_problems=2000, n_eval_problems=300, eval_sources=["uniform"], progress=False)
    cli = run_cli(["fit", "--config", "configs/icpo_bandit.yaml", "--trainer.logger", "false",
                   "--trainer.max_epochs", "1", "--trainer.enable_checkpointing", "false",
                   "--trainer.enable_progress_bar", "false", "--evaluation", "null",
                   "--trainer.default_root_dir", str(tmp_path), *data])
    suite = cli.datamodule.held_out("duels")[0]
    cli.model.eval()
    first, second = agent_duels(cli.model.make_agent(), suite.context, np.random.default_rng(0))
    # the trained policy's duels through the Agent are those of its own full-prefix forward pass
    reference = _direct_forward_duels(cli.model.policy, suite.context, np.random.default_rng(0))
    assert torch.equal(first, reference[0]) and torch.equal(second, reference[1])
    icpo = regret_curve(suite.expected_rewards, (first, second))[:, -1].numpy()
    uniform = _uniform_pair_regret(suite.expected_rewards.numpy())
    diff = uniform - icpo
    assert diff.mean() > 3 * diff.std(ddof=1) / np.sqrt(len(diff)), (icpo.mean(), uniform.mean())
    assert icpo.mean() < 0.6 * uniform.mean(), (icpo.mean(), uniform.mean())  # measured: 0.05 vs 0.26


def test_a_stateless_policy_builds_without_warnings_and_its_query_token_is_a_learned_vector():
    """A bandit has no state: the query embedding maps 0 features to its bias. Building it must not warn
    (nn.Linear's init of the empty weight does, which every bandit run printed), and the bias is trained."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        module = ICPOModule(state_dim=0, action_dim=4, discrete=True, max_context=8,
                            backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
    embed = module.policy.query_embed
    assert embed.weight.shape == (16, 0) and embed.bias.requires_grad
    assert torch.equal(embed(torch.zeros(3, 0)), embed.bias.expand(3, 16))
