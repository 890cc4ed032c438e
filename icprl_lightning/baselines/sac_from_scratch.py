"""SAC trained from scratch on each held-out Meta-World Reach goal (paper, section 6 and appendix
"Baseline Implementation Details"): the online-RL yardstick for the test tasks' difficulty.

Algorithm: Stable-Baselines3 ``SAC("MlpPolicy")`` with SB3's default hyperparameters, as in the paper
(continuous actions, off-policy; the paper's choice for Meta-World). One agent per (goal, seed) on a
``ReachGoalEnv`` (latent reward −‖tcp − goal‖, H = 150, goal hidden: it is a constant of the task).
Every ``eval_every`` episodes the deterministic policy is evaluated on ``eval_episodes`` episodes with a
fixed seed; the best checkpoint by that return is restored and reported on ``test_episodes`` fresh
episodes (return, success = the 0.05 radius reached at some step), beside the uniform policy and
metaworld's scripted expert on the same episodes, whence the normalized return
(R − R_uniform) / (R_expert − R_uniform) of ``families/metaworld_reach/oracle.py``.

Budget. The paper trains 1,000 episodes (150,000 steps) per goal. SB3's SAC costs ≈ 35 ms of CPU per
step here (one gradient step per env step, 256×256 networks, one torch thread), so the CPU default is
20 episodes (3,000 steps, ≈ 100 s of CPU) per goal: a cheap lower bound on the paper's baseline,
stated in the output JSON. Run it as

    icprl baseline sac --episodes 20 --test-episodes 5 \
        --out docs/results/sac_from_scratch/sac_from_scratch_metaworld.json

and pass ``--episodes 1000`` for the paper's budget.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import stable_baselines3
from stable_baselines3 import SAC

from icprl_lightning.baselines.from_scratch import over_goals, train_from_scratch
from icprl_lightning.families.metaworld_reach.env import HORIZON
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.oracle import normalized_return
from icprl_lightning.families.metaworld_reach.sac import reference_acts

PAPER_EPISODES = 1000
DEFAULT_EPISODES = 20


def run_goal(goal: np.ndarray, seed: int, episodes: int, horizon: int = HORIZON, eval_every: int = 2,
             eval_episodes: int = 2, test_episodes: int = 10) -> dict[str, Any]:
    """Train SAC from scratch on one goal for ``episodes`` episodes; the best checkpoint's test results."""
    model_seed, eval_seed, test_seed, ref_seed = (int(s) for s in np.random.SeedSequence(seed).generate_state(4))
    model = SAC("MlpPolicy", ReachGoalEnv(goal, horizon=horizon), seed=model_seed, device="cpu")
    eval_env = ReachGoalEnv(goal, horizon=horizon)
    result = train_from_scratch(model, eval_env, episodes * horizon, eval_every * horizon, eval_episodes, eval_seed,
                                test_episodes, test_seed, reference_acts(eval_env, np.random.default_rng(ref_seed)))
    refs = result["reference_returns"]
    result["normalized_return"] = float(normalized_return(result["return"], refs["uniform"], refs["expert"]))
    return {"goal": np.asarray(goal).tolist(), "seed": seed, **result}


def run(goals: np.ndarray, seeds: Sequence[int], episodes: int, horizon: int = HORIZON, eval_every: int = 2,
        eval_episodes: int = 2, test_episodes: int = 10, progress: bool = False) -> dict[str, Any]:
    """All (goal, seed) runs; per goal the mean over seeds, then mean ± sem over goals."""
    return {"algorithm": f"SAC (stable-baselines3 {stable_baselines3.__version__}, default hyperparameters)",
            "env": "metaworld reach-v3, latent reward -||tcp - goal||", "horizon": horizon,
            "episodes_per_goal": episodes, "paper_episodes_per_goal": PAPER_EPISODES, "seeds": list(seeds),
            "eval_every_episodes": eval_every, "eval_episodes": eval_episodes, "test_episodes": test_episodes,
            **over_goals(goals, seeds, lambda goal, seed: run_goal(goal, seed, episodes, horizon, eval_every,
                                                                   eval_episodes, test_episodes), progress)}
