"""Exporting the SAC oracle reads the Stable-Baselines3 zips' tensors only (``sac_weights.sb3_policy_tensors``): a
crafted zip whose pickles would run code is exported (``data`` is never read) or refused (``policy.pth``), and
the code never runs. Untrained SAC models on a stand-in env of Reach's sizes: no Meta-World, no training."""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC

from icprl_lightning.families.metaworld_reach.env import ACTION_DIM, OBS_DIM
from icprl_lightning.families.metaworld_reach.sac_weights import ExportedSAC, export_sac_oracle

pytestmark = pytest.mark.usefixtures("one_thread")


class ReachSizes(gym.Env):
    """Reach's goal-visible observation and action spaces, nothing else (SAC only needs the spaces here)."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)

    def reset(self, *, seed=None, options=None):
        return np.zeros(OBS_DIM, np.float32), {}

    def step(self, action):
        return np.zeros(OBS_DIM, np.float32), 0.0, False, False, {}


class WritesMarker:
    """Unpickling this opens ``path`` for writing: the file appearing means a pickle ran."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def _replace_member(path: Path, member: str, data: bytes) -> None:
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members[member] = data
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def _run(tmp_path: Path, returns=(-100.0, -80.0, -40.0, -10.0)) -> tuple[Path, list[SAC]]:
    """A run directory as ``sac.py`` writes it: one SB3 zip per checkpoint and ``summary.json``."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    models, records = [], []
    for step, mean_return in enumerate(returns):
        model = SAC("MlpPolicy", ReachSizes(), seed=step, device="cpu")
        model.save(run / "checkpoints" / f"step_{step}.zip")
        models.append(model)
        records.append({"step": step, "mean_return": mean_return, "success": 0.0,
                        "path": f"checkpoints/step_{step}.zip"})
    final = records[-1]
    summary = {"schema_version": 1, "checkpoints": records, "uniform_return": -100.0, "expert_return": 0.0,
               "reward_scale": 10.0, "final": {"step": final["step"], "path": final["path"],
                                               "return": final["mean_return"], "success": 0.0}}
    (run / "summary.json").write_text(json.dumps(summary))
    return run, models


def test_export_reads_the_zips_tensors_and_matches_sb3(tmp_path):
    run, models = _run(tmp_path)
    oracle = ExportedSAC(export_sac_oracle(run, tmp_path / "oracle", targets=(0.2, 0.8)))
    obs = np.random.default_rng(0).standard_normal((5, OBS_DIM)).astype(np.float32)
    final = models[-1]
    np.testing.assert_allclose(oracle.mean_actions(obs), final.predict(obs, deterministic=True)[0], atol=1e-6)
    actions = np.random.default_rng(1).uniform(-1, 1, (5, ACTION_DIM)).astype(np.float32)
    with torch.no_grad():
        q = torch.minimum(*final.critic(torch.as_tensor(obs), torch.as_tensor(actions))).squeeze(-1).numpy()
    np.testing.assert_allclose(oracle.q_values(obs, actions), q / 10.0, rtol=1e-5, atol=1e-6)
    # level 0.2 is step 1 (normalized 0.22), 0.8 step 2 (0.67): each exported actor is that checkpoint's
    low = models[1].predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(oracle.mean_actions(obs, 0.2), low, atol=1e-6)


def test_a_zip_whose_data_pickle_would_run_code_is_exported_without_running_it(tmp_path):
    run, _ = _run(tmp_path)
    marker = tmp_path / "data_pickle_ran"
    final = run / "checkpoints" / "step_3.zip"
    with zipfile.ZipFile(final) as archive:
        data = json.loads(archive.read("data"))
    data["policy_kwargs"] = {":type:": "<class 'dict'>",
                             ":serialized:": base64.b64encode(pickle.dumps(WritesMarker(marker))).decode()}
    _replace_member(final, "data", json.dumps(data).encode())
    export_sac_oracle(run, tmp_path / "oracle", targets=(0.5,))
    assert not marker.exists()  # the export never unpickled the zip's data
    from stable_baselines3.common.save_util import load_from_zip_file

    load_from_zip_file(final, device="cpu")  # SB3's own loader (SAC.load) runs the same zip's pickle
    assert marker.exists(), "the crafted zip's payload is live: SB3's loader runs it"


def test_a_zip_whose_tensors_pickle_would_run_code_is_refused_in_one_line(tmp_path):
    import io

    run, _ = _run(tmp_path)
    marker = tmp_path / "policy_pickle_ran"
    buffer = io.BytesIO()
    torch.save({"actor.mu.weight": WritesMarker(marker)}, buffer)
    _replace_member(run / "checkpoints" / "step_1.zip", "policy.pth", buffer.getvalue())
    with pytest.raises(ValueError, match=r"step_1.zip: its policy.pth was refused: it holds more than tensors") as e:
        export_sac_oracle(run, tmp_path / "oracle", targets=(0.2,))
    assert "\n" not in str(e.value) and not marker.exists() and not (tmp_path / "oracle").exists()
    (run / "checkpoints" / "step_1.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="step_1.zip is not a readable Stable-Baselines3 zip"):
        export_sac_oracle(run, tmp_path / "oracle", targets=(0.2,))
    summary = json.loads((run / "summary.json").read_text())
    summary["final"]["path"] = "../elsewhere.zip"
    (run / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(ValueError, match="outside the run directory"):
        export_sac_oracle(run, tmp_path / "oracle", targets=(0.9,))
