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

import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import stable_baselines3
from stable_baselines3 import SAC

from icprl_lightning.baselines.from_scratch import from_scratch_record, train_from_scratch
from icprl_lightning.families.metaworld_reach.env import ACTION_DIM, HORIZON
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.oracle import expert_actions, normalized_return
from icprl_lightning.sb3 import Act

PAPER_EPISODES = 1000
DEFAULT_EPISODES = 20


def reach_references(env: ReachGoalEnv, seed: int) -> dict[str, Act]:
    """Uniform actions (seeded) and the scripted expert of ``families/metaworld_reach/oracle.py``, which reads
    ``env``'s privileged state (the goal, the TCP): run them on ``env`` itself."""
    rng = np.random.default_rng(seed)
    return {"uniform": lambda obs: rng.uniform(-1.0, 1.0, size=ACTION_DIM).astype(np.float32),
            "expert": lambda obs: expert_actions(env.oracle_state())[0]}


def run_goal(goal: np.ndarray, seed: int, episodes: int, horizon: int = HORIZON, eval_every: int = 2,
             eval_episodes: int = 2, test_episodes: int = 10) -> dict[str, Any]:
    """Train SAC from scratch on one goal for ``episodes`` episodes; the best checkpoint's test results."""
    model_seed, eval_seed, test_seed, ref_seed = (int(s) for s in np.random.SeedSequence(seed).generate_state(4))
    model = SAC("MlpPolicy", ReachGoalEnv(goal, horizon=horizon), seed=model_seed, device="cpu")
    eval_env = ReachGoalEnv(goal, horizon=horizon)
    result = train_from_scratch(model, eval_env, episodes * horizon, eval_every * horizon, eval_episodes, eval_seed,
                                test_episodes, test_seed, reach_references(eval_env, ref_seed))
    refs = result["reference_returns"]
    result["normalized_return"] = float(normalized_return(result["return"], refs["uniform"], refs["expert"]))
    return {"goal": np.asarray(goal).tolist(), "seed": seed, **result}


def run(goals: np.ndarray, seeds: Sequence[int], episodes: int, horizon: int = HORIZON, eval_every: int = 2,
        eval_episodes: int = 2, test_episodes: int = 10, progress: bool = False) -> dict[str, Any]:
    """All (goal, seed) runs; per goal the mean over seeds, then mean ± sem over goals."""
    start, cpu_start = time.perf_counter(), time.process_time()
    keys = ("return", "success", "normalized_return")
    per_goal = []
    for g, goal in enumerate(goals):
        runs = []
        for seed in seeds:
            runs.append(run_goal(goal, int(np.random.SeedSequence([seed, g]).generate_state(1)[0]), episodes,
                                 horizon, eval_every, eval_episodes, test_episodes))
            if progress:
                print(f"goal {g} seed {seed}: return {runs[-1]['return']:.2f} success {runs[-1]['success']:.2f} "
                      f"({runs[-1]['train_seconds']:.0f} s)", file=sys.stderr, flush=True)
        per_goal.append({"goal": np.asarray(goal).tolist(),
                         **{k: float(np.mean([r[k] for r in runs])) for k in keys}, "runs": runs})
    return {"algorithm": f"SAC (stable-baselines3 {stable_baselines3.__version__}, default hyperparameters)",
            "env": "metaworld reach-v3, latent reward -||tcp - goal||", "horizon": horizon,
            "episodes_per_goal": episodes, "paper_episodes_per_goal": PAPER_EPISODES, "seeds": list(seeds),
            "eval_every_episodes": eval_every, "eval_episodes": eval_episodes, "test_episodes": test_episodes,
            **from_scratch_record(per_goal, keys, start, cpu_start)}
