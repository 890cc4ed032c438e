"""Meta-World Reach T-PRL: BT label rates, trajectory semantics, the reward-free invariant, determinism, the
DataModule's splits and manifest, every Meta-World T-PRL config under fast_dev_run and ICRG's deployment.

Generation runs at short horizons on a few goals with in-process envs (``num_workers=0``) so these tests
stay cheap; the semantics do not depend on the horizon.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import torch
import yaml

pytest.importorskip("metaworld")

from factories import cli_data_args, config_args, reach_data, served_fields, trajectory_pairs  # noqa: E402

from icprl_lightning import TrajectoryPreferenceContext, load_agent  # noqa: E402
from icprl_lightning.commands import run_cli  # noqa: E402
from icprl_lightning.contexts import RewardTrajectoryContext  # noqa: E402
from icprl_lightning.data import PreferenceDataModule  # noqa: E402
from icprl_lightning.data.settings.trajectory_pairs import label_trajectory_pairs  # noqa: E402
from icprl_lightning.families.metaworld_reach import ReachTaskFamily  # noqa: E402
from icprl_lightning.families.metaworld_reach.env import GOAL_SLICE, latent_reward  # noqa: E402
from icprl_lightning.families.metaworld_reach.oracle import expert_actions  # noqa: E402
from icprl_lightning.models.config import TransformerConfig
from icprl_lightning.preferences import preference_probability  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[2]
H = 10
FORBIDDEN = ("reward", "goal", "advantage", "q_value", "value", "return")
PAIR = ("states_a", "actions_a", "states_b", "actions_b", "preferred")
TINY = dict(horizon=H, n_train_tasks=3, n_test_tasks=2, trajectories_per_task=3, val_trajectories_per_task=2,
            eval_contexts_per_task=2, calibration_episodes=2, reference_episodes=2, num_workers=0, progress=False,
            batch_size=4)
SIZES = dict(backbone=TransformerConfig(n_layer=1, n_embd=16, n_head=2))
# The same tiny dataset for every config (sizes, batch and workers overridden; the paper configs too).
CLI_TINY = cli_data_args("reach", **TINY)
CONFIGS = ("reward_gen_metaworld", "icrg_metaworld", "dit_metaworld", "dp2t_metaworld_tprl")


@pytest.fixture(scope="module")
def family() -> ReachTaskFamily:
    return ReachTaskFamily(seed=0, horizon=H, num_workers=0)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("reach_tprl"))


def _prepared(context_kind: str = "trajectory_preference", **kwargs) -> PreferenceDataModule:
    dm = reach_data(context_kind, **{**TINY, **kwargs})
    dm.prepare_data()
    return dm


@pytest.fixture(scope="module")
def tprl(root) -> PreferenceDataModule:
    return _prepared(root_dir=root, pairs=True, query_labels=True)


@pytest.fixture(scope="module")
def tprl_rewards(root) -> PreferenceDataModule:
    return _prepared(root_dir=root, context_kind="reward_trajectory")


# ---- generation ------------------------------------------------------------------------------------

def test_labels_follow_bt_on_return_differences(family):
    """Labels of real Reach pairs: agreement as BT predicts, and BT rates per return gap over many draws."""
    goals = np.repeat(family.train_goals, 40, axis=0)[:120]
    p = np.random.default_rng(1).uniform(0.0, 0.6, len(goals))  # mixed qualities: a spread of return gaps
    temperature = 0.07  # ≈ the median |ΔR| of these 10-step pairs: labels neither coin flips nor deterministic
    arrays, rewards, stats = trajectory_pairs(family, goals, p, temperature, np.random.default_rng(0))
    ret_a, ret_b = rewards["rewards_a"].sum(1), rewards["rewards_b"].sum(1)
    diff = ret_a.astype(np.float64) - ret_b
    agree = (diff > 0) == (arrays["preferred"] == 1)
    expected = preference_probability(np.abs(diff), 0.0, temperature)
    assert stats["label_agreement"] == pytest.approx(agree.mean()) and stats["tie_fraction"] == 0.0
    assert abs(agree.sum() - expected.sum()) < 4 * np.sqrt((expected * (1 - expected)).sum())
    assert 0.6 < expected.mean() < 0.9
    # the same returns relabelled 40 times: the rate of y = 1 per bin of ΔR is σ(ΔR / T) within 4 sd
    both = np.concatenate([rewards["rewards_a"], rewards["rewards_b"]])  # as states and actions too: unused by labels
    draws = np.stack([label_trajectory_pairs(both, both, both, len(goals), temperature,
                                             np.random.default_rng(seed))[0]["preferred"] for seed in range(40)])
    for lo, hi in ((-np.inf, -0.1), (-0.1, -0.03), (-0.03, 0.03), (0.03, 0.1), (0.1, np.inf)):
        sel = (diff >= lo) & (diff < hi)
        prob = preference_probability(diff[sel], 0.0, temperature)
        n = 40 * sel.sum()
        assert sel.sum() >= 8, (lo, hi)
        sd = np.sqrt(40 * (prob * (1 - prob)).sum()) / n
        assert abs(draws[:, sel].mean() - prob.mean()) < 4 * sd + 1e-9, (lo, hi, draws[:, sel].mean(), prob.mean())


def test_pairs_replay_in_the_env_and_queries_are_visited_states_with_expert_labels(family):
    goals = np.repeat(family.train_goals[:3], 2, axis=0)
    n = len(goals)
    arrays, rewards, _ = trajectory_pairs(family, goals, np.full(n, 0.3), 1.0, np.random.default_rng(7), behavior=True,
                                         queries=True)
    assert set(arrays) == {*PAIR, "behavior_states", "behavior_actions", "query_states", "optimal_actions"}
    assert set(rewards) == {"rewards_a", "rewards_b", "behavior_rewards"}
    assert arrays["preferred"].shape == (n,) and arrays["preferred"].dtype == np.uint8
    assert arrays["query_states"].shape == (n, H, 39) and arrays["optimal_actions"].shape == (n, H, 4)
    # rows a, then b, then behavior stepped together in one env seeded by the generator's first draw
    states = np.concatenate([arrays["states_a"], arrays["states_b"], arrays["behavior_states"]])
    actions = np.concatenate([arrays["actions_a"], arrays["actions_b"], arrays["behavior_actions"]])
    reward = np.concatenate([rewards["rewards_a"], rewards["rewards_b"], rewards["behavior_rewards"]])
    experts = []
    with family.make_env(np.tile(goals, (3, 1)), num_workers=0) as env:
        obs, _ = env.reset(seed=int(np.random.default_rng(7).integers(2**31)))
        for h in range(H):
            np.testing.assert_array_equal(obs, states[:, h])
            experts.append(expert_actions(env.oracle_state()))
            obs, r, *_ = env.step(actions[:, h])
            np.testing.assert_allclose(reward[:, h], latent_reward(env.oracle_state().tcp, env.goals), rtol=1e-6)
            np.testing.assert_allclose(reward[:, h], r, rtol=1e-6)
    experts = np.stack(experts, axis=1)
    for i in range(n):  # H distinct states of ξ_a or ξ_b, each with the expert's action there
        visited = np.concatenate([states[i], states[n + i]])
        labels = np.concatenate([experts[i], experts[n + i]])
        match = (arrays["query_states"][i][:, None] == visited[None]).all(-1)  # [H queries, 2H steps]
        assert (match.sum(1) >= 1).all() and len(set(match.argmax(1))) == H
        np.testing.assert_array_equal(arrays["optimal_actions"][i], labels[match.argmax(1)])
    assert np.all(states[..., GOAL_SLICE] == 0) and np.all(arrays["query_states"][..., GOAL_SLICE] == 0)


# ---- the DataModule ---------------------------------------------------------------------------------

def test_preference_batches_and_eval_contexts_are_reward_free(tprl):
    tprl.setup("fit")
    batch = next(iter(tprl.train_dataloader()))
    served = served_fields(batch)
    assert served == {*(f"context.{k}" for k in PAIR), *(f"pair.{k}" for k in PAIR), "query_states",
                      "optimal_actions", "task"}
    assert not [k for k in served if any(word in k for word in FORBIDDEN)]
    ctx = batch.context
    assert ctx.states_a.shape == (4, H, 39) and ctx.actions_b.dtype == torch.float32
    assert ctx.preferred.shape == (4,) and set(ctx.preferred.tolist()) <= {0.0, 1.0}
    for k, states in {"states_a": ctx.states_a, "states_b": ctx.states_b, "pair.states_a": batch.pair.states_a,
                      "query_states": batch.query_states}.items():
        assert torch.all(states[..., GOAL_SLICE] == 0), k
    stored = [f for f in tprl.load().manifest["files"] if not f.startswith("tasks/")]  # tasks: evaluation only
    assert stored and not any(w in f for f in stored for w in FORBIDDEN)  # nothing on disk either
    without_labels = reach_data("trajectory_preference", root_dir=tprl.root_dir, **TINY)
    assert served_fields(next(iter(without_labels.val_dataloader()))) == {*(f"context.{k}" for k in PAIR), "task"}
    for suite in tprl.held_out("rollouts"):
        ctx = suite.context
        assert isinstance(ctx, TrajectoryPreferenceContext) and ctx.behavior_states.shape == (4, H, 39)
        assert not any(any(w in f for w in FORBIDDEN) for f in vars(ctx)), suite.quality
        assert torch.all(ctx.behavior_states[..., GOAL_SLICE] == 0)


def test_splits_manifest_agreement_and_calibration(tprl):
    data = tprl.load()
    assert data["train"]["states_a"].shape == (9, H, 39) and data["val"]["preferred"].shape == (6,)
    np.testing.assert_array_equal(data["train"]["task_index"], np.repeat(np.arange(3), 3))
    np.testing.assert_array_equal(data["train"]["quality"], 3)  # "pretraining": after low, medium, high
    np.testing.assert_array_equal(data["eval_medium"]["quality"], 1)
    info = data.manifest["info"]
    calibration = info["calibration"]
    assert set(calibration) == {"low", "medium", "high", "pretraining"}
    assert calibration["pretraining"]["target"] == 0.5
    p = {q: c["mixing"] for q, c in calibration.items()}
    assert p["medium"] <= p["pretraining"] <= p["high"]
    for stats in (info["train_statistics"], *info["eval_statistics"].values()):
        assert 0.0 <= stats["label_agreement"] <= 1.0 and stats["tie_fraction"] == 0.0
    ref = info["test_reference"]
    assert {"behavior_return", "behavior_success", "expert_return", "uniform_return"} <= set(ref["high"])
    config = tprl.generator_config()
    assert config["setting"] == "TrajectoryPairs" and config["train_policy"] == "pretraining"
    assert config["pretraining_target"] == 0.5 and config["bt_temperature"] == 1.0
    assert "trajectory_preference" in tprl.path.name


def test_same_seed_same_bytes(tmp_path):
    kw = {"n_train_tasks": 2, "n_test_tasks": 1, "trajectories_per_task": 2, "val_trajectories_per_task": 1,
          "eval_contexts_per_task": 1, "calibration_episodes": 1, "reference_episodes": 1, "horizon": 4}
    digests = []
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        dm = _prepared(data_dir=str(tmp_path / name), seed=seed, **kw)
        digests.append(sorted((k, v["sha256"]) for k, v in dm.load().manifest["files"].items()))
    assert digests[0] == digests[1] and digests[0] != digests[2]


def test_reward_kind_holds_the_same_trajectories_with_true_rewards(tprl, tprl_rewards):
    pref, rew = tprl.load(), tprl_rewards.load()
    for split in ("train", "eval_high"):
        for k in ("states_a", "actions_b", "query_states"):
            np.testing.assert_array_equal(pref[split][k], rew[split][k])
    assert "preferred" not in rew["train"] and "rewards_a" in rew["train"]
    batch = next(iter(tprl_rewards.train_dataloader()))
    assert served_fields(batch) == {f"trajectory_{side}.{k}" for side in "ab" for k in ("states", "actions", "rewards")
                                    } | {"task"}
    assert torch.all(batch.trajectory_a.rewards < 0)  # −‖tcp − goal‖
    suite = tprl_rewards.held_out("rollouts")[0]
    assert isinstance(suite.context, RewardTrajectoryContext)
    np.testing.assert_array_equal(suite.context.states.numpy(), rew["eval_low"]["behavior_states"])
    with pytest.raises(ValueError, match="trajectory_preference"):
        tprl_rewards.held_out("pair_accuracy")


def test_other_pairs_and_heldout_pairs_come_from_the_same_task(tprl):
    train = tprl.load()["train"]
    task_of = {s.tobytes(): t for s, t in zip(np.asarray(train["states_b"]), train["task_index"], strict=True)}
    batch = next(iter(tprl.train_dataloader()))
    for own, other in zip(batch.context.states_b.numpy(), batch.pair.states_b.numpy(), strict=True):
        assert not np.array_equal(own, other) and task_of[own.tobytes()] == task_of[other.tobytes()]
    held = tprl.held_out("pair_accuracy")
    assert list(held) == ["low", "medium", "high"]
    split = tprl.load()["eval_high"]
    np.testing.assert_array_equal(held["high"].pair.states_b[0].numpy(), split["states_b"][1])
    assert split["task_index"][0] == split["task_index"][1]


# ---- configs and deployment ---------------------------------------------------------------------------

def _fast_dev_run(config: str, root: str, tmp_path, *extra: str, tiny_model: bool = True):
    """Run from ``tmp_path``: the configs' checkpoint directories are relative (runs/<name>/checkpoints)."""
    sizes = [f"--model.init_args.backbone={SIZES['backbone'].as_dict()}"] if tiny_model else []
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp_path)
        return run_cli(["fit", *config_args(REPO / config), "--trainer.fast_dev_run", "1", "--trainer.logger",
                        "false", "--data.init_args.root_dir", root, *CLI_TINY, *sizes, *extra])


@pytest.fixture(scope="module")
def reward_gen_run(root, tmp_path_factory) -> tuple[str, dict[str, float]]:
    """configs/reward_gen_metaworld.yaml under fast_dev_run: (its checkpoint, its logged metrics)."""
    out = tmp_path_factory.mktemp("reward_gen")
    cli = _fast_dev_run("configs/reward_gen_metaworld.yaml", root, out)
    assert cli.trainer.state.finished
    path = out / "reward_gen.ckpt"
    cli.trainer.save_checkpoint(path)
    return str(path), {k: float(v) for k, v in cli.trainer.callback_metrics.items()}


@pytest.fixture(scope="module")
def reward_gen_ckpt(reward_gen_run) -> str:
    return reward_gen_run[0]


def test_reward_gen_config_runs_and_reports_heldout_pair_accuracy(reward_gen_run):
    path, metrics = reward_gen_run
    assert 0.0 <= metrics["val/metaworld/heldout_pair_accuracy"] <= 1.0
    assert {f"val/metaworld/{q}/pair_accuracy" for q in ("low", "medium", "high")} <= set(metrics)
    hparams = torch.load(path, map_location="cpu", weights_only=True)["hyper_parameters"]
    assert hparams["max_context"] == H and hparams["action_dim"] == 4 and not hparams["discrete"]


@pytest.mark.parametrize("config", ["configs/dit_metaworld.yaml", "configs/dp2t_metaworld_tprl.yaml"])
def test_config_runs_under_fast_dev_run(config, root, tmp_path):
    cli = _fast_dev_run(config, root, tmp_path)
    assert cli.trainer.state.finished
    assert cli.model.hparams.max_context == H  # linked from the data's horizon
    metrics = cli.trainer.callback_metrics
    assert "val/metaworld/high/success" in metrics and "val/metaworld/high/behavior_return" in metrics


def test_icrg_config_runs_and_its_checkpoint_deploys(root, reward_gen_ckpt, tmp_path):
    cli = _fast_dev_run("configs/icrg_metaworld.yaml", root, tmp_path,
                        f"--model.init_args.reward_gen_checkpoint={reward_gen_ckpt}")
    assert cli.trainer.state.finished and "val/metaworld/low/normalized_return" in cli.trainer.callback_metrics
    path = tmp_path / "icrg.ckpt"
    cli.trainer.save_checkpoint(path)
    agent = load_agent(path)
    context = cli.datamodule.held_out("rollouts")[0].context
    agent.reset(context)
    action = agent.act(context.behavior_states[:, 0])
    assert isinstance(action, torch.Tensor) and action.shape == (4, 4) and action.dtype == torch.float32


def test_paper_configs_have_the_paper_architecture_and_data():
    for name in CONFIGS:
        stem = name if name.endswith("_tprl") else f"{name}_tprl"
        cfg = yaml.safe_load((REPO / f"configs/paper/{stem}.yaml").read_text())
        args = cfg["model"]["init_args"]
        assert args["backbone"] == {"n_layer": 8, "n_embd": 256, "n_head": 8}, name
        assert cfg["data"]["init_args"]["setting"]["init_args"]["trajectories_per_task"] == 5000
        assert args["optimizer"] == {"lr": 3e-4}


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
@pytest.mark.parametrize("name", CONFIGS)
def test_paper_config_runs_under_fast_dev_run(name, root, reward_gen_ckpt, tmp_path):
    stem = name if name.endswith("_tprl") else f"{name}_tprl"
    extra = [f"--model.init_args.reward_gen_checkpoint={reward_gen_ckpt}"] if name.startswith("icrg") else []
    cli = _fast_dev_run(f"configs/paper/{stem}.yaml", root, tmp_path, *extra, tiny_model=False)
    assert cli.trainer.state.finished
