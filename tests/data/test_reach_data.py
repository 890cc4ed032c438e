"""Meta-World Reach data: I-PRL and reward-context generation, the DataModule, evaluation suites, configs.

Generation runs at horizon 20 on a few goals with in-process envs (``num_workers=0``) so these tests stay
fast; the semantics do not depend on the horizon.
"""

from __future__ import annotations

import glob

import numpy as np
import pytest
import torch

pytest.importorskip("metaworld")

from factories import cli_data_args, config_args, reach_data, reward_contexts, served_fields, step_contexts  # noqa: E402

from icprl_lightning.commands import run_cli  # noqa: E402
from icprl_lightning.data import PreferenceDataModule  # noqa: E402
from icprl_lightning.evaluation import rollout_in_context, summarize  # noqa: E402
from icprl_lightning.families.metaworld_reach import ReachTaskFamily  # noqa: E402
from icprl_lightning.families.metaworld_reach.env import GOAL_SLICE  # noqa: E402
from icprl_lightning.families.metaworld_reach.oracle import expert_actions, expert_q_values  # noqa: E402

H = 20
# Anything that would let a preference method see the task: rewards, goals, A*, Q*, V*.
FORBIDDEN = ("reward", "goal", "advantage", "q_value", "value", "return")
TINY = dict(horizon=H, n_train_tasks=3, n_test_tasks=2, trajectories_per_task=3, val_trajectories_per_task=2,
            eval_contexts_per_task=2, calibration_episodes=2, reference_episodes=2, num_workers=0, progress=False,
            batch_size=4)
# Config runs: shorter episodes and one context per held-out goal, so each fast_dev_run takes seconds.
CLI_TINY = cli_data_args("reach", **{**TINY, "horizon": 10, "eval_contexts_per_task": 1})


@pytest.fixture(scope="module")
def family() -> ReachTaskFamily:
    return ReachTaskFamily(seed=0, horizon=H, num_workers=0)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("reach"))


@pytest.fixture(scope="module")
def ipref(root) -> PreferenceDataModule:
    dm = reach_data(context_kind="step_preference", root_dir=root, pairs=True, **TINY)
    dm.prepare_data()
    return dm


@pytest.fixture(scope="module")
def reward(root) -> PreferenceDataModule:
    dm = reach_data(context_kind="reward", root_dir=root, query_labels=True, **TINY)
    dm.prepare_data()
    return dm


def _replay(family: ReachTaskFamily, goals: np.ndarray, seed: int, actions: np.ndarray):
    """Re-run the generator's env (its first draw seeds the env) with ``actions`` [N, H, 4]; yield states."""
    with family.make_env(goals, num_workers=0) as env:
        obs, _ = env.reset(seed=int(np.random.default_rng(seed).integers(2**31)))
        for h in range(family.horizon):
            state = env.oracle_state()
            yield obs, state
            obs, *_ = env.step(actions[:, h])


def test_state_follows_the_preferred_action_labels_follow_a_and_queries_are_visited_states(family):
    goals = np.repeat(family.train_goals[:3], 2, axis=0)
    n = len(goals)
    arrays, stats = step_contexts(family, goals, 0.5, 1e-9, np.random.default_rng(3), p_first=0.1)
    s, a, a2, y = (arrays[k] for k in ("states", "actions", "alt_actions", "preferred"))
    assert s.shape == (n, H, 39) and a.shape == a2.shape == (n, H, 4) and y.shape == (n, H) and y.dtype == np.uint8
    assert arrays["optimal_actions"].shape == (n, H, 4) and arrays["optimal_actions"].dtype == np.float32
    winner = np.where(y[..., None] == 1, a, a2)
    experts, decisive = [], []
    for h, (obs, state) in enumerate(_replay(family, goals, 3, winner)):
        np.testing.assert_array_equal(obs, s[:, h])  # the env stepped with the preferred action
        q = expert_q_values(state, np.stack([a[:, h], a2[:, h]]), H)
        strict = q[0] != q[1]
        decisive.append(y[strict, h] == (q[0] > q[1])[strict])  # temperature → 0: labels are the A ordering
        experts.append(expert_actions(state))
    assert np.concatenate(decisive).all()
    assert stats["label_agreement"] == 1.0 and 0.0 < stats["tie_fraction"] < 0.2
    experts = np.stack(experts, axis=1)
    for i in range(n):  # query states: this trajectory's states in another order, labelled by the expert
        match = (arrays["query_states"][i][:, None] == s[i][None]).all(-1)  # [H queries, H steps]
        assert (match.sum(1) == 1).all() and sorted(match.argmax(1)) == list(range(H))
        np.testing.assert_array_equal(arrays["optimal_actions"][i], experts[i][match.argmax(1)])
    assert not np.array_equal(arrays["query_states"], s)  # permuted in time
    assert np.all(s[..., GOAL_SLICE] == 0) and np.all(arrays["query_states"][..., GOAL_SLICE] == 0)


def test_reward_contexts_are_rollouts_with_the_latent_reward(family):
    goals = family.train_goals[:3]
    arrays, stats = reward_contexts(family, goals, [0.0, 0.5, 1.0], np.random.default_rng(1))
    np.testing.assert_array_equal(arrays["next_states"][:, :-1], arrays["states"][:, 1:])
    tcp = np.stack([state.tcp for _, state in _replay(family, goals, 1, arrays["actions"])], axis=1)
    np.testing.assert_allclose(arrays["rewards"][:, :-1], -np.linalg.norm(tcp[:, 1:] - goals[:, None], axis=-1),
                               rtol=1e-6)
    assert arrays["rewards"][2].sum() > arrays["rewards"][0].sum()  # the expert beats uniform
    assert stats["mean_context_return"] == pytest.approx(arrays["rewards"].sum(1).mean(), rel=1e-5)


def test_datamodule_splits_shapes_and_manifest(ipref, reward):
    data = ipref.load()
    assert data["train"]["states"].shape == (9, H, 39) and data["val"]["states"].shape == (6, H, 39)
    assert data["eval_medium"]["actions"].shape == (4, H, 4) and data["tasks"]["test_goals"].shape == (2, 3)
    np.testing.assert_array_equal(data["train"]["task_index"], np.repeat(np.arange(3), 3))
    np.testing.assert_array_equal(data["train"]["quality"], 2)  # I-PRL pretraining pairs: low vs high
    np.testing.assert_array_equal(reward.load()["train"]["quality"], np.tile([0, 1, 2], 3))  # qualities cycle
    info = data.manifest["info"]
    assert set(info["calibration"]) == {"low", "medium", "high"}
    assert 0.5 < info["train_statistics"]["label_agreement"] <= 1.0
    assert 0.0 <= info["train_statistics"]["tie_fraction"] < 0.5
    ref = info["test_reference"]
    keys = {"behavior_return", "behavior_success", "expert_return", "expert_success", "uniform_return"}
    assert all(keys <= set(ref[q]) for q in ("low", "medium", "high"))
    assert ref["low"]["behavior_return"] < ref["high"]["behavior_return"] < ref["high"]["expert_return"]
    assert len(info["test_reference_per_task"]["expert_return"]) == 2


def test_same_seed_same_bytes(tmp_path):
    kw = {**TINY, "n_train_tasks": 2, "n_test_tasks": 1, "trajectories_per_task": 2, "horizon": 8}
    digests = []
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        dm = reach_data(data_dir=str(tmp_path / name), seed=seed, **kw)
        dm.prepare_data()
        digests.append(sorted((k, v["sha256"]) for k, v in dm.load().manifest["files"].items()))
    assert digests[0] == digests[1] and digests[0] != digests[2]


def test_preference_batches_carry_no_reward_goal_or_advantage(ipref):
    ipref.setup("fit")
    batch = next(iter(ipref.train_dataloader()))
    served = served_fields(batch)
    assert served == {"context.states", "context.actions", "context.alt_actions", "context.preferred", "pair.states",
                      "pair.actions", "pair.alt_actions", "pair.preferred", "task"}
    assert not [k for k in served if any(word in k for word in FORBIDDEN)]
    assert torch.all(batch.context.states[..., GOAL_SLICE] == 0) and torch.all(batch.pair.states[..., GOAL_SLICE] == 0)
    assert batch.context.actions.shape == (4, H, 4) and batch.context.actions.dtype == torch.float32


def test_evaluation_suites_report_success_and_normalize_per_goal(ipref):
    suites = ipref.held_out("rollouts")
    assert [(s.env_name, s.quality) for s in suites] == [("metaworld", q) for q in ("low", "medium", "high")]
    suite = suites[2]
    per_task = ipref.load().manifest["info"]["test_reference_per_task"]
    normalized = suite.normalize(np.asarray(per_task["expert_return"])[suite.task_index])
    np.testing.assert_allclose(normalized, 1.0)

    class StandStill:
        def reset(self, context) -> None:
            self.b = context.batch_size

        def act(self, obs: torch.Tensor) -> torch.Tensor:
            return torch.zeros(self.b, 4)

    result = summarize(suite, rollout_in_context(StandStill(), suite))
    assert result["success"] == 0.0 and result["return"] < 0
    assert result["behavior_return"] == suite.reference["behavior_return"]


@pytest.mark.slow  # end to end through the CLI or several processes: the full suite's tier
@pytest.mark.parametrize("config", ["configs/icpo_metaworld.yaml", "configs/dp2t_metaworld.yaml",
                                    "configs/dpt_metaworld.yaml", *sorted(glob.glob("configs/paper/*metaworld.yaml"))])
def test_config_runs_under_fast_dev_run(config, root):
    cli = run_cli(["fit", *config_args(config), "--trainer.fast_dev_run", "1", "--trainer.logger", "false",
                   "--trainer.default_root_dir", root, "--data.init_args.root_dir", root, *CLI_TINY])
    assert cli.trainer.state.finished
    assert cli.model.hparams.max_context == 10  # linked from the data's horizon
    assert "val/metaworld/high/success" in cli.trainer.callback_metrics
    assert "val/metaworld/high/behavior_return" in cli.trainer.callback_metrics


@pytest.mark.slow
def test_icpo_beats_the_low_quality_behavior_policy_on_held_out_goals(tmp_path):
    """A tiny budget (≈2 min on 2 idle cores): horizon 60, 8 contexts per training goal, 12 short epochs."""
    small = {"horizon": 60, "trajectories_per_task": 8, "calibration_episodes": 6, "reference_episodes": 4,
             "batch_size": 16, "progress": False}
    cli = run_cli(["fit", "--config", "configs/icpo_metaworld.yaml", "--trainer.logger", "false",
                   "--trainer.default_root_dir", str(tmp_path), "--data.init_args.root_dir", str(tmp_path),
                   *cli_data_args("reach", **small),
                   "--trainer.max_epochs", "12", "--trainer.check_val_every_n_epoch", "12",
                   "--trainer.enable_progress_bar", "false"])
    metrics = {k: float(v) for k, v in cli.trainer.callback_metrics.items()}
    assert metrics["val/metaworld/low/return"] > metrics["val/metaworld/low/behavior_return"], metrics
    assert metrics["val/metaworld/low/normalized_return"] > metrics["val/metaworld/low/behavior_normalized_return"]
