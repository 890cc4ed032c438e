"""DQN trained from scratch on each held-out DarkRoom goal: the paper's online-RL yardstick ("SAC from
scratch", appendix "Baseline Implementation Details") for DarkRoom's discrete actions.

Algorithm. Stable-Baselines3 has no discrete SAC, so we use SB3 ``DQN("MlpPolicy")``: like SAC it is
off-policy with a replay buffer and a learned Q-function, which is what makes 1,000 episodes enough on a
sparse-reward grid; PPO (on-policy, SB3 default 2,048-step rollouts = 20 episodes per update) would
make a handful of updates on the CPU budget below and waste the replay of rare goal visits.
Hyperparameters are SB3's defaults except the two whose defaults are tuned for 10⁷-step Atari runs:
``target_update_interval`` = 1,000 steps (10 episodes; the default 10,000 would leave the target
network untrained for the whole CPU budget) and ``exploration_fraction`` = 0.3 of the budget (the
default 0.1 would stop exploring after a few episodes). ``learning_starts`` stays 100.

Protocol, as for SAC on Meta-World: one agent per (goal, seed) on ``DarkRoomGoalEnv`` (H = 100, the
goal is not observed; it is a constant of the task); every ``eval_every`` episodes the greedy policy is
evaluated on ``eval_episodes`` fixed-seed episodes (random starts); the best checkpoint is restored
and reported on ``test_episodes`` fresh episodes beside the uniform policy and the optimal policy
(closed form, ``families/darkroom/oracle.py``) on the same starts; ``normalized_return`` = R / R_optimal, the
DarkRoom oracle's share-of-optimal convention.

Budget. The paper trains 1,000 episodes (100,000 steps) per goal; the CPU default is 100 episodes
(10,000 steps, ≈ 16 s of CPU) per goal on the 20 held-out goals:

    icprl baseline dqn --episodes 100 \
        --out docs/results/dqn_from_scratch/dqn_from_scratch_darkroom.json

Evaluation uses the greedy policy as a lookup table over the 100 cells (``greedy_table_act``): the same
actions as ``predict(deterministic=True)`` at one network call per evaluation instead of one per step.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import DQN

from icprl_lightning.baselines.from_scratch import over_goals, train_from_scratch
from icprl_lightning.families.darkroom import DarkRoomFamily
from icprl_lightning.families.darkroom.env import N_ACTIONS
from icprl_lightning.families.darkroom.gym_env import DarkRoomGoalEnv
from icprl_lightning.families.darkroom.oracle import optimal_actions
from icprl_lightning.sb3 import Act

PAPER_EPISODES = 1000
DEFAULT_EPISODES = 100
TARGET_UPDATE_STEPS = 1000
EXPLORATION_FRACTION = 0.3


def darkroom_references(env: DarkRoomGoalEnv, seed: int) -> dict[str, Act]:
    """Uniform actions (seeded) and the optimal policy, which reads ``env``'s goal: run them on ``env``."""
    rng = np.random.default_rng(seed)
    return {"uniform": lambda obs: int(rng.integers(N_ACTIONS)),
            "optimal": lambda obs: int(optimal_actions(env.state, env.goal))}


def greedy_table_act(model: DQN) -> Act:
    """The greedy policy as a lookup table over the grid's cells: one Q-network call per evaluation.

    Same actions as ``model.predict(obs, deterministic=True)`` (argmax of the same Q-values), without a
    network call per step; the observation is the agent's integer cell.
    """
    size = model.observation_space.high[0].astype(int) + 1
    cells = np.stack(np.meshgrid(np.arange(size), np.arange(size), indexing="ij"), -1).reshape(-1, 2)
    with torch.no_grad():
        q = model.q_net(torch.as_tensor(cells, dtype=torch.float32))
    table = q.argmax(dim=1).numpy().reshape(size, size)
    return lambda obs: int(table[int(obs[0]), int(obs[1])])


def run_goal(family: DarkRoomFamily, goal: np.ndarray, seed: int, episodes: int, eval_every: int = 5,
             eval_episodes: int = 10, test_episodes: int = 50) -> dict[str, Any]:
    """Train DQN from scratch on one goal for ``episodes`` episodes; the best checkpoint's test results."""
    model_seed, eval_seed, test_seed, ref_seed = (int(s) for s in np.random.SeedSequence(seed).generate_state(4))
    horizon = family.horizon
    model = DQN("MlpPolicy", DarkRoomGoalEnv(family, goal), seed=model_seed, device="cpu",
                target_update_interval=TARGET_UPDATE_STEPS, exploration_fraction=EXPLORATION_FRACTION)
    eval_env = DarkRoomGoalEnv(family, goal)
    result = train_from_scratch(model, eval_env, episodes * horizon, eval_every * horizon, eval_episodes, eval_seed,
                                test_episodes, test_seed, darkroom_references(eval_env, ref_seed), greedy_table_act)
    result["normalized_return"] = result["return"] / result["reference_returns"]["optimal"]
    return {"goal": np.asarray(goal).tolist(), "seed": seed, **result}


def run(family: DarkRoomFamily, goals: np.ndarray, seeds: Sequence[int], episodes: int, eval_every: int = 5,
        eval_episodes: int = 10, test_episodes: int = 50, progress: bool = False) -> dict[str, Any]:
    """All (goal, seed) runs; per goal the mean over seeds, then mean ± sem over goals."""
    return {"algorithm": f"DQN (stable-baselines3 {stable_baselines3.__version__}, defaults except "
                         f"target_update_interval={TARGET_UPDATE_STEPS}, exploration_fraction={EXPLORATION_FRACTION})",
            "env": f"DarkRoom {family.size}x{family.size}, terminate_on_goal={family.terminate_on_goal}",
            "horizon": family.horizon, "episodes_per_goal": episodes, "paper_episodes_per_goal": PAPER_EPISODES,
            "seeds": list(seeds), "eval_every_episodes": eval_every, "eval_episodes": eval_episodes,
            "test_episodes": test_episodes,
            **over_goals(goals, seeds, lambda goal, seed: run_goal(family, goal, seed, episodes, eval_every,
                                                                   eval_episodes, test_episodes), progress)}
