"""Meta-World Reach oracle (b), as in the paper: Stable-Baselines3 SAC, its checkpoints as behavior
policies and its critic as the A* estimate (appendices "Baseline Implementation Details" and
"Pretraining Data Generation").

Privileged: the SAC sees the goal (``ReachGoalEnv(goal_visible=True)``); no preference learner receives its
inputs or outputs except through the labels and behavior actions it produces.

One goal-conditioned SAC over the chosen goals (default: the 45 training goals), not the paper's one SAC per
task: on a CPU SB3's SAC runs ≈ 30 steps/s per core, so 45 runs to convergence would take a day, while the arm
dynamics are shared and only the goal differs. Its critic Q(s, a; g) is goal-specific, which is all A* needs.
The one difference: the behavior checkpoints are shared by the goals, so "20% of the final return" holds on
average over the goals. ``--goal-index i`` trains the per-task variant with the same code.

Checkpoints are saved and evaluated every ``checkpoint_every`` steps (and at step 0) on the same episodes,
acting by *sampling*, as a behavior policy will; the last is the converged policy π. A checkpoint's quality is
q = (R − R_uniform) / (R_final − R_uniform), and per target the checkpoint with q closest is the behavior
policy (``calibrate_checkpoints``; ``achieved_vs_expert`` normalizes by the scripted expert instead).

Advantage. A*(s, a) ≈ Q̂(s, a) − (1/M) Σ_m Q̂(s, a'_m), a'_m ~ π(·|s), with Q̂ the minimum of SAC's twin
critics (the value SAC's own policy update uses). Averaged over actions drawn from π it is zero up to
Monte Carlo error.

Hyperparameters. SB3's defaults (γ = 0.99, latent reward as is) learn and then lose Reach: a 200k-transition
run reached 0.8 success at 110k and fell to 0.1. The committed oracle
(``sac_oracle_v1``) was trained with the reward scaled by 10 (``--reward-scale``: Q̂ is divided by it again,
so A* stays in latent-return units) and γ = 0.95 (``--gamma``), 4 envs collecting at once; everything else
is SB3's default. On the same seed, γ = 0.99 with two gradient steps per vector step plateaued at about
−9 (sampled) while γ = 0.95 reached −6.6 by 250k transitions.

Run (writes ``<out>/checkpoints/step_*.zip`` and ``<out>/summary.json`` through a temp directory renamed
into place, so an interrupted run leaves nothing half-written), then export the weights the data recipe
reads (``sac_weights.py``):

    icprl oracle train --goals all --n-envs 4 --reward-scale 10 \
        --gamma 0.95 --timesteps 400000 --checkpoint-every 10000 --eval-episodes 20 --out runs/sac_oracle/C
    icprl oracle export runs/sac_oracle/C --out icprl_lightning/families/metaworld_reach/sac_oracle_v1

``SACTrainingRun`` reads such a run directory back (its SB3 zips, unpickled: our own runs only);
``sac_weights.ExportedSAC`` is the exported, pickle-free form that data generation loads.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch
from gymnasium.wrappers import TransformReward
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import DummyVecEnv

from icprl_lightning.families.metaworld_reach.env import ACTION_DIM, HORIZON
from icprl_lightning.families.metaworld_reach.gym_env import ReachGoalEnv
from icprl_lightning.families.metaworld_reach.oracle import QUALITY_TARGETS, expert_actions
from icprl_lightning.io import check_replaceable, jsonable, staged_directory
from icprl_lightning.sb3 import Act, EvalCheckpointCallback, EvalRecord, run_episodes

SUMMARY = "summary.json"  # the marker of an oracle directory: only one with it (this schema) is replaced
SCHEMA_VERSION = 1
WHAT = "SAC oracle directory"


def sample_policy_actions(model: SAC, obs: np.ndarray, generator: torch.Generator) -> np.ndarray:
    """Actions [B, 4] sampled from SAC's squashed Gaussian at obs [B, 39], noise from ``generator``."""
    with torch.no_grad():
        mean, log_std, _ = model.actor.get_action_dist_params(torch.as_tensor(obs, dtype=torch.float32))
        noise = torch.randn(mean.shape, generator=generator)
        actions = torch.tanh(mean + log_std.exp() * noise)
    return model.policy.unscale_action(actions.numpy())


def stochastic_act(seed: int) -> Callable[[SAC], Act]:
    """``make_act`` for the checkpoint callback: sample from the policy, the same noise at each evaluation."""
    def make_act(model: SAC) -> Act:
        generator = torch.Generator().manual_seed(seed)
        return lambda obs: sample_policy_actions(model, obs[None], generator)[0]
    return make_act


def calibrate_checkpoints(records: Sequence[EvalRecord], uniform_return: float, expert_return: float,
                          targets: Mapping[str, float] = QUALITY_TARGETS) -> dict[str, dict[str, Any]]:
    """For each target, the checkpoint whose return normalized between uniform (0) and the last one (1) is closest.

    Ties go to the earlier checkpoint. The scripted oracle's calibration format, plus the checkpoint.
    """
    returns = np.array([r.mean_return for r in records], dtype=np.float64)
    final = returns[-1]
    normalized = (returns - uniform_return) / (final - uniform_return)
    out = {}
    for name, target in targets.items():
        i = int(np.argmin(np.abs(normalized - target)))
        out[name] = {"target": float(target), "achieved": float(normalized[i]), "step": records[i].step,
                     "path": records[i].path, "return": float(returns[i]), "success": records[i].success,
                     "uniform_return": float(uniform_return), "final_return": float(final),
                     "expert_return": float(expert_return),
                     "achieved_vs_expert": float((returns[i] - uniform_return) / (expert_return - uniform_return))}
    return out


def reference_acts(env: ReachGoalEnv, rng: np.random.Generator) -> dict[str, Act]:
    """The two reference policies of every report, on ``env``: uniform actions (from ``rng``) and the scripted
    expert (which reads ``env``'s privileged state)."""
    return {"uniform": lambda obs: rng.uniform(-1, 1, ACTION_DIM).astype(np.float32),
            "expert": lambda obs: expert_actions(env.oracle_state())[0]}


def split_report(model: SAC, goals: np.ndarray, horizon: int, episodes_per_goal: int, seed: int) -> dict[str, Any]:
    """The final policy on every goal of a split (``episodes_per_goal`` fresh episodes each): return and
    success acting by its mean (deterministic) and by sampling, beside uniform actions and the scripted expert."""
    env = ReachGoalEnv(goals, horizon=horizon, goal_visible=True)
    options = [{"goal_index": i % len(goals)} for i in range(episodes_per_goal * len(goals))]
    n = len(options)
    policies: dict[str, Act] = {"deterministic": lambda obs: model.predict(obs, deterministic=True)[0],
                                "stochastic": stochastic_act(seed)(model),
                                **reference_acts(env, np.random.default_rng(seed))}
    out: dict[str, Any] = {"goals": len(goals), "episodes": n}
    for name, act in policies.items():
        stats = run_episodes(act, env, n, seed, options)
        out[name] = {"return": float(stats.returns.mean()), "success": float(stats.success.mean())}
    return out


def train_sac_oracle(goals: np.ndarray, out: str | Path, timesteps: int, seed: int = 0,
                     checkpoint_every: int | None = None, eval_episodes: int = 10, horizon: int = HORIZON,
                     targets: Mapping[str, float] = QUALITY_TARGETS, overwrite: bool = False,
                     extra: Mapping[str, Any] | None = None, n_envs: int = 1,
                     report_splits: Mapping[str, np.ndarray] | None = None, report_episodes_per_goal: int = 4,
                     reward_scale: float = 1.0, sac_kwargs: Mapping[str, Any] | None = None, verbose: int = 0
                     ) -> Path:
    """Train one goal-conditioned SAC on ``goals`` [G, 3], save checkpoints, pick the behavior policies.

    ``checkpoint_every`` defaults to timesteps // 20. ``n_envs`` > 1 collects from that many envs at once
    (SB3 ``DummyVecEnv``; one gradient step per vector step, so n transitions per update). The final policy
    is reported on each goal set of ``report_splits`` (e.g. train and test goals; ``split_report``).
    Returns ``out``, written atomically. ``overwrite`` replaces only an oracle directory (its
    ``summary.json`` of this schema); anything else is refused.

    ``reward_scale`` multiplies the latent reward SAC learns from (evaluation returns stay latent); the
    critic's Q̂ is divided by it again in ``SACTrainingRun.q_values``, so A* is in latent-return units.
    ``sac_kwargs`` override SB3's defaults (e.g. ``learning_rate``, ``gradient_steps``, ``batch_size``).
    """
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if not reward_scale > 0:
        raise ValueError(f"reward_scale must be > 0, got {reward_scale}")
    out = Path(out)
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise FileExistsError(f"{out} exists; delete it or pass overwrite=True (--overwrite)")
    check_replaceable(out, SUMMARY, SCHEMA_VERSION, WHAT)  # only an oracle directory is replaced, before training
    goals = np.asarray(goals, dtype=np.float64).reshape(-1, 3)
    every = checkpoint_every or max(1, timesteps // 20)
    model_seed, eval_seed, noise_seed, ref_seed = (int(s) for s in np.random.SeedSequence(seed).generate_state(4))
    with staged_directory(out, marker=SUMMARY, schema_version=SCHEMA_VERSION, what=WHAT, overwrite=overwrite) as tmp:
        eval_env = ReachGoalEnv(goals, horizon=horizon, goal_visible=True)
        options = [{"goal_index": i % len(goals)} for i in range(eval_episodes)]
        callback = EvalCheckpointCallback(eval_env, every, eval_episodes, eval_seed, stochastic_act(noise_seed),
                                          save_dir=tmp / "checkpoints", reset_options=options, eval_at_start=True,
                                          verbose=verbose)

        def make_train_env() -> gym.Env:
            env = ReachGoalEnv(goals, horizon=horizon, goal_visible=True)
            return env if reward_scale == 1.0 else TransformReward(env, lambda r: reward_scale * r)

        train_env = make_train_env() if n_envs == 1 else DummyVecEnv([make_train_env] * n_envs)
        model = SAC("MlpPolicy", train_env, seed=model_seed, device="cpu", **(sac_kwargs or {}))
        start = time.perf_counter()
        model.learn(total_timesteps=timesteps, callback=callback)
        seconds = time.perf_counter() - start
        uniform, expert = (run_episodes(act, eval_env, eval_episodes, eval_seed, options).returns.mean()
                           for act in reference_acts(eval_env, np.random.default_rng(ref_seed)).values())
        calibration = calibrate_checkpoints(callback.history, float(uniform), float(expert), targets)
        final = callback.history[-1]
        splits = {name: split_report(model, g, horizon, report_episodes_per_goal, ref_seed)
                  for name, g in (report_splits or {}).items()}
        summary = {
            "schema_version": SCHEMA_VERSION,
            "algorithm": f"SAC (stable-baselines3 {stable_baselines3.__version__}, defaults except sac_kwargs), "
                         "goal-conditioned (goal in obs[36:39])",
            "goals": goals, "timesteps": timesteps, "horizon": horizon, "seed": seed, "model_seed": model_seed,
            "checkpoint_every": every, "eval_episodes": eval_episodes, "eval_seed": eval_seed,
            "eval_policy": "stochastic (sampled actions)", "uniform_return": float(uniform),
            "expert_return": float(expert), "final": {"step": final.step, "path": final.path,
                                                      "return": final.mean_return, "success": final.success},
            "final_beats_uniform": bool(final.mean_return > uniform),
            "checkpoints": [r._asdict() for r in callback.history], "calibration": calibration,
            "final_by_split": splits, "n_envs": n_envs, "reward_scale": reward_scale,
            "sac_kwargs": dict(sac_kwargs or {}), "train_seconds": seconds, **(extra or {})}
        with open(tmp / SUMMARY, "w") as f:
            json.dump(jsonable(summary), f, indent=2)
    return out


class SACTrainingRun:
    """A SAC oracle's training run directory: the converged policy π and critic, the behavior checkpoints.

    Observations are goal-visible [B, 39] (``ReachGoalEnv(goal_visible=True)``), actions [B, 4].
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        summary_path = self.path / SUMMARY
        if not summary_path.exists():
            raise FileNotFoundError(f"{summary_path} not found: train it with `icprl oracle train`")
        self.summary = json.loads(summary_path.read_text())
        if self.summary.get("schema_version") != SCHEMA_VERSION:
            raise ValueError(f"{summary_path} has schema {self.summary.get('schema_version')}, expected "
                             f"{SCHEMA_VERSION}: retrain the oracle")
        self.model = self.load_checkpoint(self.summary["final"]["path"])
        self._behavior: dict[str, SAC] = {}

    @property
    def calibration(self) -> dict[str, dict[str, Any]]:
        return self.summary["calibration"]

    @property
    def goals(self) -> np.ndarray:
        return np.asarray(self.summary["goals"], dtype=np.float64)

    def behavior(self, quality: str) -> SAC:
        """The checkpoint calibrated for ``quality`` (e.g. "low", "medium", "high")."""
        if quality not in self.calibration:
            raise KeyError(f"quality {quality!r} not calibrated; have {sorted(self.calibration)}")
        if quality not in self._behavior:
            self._behavior[quality] = self.load_checkpoint(self.calibration[quality]["path"])
        return self._behavior[quality]

    def policy_actions(self, obs: np.ndarray, generator: torch.Generator, quality: str | None = None) -> np.ndarray:
        """Actions [B, 4] sampled from π (``quality=None``) or from that quality's behavior checkpoint."""
        model = self.model if quality is None else self.behavior(quality)
        return sample_policy_actions(model, self._check_obs(obs), generator)

    def q_values(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Q̂(s, a) [B]: the minimum of SAC's twin critics, in latent-return units (÷ ``reward_scale``)."""
        obs = self._check_obs(obs)
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (len(obs), ACTION_DIM):
            raise ValueError(f"actions must have shape [{len(obs)}, {ACTION_DIM}], got {list(actions.shape)}")
        scaled = self.model.policy.scale_action(actions)
        with torch.no_grad():
            qs = self.model.critic(torch.as_tensor(obs), torch.as_tensor(scaled, dtype=torch.float32))
        q = torch.cat(qs, dim=1).min(dim=1).values.numpy().astype(np.float64)
        return q / self.summary.get("reward_scale", 1.0)

    def advantage(self, obs: np.ndarray, actions: np.ndarray, n_samples: int = 64, seed: int = 0) -> np.ndarray:
        """A*(s, a) ≈ Q̂(s, a) − mean over ``n_samples`` actions a' ~ π(·|s) of Q̂(s, a') [B]."""
        obs = self._check_obs(obs)
        q = self.q_values(obs, actions)
        repeated = np.repeat(obs, n_samples, axis=0)  # [B·M, 39]
        sampled = self.policy_actions(repeated, torch.Generator().manual_seed(seed))
        baseline = self.q_values(repeated, sampled).reshape(len(obs), n_samples).mean(axis=1)
        return q - baseline

    def load_checkpoint(self, rel: str) -> SAC:
        """An SB3 checkpoint of this run (path relative to the run directory); unpickles: our own runs only."""
        return SAC.load(self.path / rel, device="cpu")

    @staticmethod
    def _check_obs(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        if obs.ndim != 2 or obs.shape[1] != 39:
            raise ValueError(f"obs must be goal-visible observations of shape [B, 39], got {list(obs.shape)}")
        return obs
