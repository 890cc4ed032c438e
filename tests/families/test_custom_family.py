"""Bring your own family: a 1-D chain defined here, in the test, trains ICPO and DPT from a config that
names it by class_path and deploys through ``load_agent`` — with no edit to the package
(docs/extending.md walks through the same code).

The chain: cells 0..L−1, a hidden goal cell per task, three actions (left, stay, right), reward 1 on
every step that ends on the goal, H steps. Utility of an action: minus the distance to the goal after it
(A* up to a per-state constant while the goal is more than one step away).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml

from icprl_lightning import StepPreferenceContext, load_agent
from icprl_lightning.commands import run_cli
from icprl_lightning.contexts import ActionSpec
from icprl_lightning.families.base import Oracle, TaskFamily

LEFT, STAY, RIGHT = 0, 1, 2


class ChainState(NamedTuple):
    position: np.ndarray  # [N] int
    goal: np.ndarray      # [N] int
    t: int


class ChainEnv(gym.vector.VectorEnv):
    """N chain episodes at once; obs = the position as float32 [N, 1]; the goal is never observed."""

    def __init__(self, length: int, horizon: int, goals: np.ndarray) -> None:
        self.length, self.horizon, self.goals = length, horizon, np.asarray(goals, dtype=np.int64).reshape(-1)
        self.num_envs = len(self.goals)
        self.single_observation_space = gym.spaces.Box(0, length - 1, shape=(1,), dtype=np.float32)
        self.single_action_space = gym.spaces.Discrete(3)
        self.position, self.t = np.zeros(self.num_envs, dtype=np.int64), 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.position, self.t = self.np_random.integers(0, self.length, self.num_envs), 0
        return self.position[:, None].astype(np.float32), {}

    def step(self, actions: np.ndarray):
        self.position = np.clip(self.position + np.asarray(actions) - 1, 0, self.length - 1)
        self.t += 1
        reward = (self.position == self.goals).astype(np.float32)
        done = np.full(self.num_envs, self.t >= self.horizon)
        return self.position[:, None].astype(np.float32), reward, np.zeros_like(done), done, {}

    def oracle_state(self) -> ChainState:
        return ChainState(self.position.copy(), self.goals.copy(), self.t)


class ChainOracle(Oracle):
    def __init__(self, length: int) -> None:
        self.length = length

    def uniform_actions(self, state: ChainState, rng: np.random.Generator) -> np.ndarray:
        return rng.integers(0, 3, size=len(state.position))

    def optimal_actions(self, state: ChainState) -> np.ndarray:
        return 1 + np.sign(state.goal - state.position)

    def utility(self, state: ChainState, actions: np.ndarray) -> np.ndarray:
        after = np.clip(state.position + actions - 1, 0, self.length - 1)
        return -np.abs(after - state.goal).astype(np.float64)


class ChainFamily(TaskFamily):
    name = "chain"
    metric_env = "chain"
    obs_dim = 1

    def __init__(self, length: int = 9, horizon: int = 12, n_train_tasks: int = 6, n_test_tasks: int = 3,
                 seed: int = 0) -> None:
        self.length, self.horizon, self.seed = length, horizon, seed
        cells = np.random.default_rng(seed).permutation(length)
        self._split = {"train": cells[:n_train_tasks], "test": cells[n_train_tasks:n_train_tasks + n_test_tasks]}
        self._oracle = ChainOracle(length)

    @property
    def action_spec(self) -> ActionSpec:
        return ActionSpec(discrete=True, size=3)

    @property
    def oracle(self) -> ChainOracle:
        return self._oracle

    def tasks(self, split: str) -> np.ndarray:
        return self._split[split].copy()

    def make_env(self, tasks: np.ndarray) -> ChainEnv:
        return ChainEnv(self.length, self.horizon, tasks)

    def config(self) -> dict[str, Any]:
        return {"family": self.name, "length": self.length, "horizon": self.horizon, "seed": self.seed,
                "tasks": {k: v.tolist() for k, v in self._split.items()}}


def _config(tmp_path, method: dict, setting: str, data_flags: dict) -> str:
    config = {
        "seed_everything": 0,
        "trainer": {"accelerator": "cpu", "max_steps": 30, "logger": False, "enable_progress_bar": False,
                    "default_root_dir": str(tmp_path), "check_val_every_n_epoch": 1},
        "evaluation": {"print_table": False}, "best_checkpoint": None,
        "model": method,
        "data": {"class_path": "icprl_lightning.data.PreferenceDataModule",
                 "init_args": {"family": {"class_path": f"{__name__}.ChainFamily"},
                               "setting": {"class_path": f"icprl_lightning.data.settings.{setting}",
                                           "init_args": {"trajectories_per_task": 8, "val_trajectories_per_task": 2,
                                                         "eval_contexts_per_task": 2, "calibration_episodes": 12,
                                                         "reference_episodes": 4}},
                               "root_dir": str(tmp_path / "data"), "batch_size": 8, "progress": False,
                               **data_flags}}}
    path = tmp_path / f"{setting}.yaml"
    path.write_text(yaml.safe_dump(config))
    return str(path)


SIZES = {"backbone": {"n_layer": 1, "n_embd": 16, "n_head": 2}, "optimizer": {"lr": 0.003}}


@pytest.mark.parametrize(("method", "setting", "flags"), [
    ({"class_path": "icprl_lightning.methods.icpo.ICPOModule", "init_args": SIZES}, "StepPreferences",
     {"pairs": True}),
    ({"class_path": "icprl_lightning.methods.dpt.DPTModule", "init_args": SIZES}, "RewardContexts",
     {"query_labels": True}),
])
def test_a_family_defined_outside_the_package_trains_and_deploys(tmp_path, method, setting, flags, capsys):
    cli = run_cli(["fit", "--config", _config(tmp_path, method, setting, flags)])
    metrics = cli.trainer.callback_metrics  # the held-out rollouts ran through the public Agent
    for quality in ("low", "medium", "high"):
        assert {"return", "normalized_return", "behavior_return", "optimal_return"} <= {
            k.rsplit("/", 1)[1] for k in metrics if k.startswith(f"val/chain/{quality}/")}
    ckpt = next(tmp_path.rglob("*.ckpt"))
    data_dir = next((tmp_path / "data").iterdir())
    assert data_dir.name.startswith("chain-")
    manifest = yaml.safe_load((data_dir / "manifest.json").read_text())
    calibration = manifest["info"]["calibration"]
    assert calibration["low"]["mixing"] < calibration["medium"]["mixing"] < calibration["high"]["mixing"]
    reference = manifest["info"]["test_reference"]
    assert reference["low"]["behavior_return"] < reference["high"]["behavior_return"] < reference["high"][
        "optimal_return"]

    agent = load_agent(ckpt)
    family = ChainFamily()
    if setting == "StepPreferences":
        # an I-PRL context for each held-out goal, built by hand: stay at the start, prefer moving towards it
        goals = family.tasks("test")
        states = torch.zeros(len(goals), 5, 1)
        towards = torch.from_numpy(1 + np.sign(goals)).long()[:, None].expand(-1, 5)
        context = StepPreferenceContext(states, towards.clone(), torch.full((len(goals), 5), STAY),
                                        torch.ones(len(goals), 5))
        agent.reset(context)
        actions = agent.act(torch.zeros(len(goals), 1))
        assert actions.shape == (len(goals),) and actions.dtype == torch.int64
        assert ((actions >= 0) & (actions < 3)).all()
    else:
        with pytest.raises(ValueError, match="RewardContext"):
            agent.reset(StepPreferenceContext(torch.zeros(1, 2, 1), torch.zeros(1, 2).long(),
                                              torch.zeros(1, 2).long(), torch.ones(1, 2)))
