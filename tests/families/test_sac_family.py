"""The exported SAC oracle (weights only, checksummed) and the Reach family built on it (the paper's recipe),
on a tiny SAC run: plumbing, equality with SB3's networks, safety and determinism, not learning."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from icprl_lightning.data.settings import RewardContexts, StepPreferences, TrajectoryPairs
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.sac import SACTrainingRun, train_sac_oracle
from icprl_lightning.families.metaworld_reach.sac_family import DEFAULT_ORACLE, ReachSACTaskFamily
from icprl_lightning.families.metaworld_reach.sac_weights import (
    CHECKSUMS,
    MANIFEST,
    ExportedSAC,
    export_sac_oracle,
)
from icprl_lightning.io import sha256

GOALS = np.array([[0.05, 0.85, 0.2], [-0.05, 0.82, 0.1]])
TARGETS = (0.2, 0.4, 0.5, 0.8)

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("sac") / "run"
    return train_sac_oracle(GOALS, out, timesteps=200, checkpoint_every=50, eval_episodes=2, horizon=30,
                            reward_scale=10.0)


@pytest.fixture(scope="module")
def exported(run_dir, tmp_path_factory):
    return export_sac_oracle(run_dir, tmp_path_factory.mktemp("export") / "oracle", TARGETS)


def _obs(n: int, seed: int = 0) -> np.ndarray:
    env = ReachGoalEnv(GOALS, horizon=30, goal_visible=True)
    rng = np.random.default_rng(seed)
    obs = [env.reset(seed=seed, options={"goal_index": 0})[0]]
    for _ in range(n - 1):
        obs.append(env.step(rng.uniform(-1, 1, 4).astype(np.float32))[0])
    return np.stack(obs)


def test_export_writes_weights_manifest_and_checksums(run_dir, exported):
    names = sorted(p.name for p in exported.iterdir())
    assert names == sorted([CHECKSUMS, MANIFEST, "critic_final.pt", "actor_020.pt", "actor_040.pt", "actor_050.pt",
                            "actor_080.pt", "actor_100.pt"])
    listed = dict(line.split("  ")[::-1] for line in (exported / CHECKSUMS).read_text().splitlines())
    assert set(listed) == set(names) - {CHECKSUMS}
    assert all(sha256(exported / f) == d for f, d in listed.items())
    manifest = json.loads((exported / MANIFEST).read_text())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert manifest["reward_scale"] == 10.0 and manifest["policies"]["100"]["step"] == summary["final"]["step"]
    for level in TARGETS:
        assert manifest["policies"][f"{round(100 * level):03d}"]["step"] in [c["step"] for c in summary["checkpoints"]]
    assert not list(exported.parent.glob(".oracle.tmp-*"))


def test_weights_reproduce_sb3_actions_and_scaled_q(run_dir, exported):
    sb3 = SACTrainingRun(run_dir)  # the final SB3 model: reward_scale divides its Q
    ours = ExportedSAC(exported)
    obs = _obs(6)
    np.testing.assert_allclose(ours.mean_actions(obs), sb3.model.predict(obs, deterministic=True)[0], atol=1e-6)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 4)).astype(np.float32)
    np.testing.assert_allclose(ours.q_values(obs, actions), sb3.q_values(obs, actions), rtol=1e-5, atol=1e-6)
    stacked = np.stack([actions, -actions])  # candidates [K, B, 4]
    np.testing.assert_allclose(ours.q_values(obs, stacked)[1], sb3.q_values(obs, -actions), rtol=1e-5, atol=1e-6)
    noise = np.random.default_rng(2).standard_normal((6, 4))
    mean, log_std, _ = sb3.model.actor.get_action_dist_params(torch.as_tensor(obs))
    expected = torch.tanh(mean + log_std.exp() * torch.as_tensor(noise, dtype=torch.float32)).detach().numpy()
    np.testing.assert_allclose(ours.sample_actions(obs, 1.0, noise), expected, atol=1e-6)
    with pytest.raises(KeyError, match="no policy at level 0.3"):
        ours.sample_actions(obs, 0.3, noise)
    with pytest.raises(ValueError, match=r"shape \[B, 39\]"):
        ours.mean_actions(obs[:, :36])


def test_tampered_or_pickled_files_are_refused(exported, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(exported, copy)
    data = bytearray((copy / "actor_020.pt").read_bytes())
    data[-20] ^= 0xFF
    (copy / "actor_020.pt").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="checksum mismatch"):
        ExportedSAC(copy)

    class Payload:
        def __reduce__(self):
            return (print, ("unpickled!",))

    shutil.rmtree(copy)
    shutil.copytree(exported, copy)
    torch.save({"latent_pi.0.weight": Payload()}, copy / "actor_020.pt")
    lines = [f"{sha256(copy / f)}  {f}" for f in sorted(p.name for p in copy.iterdir() if p.name != CHECKSUMS)]
    (copy / CHECKSUMS).write_text("\n".join(lines) + "\n")  # a consistent but malicious directory
    with pytest.raises(ValueError, match=r"actor_020.pt was refused: .*its pickle names \S*print\)"):
        ExportedSAC(copy)
    with pytest.raises(FileNotFoundError, match="not an exported SAC oracle"):
        ExportedSAC(tmp_path)


@pytest.fixture(scope="module")
def family(exported):
    return ReachSACTaskFamily(exported, n_train=2, n_test=1, horizon=12, num_workers=0)


def test_behavior_levels_are_sac_samples_uniform_at_zero_and_deterministic(family):
    with family.make_env(np.repeat(family.train_goals, 2, axis=0)) as env:
        env.reset(seed=0)
        state = env.oracle_state()
    assert state.obs.shape == (4, 39) and np.allclose(state.obs[:, 36:39], np.repeat(family.train_goals, 2, axis=0))
    levels = np.array([0.0, 0.2, 0.8, 1.0])
    a = family.oracle.behavior_actions(state, levels, np.random.default_rng(5))
    b = family.oracle.behavior_actions(state, levels, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(5)
    noise, uniform = rng.standard_normal((4, 4)), rng.uniform(-1, 1, (4, 4)).astype(np.float32)
    np.testing.assert_array_equal(a[0], uniform[0])
    np.testing.assert_allclose(a[2], family.weights.sample_actions(state.obs[2:3], 0.8, noise[2:3])[0], atol=1e-7)
    np.testing.assert_allclose(family.oracle.optimal_actions(state), family.weights.mean_actions(state.obs))
    u = family.oracle.utility(state, np.stack([a, -a]))
    assert u.shape == (2, 4)


def test_sac_family_generates_the_paper_recipes(family):
    ipref = StepPreferences(first_policy="low", train_policy="high", bt_temperature=0.02, trajectories_per_task=2,
                            val_trajectories_per_task=1, eval_contexts_per_task=1, calibration_episodes=2,
                            reference_episodes=1)
    splits, info = ipref.generate(family, progress=False)
    assert splits["train"]["states"].shape == (4, 12, 39) and np.all(splits["train"]["states"][..., 36:39] == 0)
    assert {q: c["mixing"] for q, c in info["calibration"].items()} == {"low": 0.2, "medium": 0.4, "high": 0.8}
    assert 0.0 <= info["train_statistics"]["label_agreement"] <= 1.0
    ref = info["test_reference"]["high"]
    assert {"behavior_return", "sac_return", "expert_return", "uniform_return"} <= set(ref)
    assert family.config()["expert"] == "sac" and len(family.config()["sac_oracle"]["sha256"]) == 64
    again, _ = ipref.generate(family, progress=False)
    np.testing.assert_array_equal(again["train"]["preferred"], splits["train"]["preferred"])
    # DP²T's labels are π's mean actions at the query states (the goal shown to π, hidden in the stored states)
    train = splits["train"]
    query = train["query_states"].copy()
    query[..., 36:39] = family.train_goals[train["task_index"]][:, None, :]
    expected = family.weights.mean_actions(query.reshape(-1, 39)).reshape(train["optimal_actions"].shape)
    np.testing.assert_allclose(train["optimal_actions"], expected, atol=1e-6)
    assert np.all(query[..., 36:39] != 0) and np.all(train["query_states"][..., 36:39] == 0)
    tprl = TrajectoryPairs(train_policy="pretraining", trajectories_per_task=1, val_trajectories_per_task=1,
                           eval_contexts_per_task=1, calibration_episodes=2, reference_episodes=1)
    _, info = tprl.generate(family, progress=False)
    assert info["calibration"]["pretraining"]["mixing"] == 0.5
    contexts = RewardContexts(trajectories_per_task=1, val_trajectories_per_task=1, eval_contexts_per_task=1,
                              calibration_episodes=2, reference_episodes=1, quality_targets=(0.2, 0.3, 0.8))
    with pytest.raises(KeyError, match="no policy at level 0.3"):
        contexts.generate(family, progress=False)


@pytest.mark.skipif(not DEFAULT_ORACLE.exists(), reason="the committed SAC oracle is not exported yet")
def test_the_committed_oracle_loads_and_verifies():
    oracle = ExportedSAC(DEFAULT_ORACLE)
    assert oracle.levels == (0.2, 0.4, 0.5, 0.8, 1.0)
    manifest = oracle.manifest
    assert manifest["training"]["command"].startswith("python -m icprl_lightning.families.metaworld_reach.sac ")


def test_reach_ipref_configs_are_the_sac_recipe_and_overlays_switch_recipes(exported, tmp_path):
    """icpo/dp2t/dpt_metaworld.yaml are the paper's recipe; scripted_expert_*.yaml put them back on the scripted
    expert; sac_oracle.yaml puts the T-PRL configs on the SAC oracle."""
    from factories import REPO

    from icprl_lightning.data.config import datamodule_from_config
    from icprl_lightning.families.metaworld_reach import ReachTaskFamily

    local = tmp_path / "local.yaml"  # the tiny oracle instead of the committed one
    local.write_text(f"data:\n  init_args:\n    family:\n      init_args:\n        oracle_dir: {exported}\n")

    def config(name: str, *overlays: str):
        return [str(REPO / f"configs/{name}.yaml"), *(str(REPO / f"configs/overlays/{o}.yaml") for o in overlays)]

    for name in ("icpo_metaworld", "dp2t_metaworld"):
        dm = datamodule_from_config(*config(name), str(local), root_dir=str(tmp_path))
        assert isinstance(dm.family, ReachSACTaskFamily) and dm.family.oracle_dir == exported, name
        assert dm.setting.bt_temperature == 0.01, name
        dm = datamodule_from_config(*config(name, "scripted_expert_ipref"), root_dir=str(tmp_path))
        assert type(dm.family) is ReachTaskFamily and dm.setting.bt_temperature == 0.02, name
    dpt = datamodule_from_config(*config("dpt_metaworld"), str(local), root_dir=str(tmp_path))
    assert isinstance(dpt.family, ReachSACTaskFamily)
    assert (dpt.setting.train_policy, dpt.setting.pretraining_target) == ("pretraining", 1.0)
    dpt = datamodule_from_config(*config("dpt_metaworld", "scripted_expert_dpt"), root_dir=str(tmp_path))
    assert type(dpt.family) is ReachTaskFamily
    assert (dpt.setting.train_policy, dpt.setting.pretraining_target) == ("cycle", None)
    for name in ("dp2t_metaworld_tprl", "icrg_metaworld", "reward_gen_metaworld", "dit_metaworld"):
        assert type(datamodule_from_config(*config(name), root_dir=str(tmp_path)).family) is ReachTaskFamily, name
        dm = datamodule_from_config(*config(name, "sac_oracle"), str(local), root_dir=str(tmp_path))
        assert isinstance(dm.family, ReachSACTaskFamily) and dm.family.oracle_dir == exported, name


def test_the_default_oracle_is_a_bare_name_so_saved_configs_carry_no_machine_path(tmp_path, monkeypatch):
    from icprl_lightning.families.metaworld_reach.sac_family import DEFAULT_ORACLE_NAME, oracle_path

    monkeypatch.chdir(tmp_path)
    assert oracle_path(DEFAULT_ORACLE_NAME) == DEFAULT_ORACLE  # a packaged oracle, from any working directory
    assert oracle_path(tmp_path / "mine") == tmp_path / "mine"  # any other path is taken as given
    assert oracle_path("not_packaged") == Path("not_packaged")
    (tmp_path / DEFAULT_ORACLE_NAME).mkdir()  # a folder of that name here wins over the package's
    assert oracle_path(DEFAULT_ORACLE_NAME) == Path(DEFAULT_ORACLE_NAME)
