"""The exported SAC oracle (weights only, checksummed) and the Reach family built on it (the paper's recipe),
on a tiny SAC run: plumbing, equality with SB3's networks, safety and determinism, not learning."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch

from icprl_lightning.data.settings import RewardContexts, StepPreferences, TrajectoryPairs
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.sac import SACOracle, train_sac_oracle
from icprl_lightning.families.metaworld_reach.sac_family import DEFAULT_ORACLE, ReachSACTaskFamily
from icprl_lightning.families.metaworld_reach.sac_weights import (
    CHECKSUMS,
    MANIFEST,
    SACOracleWeights,
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
    sb3 = SACOracle(run_dir)  # the final SB3 model: reward_scale divides its Q
    ours = SACOracleWeights(exported)
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
        SACOracleWeights(copy)

    class Payload:
        def __reduce__(self):
            return (print, ("unpickled!",))

    shutil.rmtree(copy)
    shutil.copytree(exported, copy)
    torch.save({"latent_pi.0.weight": Payload()}, copy / "actor_020.pt")
    lines = [f"{sha256(copy / f)}  {f}" for f in sorted(p.name for p in copy.iterdir() if p.name != CHECKSUMS)]
    (copy / CHECKSUMS).write_text("\n".join(lines) + "\n")  # a consistent but malicious directory
    with pytest.raises(pickle.UnpicklingError):
        SACOracleWeights(copy)
    with pytest.raises(FileNotFoundError, match="not an exported SAC oracle"):
        SACOracleWeights(tmp_path)


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
    oracle = SACOracleWeights(DEFAULT_ORACLE)
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


def test_scale_curves_tabulate_and_plot_what_is_there(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import reach_scale_curves

    def row(value):
        return {"return": -10.0, "normalized_return": value, "normalized_return_sem": 0.01, "training_seeds": 3}

    for recipe, k, icpo in (("sac", 1, 0.5), ("sac", 2, 0.6), ("scripted", 1, 0.7)):
        results = {m: {q: row(v) for q in ("low", "medium", "high")}
                   for m, v in (("DPT", 0.9), ("DP2T", 0.8), ("ICPO", icpo), ("behavior", 0.3))}
        diagnostics = {m: {c: {"medium": row(0.1)} for c in ("flipped_labels", "random_labels", "other_task")}
                       for m in ("DP2T", "ICPO")}
        (tmp_path / f"metaworld_{recipe}_x{k}.json").write_text(json.dumps({"results": results,
                                                                             "diagnostics": diagnostics}))
    reach_scale_curves.main(["--results", str(tmp_path), "--out", str(tmp_path / "scale")])
    md = (tmp_path / "scale.md").read_text()
    assert "| ICPO | 40 | 3 | 0.60 ± 0.01 | 0.60 ± 0.01 | 0.60 ± 0.01 |" in md
    assert "- ICPO, 20 contexts / goal: 0.50 / 0.10 / 0.10 / 0.10" in md
    assert "Not run: 80, 160 contexts per goal." in md and "Not run: 40, 80, 160" in md
    assert (tmp_path / "scale.png").stat().st_size > 0

    refit = {"results": {"ICPO": {q: row(0.75) for q in ("low", "medium", "high")}},
             "diagnostics": {"ICPO": {c: {"medium": row(0.2)} for c in ("flipped_labels", "random_labels")}}}
    (tmp_path / "refit.json").write_text(json.dumps(refit))
    reach_scale_curves.main(["--results", str(tmp_path), "--out", str(tmp_path / "scale"),
                             "--rows", f"sac:1={tmp_path / 'refit.json'}:ICPO"])
    md = (tmp_path / "scale.md").read_text()
    assert "| ICPO | 20 | 3 | 0.75 ± 0.01 |" in md and "| ICPO | 40 | 3 | 0.60 ± 0.01 |" in md
    assert "- ICPO, 20 contexts / goal: 0.75 / 0.20 / 0.20 / –" in md and "ICPO from " in md
    for bad in (f"sac:4={tmp_path / 'refit.json'}:ICPO", f"sac:1={tmp_path / 'refit.json'}:DPT", "sac1=x"):
        with pytest.raises(SystemExit, match="--rows"):
            reach_scale_curves.main(["--results", str(tmp_path), "--out", str(tmp_path / "scale"), "--rows", bad])


def test_from_scratch_curve_normalizes_per_goal_and_finds_the_crossing(tmp_path, capsys):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import sac_from_scratch_curve

    def run(returns):  # uniform −40, expert −10: normalized (R + 40) / 30
        return {"eval_curve": [[150 * (i + 1), r, 0.0] for i, r in enumerate(returns)],
                "reference_returns": {"uniform": -40.0, "expert": -10.0}}

    scratch = {"horizon": 150,
               "per_goal": [{"runs": [run([-40.0, -31.0, -25.0])]}, {"runs": [run([-34.0, -25.0, -19.0])]}]}
    (tmp_path / "scratch.json").write_text(json.dumps(scratch))
    (tmp_path / "zero.json").write_text(json.dumps({"results": {"ICPO": {"medium": {"normalized_return": 0.5}},
                                                                "expert": {"medium": {"normalized_return": 1.0}}}}))
    episodes, mean, _ = sac_from_scratch_curve.curve(scratch)
    np.testing.assert_allclose(episodes, [1, 2, 3])
    np.testing.assert_allclose(mean, [0.1, 0.4, 0.6])
    sac_from_scratch_curve.main([str(tmp_path / "scratch.json"), "--zero-shot", str(tmp_path / "zero.json"),
                                 "--out", str(tmp_path / "curve")])
    out = capsys.readouterr().out
    assert "ICPO: zero-shot 0.50; SAC from scratch reaches it after 3 episodes" in out and "expert" not in out
    assert (tmp_path / "curve.png").exists()


@pytest.mark.skipif(not DEFAULT_ORACLE.exists(), reason="the committed SAC oracle is not exported yet")
def test_label_truth_script_scores_pairs_against_mujoco(monkeypatch):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import sac_label_truth

    out = sac_label_truth.measure(episodes=1, every=50, seed=0)
    assert out["pairs"] == 3
    for key in ("sac_sign_agreement_with_true", "surrogate_sign_agreement_with_true", "true_prefers_80_percent"):
        assert 0.0 <= out[key] <= 1.0


def test_action_balance_separates_a_biased_rejected_side(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import ipref_action_balance

    rng = np.random.default_rng(0)
    a, b = rng.uniform(-1, 1, (50, 10, 4)), rng.uniform(-1, 1, (50, 10, 4)) - 0.5  # the alternative sits lower
    np.save(tmp_path / "actions.npy", a)
    np.save(tmp_path / "alt_actions.npy", b)
    np.save(tmp_path / "preferred.npy", np.ones((50, 10), dtype=np.uint8))
    out = ipref_action_balance.balance(tmp_path)
    np.testing.assert_allclose(out["difference_of_means"], 0.5, atol=0.1)
    assert all(d > 0.5 for d in out["mean_abs_pair_difference"])
    np.save(tmp_path / "actions.npy", a[..., 0])
    with pytest.raises(ValueError, match="continuous actions"):
        ipref_action_balance.balance(tmp_path)


def test_action_balance_by_distance_splits_near_and_far_steps(tmp_path):
    """--near R: steps whose hand (states[..., :3]) lies within R of the task's goal, against the others."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import ipref_action_balance

    split = tmp_path / "train"
    split.mkdir()
    (tmp_path / "tasks").mkdir()
    np.save(tmp_path / "tasks" / "train_goals.npy", np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    states = np.zeros((2, 4, 39), dtype=np.float32)
    states[:, 2:, :3] = 5.0  # the last two steps of each row are far from both goals
    states[1, :2, :3] = 1.0  # row 1 (task 1) starts on its goal
    np.save(split / "states.npy", states)
    np.save(split / "task_index.npy", np.array([0, 1]))
    np.save(split / "actions.npy", np.where(states[..., :1] == 5.0, 1.0, 0.5) * np.ones((2, 4, 4)))
    np.save(split / "alt_actions.npy", -np.ones((2, 4, 4)))
    np.save(split / "preferred.npy", np.ones((2, 4), dtype=np.uint8))
    out = ipref_action_balance.balance_by_distance(tmp_path, "train", radius=0.1)
    assert out["near"]["share"] == 0.5 and out["far"]["share"] == 0.5
    assert out["near"]["mean_preferred"] == [0.5] * 4 and out["far"]["mean_preferred"] == [1.0] * 4
    assert out["near"]["mean_rejected"] == [-1.0] * 4
