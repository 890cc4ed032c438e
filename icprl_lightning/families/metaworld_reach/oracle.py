"""Meta-World Reach oracle (CPU default): a scripted expert, mixed behavior policies calibrated to
20/40/80% of the expert's normalized return, and an A* estimate for I-PRL step labels.

Privileged: it sees the goal, the TCP and the mocap position (``ReachOracleState``). Only data
generation and evaluation use it.

Expert. metaworld's ``SawyerReachV3Policy`` is a proportional controller, a = (clip(5 (goal − hand)), 0),
on the *hand* body position obs[0:3] (``metaworld_expert_actions``, tested against metaworld's policy).
Our latent reward measures the TCP, which hangs ≈0.045 below the hand, so that policy settles with
‖tcp − goal‖ ≈ 0.045 and forfeits reward at every step. The default expert (``expert_actions``) aims
the same controller at the TCP with gain 10: a = (clip(10 (goal − tcp)), 0). On 20 training goals it
ends 0.0014 from the goal (max 0.005) with latent return −4.82, against −10.46 for metaworld's policy
and −5.97 for the TCP-aimed controller at gain 5 (gain 20: −4.50, but the surrogate below tracks it
less well: sign agreement 93% vs 95%). It is an expert, not the optimum.

Behavior policies (appendix "Pretraining Data Generation"). The paper uses SAC checkpoints for Meta-World
and a per-step mixture for DarkRoom; the CPU default transplants the mixture: with probability p the
expert action, otherwise an action uniform in [−1, 1]^4. One knob spans exactly uniform (p = 0) to
expert (p = 1), it is the paper's own construction, and the uniform end is the I-PRL comparison policy
(a Gaussian-noise scale would need a second reference point for "0%"). Quality is the normalized return

    q(π) = (R(π) − R(uniform)) / (R(expert) − R(uniform)),   R = mean Σ_h −‖tcp_h − goal‖,

(raw ratios of negative returns mean nothing), and ``calibrate_mixing`` finds p for q = 0.2/0.4/0.8 by
simulation on the training goals.

A* estimate. Following the paper (A* ≈ Q̂(s, a) − E_π Q̂(s, ·) for a converged policy π), we use the
expert as π: A(s, a) = Q^E(s, a) − Q^E(s, π_E(s)), with Q^E the latent return of taking a and then
following the expert to the horizon. Q^E is computed by a vectorized rollout of a surrogate model of
the arm: an action moves the mocap by 0.01·clip(a) (exact, metaworld's ``set_xyz_action``, mocap clipped
to the hand box) and the hand follows the mocap through a per-axis linear model

    h_{k+1} − h_k = c0 (h_k − h_{k−1}) + c1 (m_k − h_k) + c2 (m_{k+1} − m_k),

fitted by least squares on 6,000 transitions of mixed policies (R² 0.94–0.97 per axis), with the TCP at
the current hand-to-TCP offset. Measured against MuJoCo (``simulated_q_values``: clone the simulator,
take the action, follow the expert to the horizon) on 180 states of mixed-policy rollouts on the 45
training goals, 4 actions each (expert, 20%-policy, 80%-policy, uniform): Spearman 0.86 within a state,
Pearson 0.97 pooled (slope ≈ 0.93), and the sign of A(a_20%) − A(a_80%) agrees with the simulated one
on 95% of the 175 non-tied pairs. The grip action a[3] does not enter the surrogate (the TCP is the
finger midpoint, which barely moves).

Calibration (TCP expert, 24 training-goal episodes per p): q(p) = 0.07, 0.13, 0.19, 0.26, 0.32, 0.47,
0.57, 0.70, 0.82, 0.92 at p = 0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, so p ≈ 0.06 / 0.13 /
0.42 for low / medium / high (R(uniform) ≈ −40.6, R(expert) ≈ −4.8).

Bradley–Terry temperature. Per-step differences of A are small (median |ΔA| ≈ 0.04 in return units for
a 20%-vs-80%-policy pair; 2.4% of pairs tie, both actions the expert's), so temperature 1 would give
labels near coin flips. ``DEFAULT_BT_TEMPERATURE`` = 0.02 makes 84% of the labels agree with the sign of
ΔA for those pairs (0.01: 91%, 0.05: 73%; 24 episodes each).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import mujoco
import numpy as np
from metaworld.envs.sawyer_reach_v3 import SawyerReachEnvV3

from icprl_lightning.families.base import Oracle, TaskFamily
from icprl_lightning.families.metaworld_reach.env import (
    ACTION_DIM,
    GOAL_SLICE,
    HAND_HIGH,
    HAND_LOW,
    HORIZON,
    ReachOracleState,
    latent_reward,
)

QUALITY_TARGETS: Mapping[str, float] = MappingProxyType({"low": 0.2, "medium": 0.4, "high": 0.8})
METAWORLD_GAIN = 5.0  # SawyerReachV3Policy: move(hand, to=goal, p=5)
EXPERT_GAIN = 10.0
MOCAP_STEP = 0.01  # SawyerXYZEnv.action_scale
# Rows x, y, z; columns c0 (momentum), c1 (spring to the mocap), c2 (mocap velocity).
HAND_DYNAMICS = np.array([[0.605, 0.103, 0.100], [0.899, 0.002, 0.078], [0.829, 0.021, 0.096]])
DEFAULT_BT_TEMPERATURE = 0.02
# Normalized return rises steeply at small p (q ≈ 0.2 near p = 0.05, 0.8 near p = 0.4): dense there.
CALIBRATION_GRID = (0.0, 0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, 1.0)
_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


def expert_actions(state: ReachOracleState) -> np.ndarray:
    """The default expert [B, 4]: a = (clip(10 (goal − tcp)), 0), metaworld's controller aimed at the TCP."""
    return _aim(state.tcp, state.goal, EXPERT_GAIN)


def metaworld_expert_actions(obs: np.ndarray) -> np.ndarray:
    """metaworld's ``SawyerReachV3Policy`` on goal-visible observations [B, 39]: aims the *hand* obs[0:3]."""
    obs = np.asarray(obs, dtype=np.float64)
    return _aim(obs[:, 0:3], obs[:, GOAL_SLICE], METAWORLD_GAIN)


def _aim(point: np.ndarray, goal: np.ndarray, gain: float) -> np.ndarray:
    actions = np.zeros((len(point), ACTION_DIM), dtype=np.float32)
    actions[:, :3] = np.clip(gain * (goal - point), -1.0, 1.0)
    return actions


def expert_q_values(state: ReachOracleState, actions: np.ndarray, horizon: int = HORIZON) -> np.ndarray:
    """Surrogate Q^E(s, a): latent return of ``actions`` then the expert, to the horizon.

    ``actions`` [B, 4] -> [B], or K candidates per env [K, B, 4] -> [K, B] in one vectorized rollout
    (differences of Q^E at one state are differences of A).
    """
    actions = np.asarray(actions, dtype=np.float64)
    b = len(state.hand)
    if actions.shape[-2:] != (b, ACTION_DIM) or actions.ndim not in (2, 3):
        raise ValueError(f"actions must have shape [{b}, {ACTION_DIM}] or [K, {b}, {ACTION_DIM}], "
                         f"got {list(actions.shape)}")
    if actions.ndim == 3:
        return _surrogate_returns(state, actions, horizon)
    return _surrogate_returns(state, actions[None], horizon)[0]


def advantage(state: ReachOracleState, actions: np.ndarray, horizon: int = HORIZON) -> np.ndarray:
    """A(s, a) = Q^E(s, a) − Q^E(s, π_E(s)) [B] (see the module docstring); 0 for the expert's action."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != (len(state.hand), ACTION_DIM):
        raise ValueError(f"actions must have shape [{len(state.hand)}, {ACTION_DIM}], "
                         f"got {list(actions.shape)}")
    q = _surrogate_returns(state, np.stack([actions, expert_actions(state)]), horizon)
    return q[0] - q[1]


def _surrogate_returns(state: ReachOracleState, first: np.ndarray, horizon: int) -> np.ndarray:
    """Returns [K, B] of first actions [K, B, 4] followed by the expert, under the surrogate arm model."""
    steps = horizon - state.t
    if steps <= 0:
        raise ValueError(f"no steps left at t={state.t} with horizon {horizon}")
    c0, c1, c2 = HAND_DYNAMICS.T
    shape = first.shape[:2] + (3,)
    hand, prev = np.broadcast_to(state.hand, shape), np.broadcast_to(state.prev_hand, shape)
    mocap, tcp_offset = np.broadcast_to(state.mocap, shape), state.tcp - state.hand
    push = np.clip(first[..., :3], -1.0, 1.0)
    ret = np.zeros(shape[:2])
    for _ in range(steps):
        nxt_mocap = np.clip(mocap + MOCAP_STEP * push, HAND_LOW, HAND_HIGH)  # the mocap box
        nxt = hand + c0 * (hand - prev) + c1 * (mocap - hand) + c2 * (nxt_mocap - mocap)
        prev, hand, mocap = hand, nxt, nxt_mocap
        ret += latent_reward(hand + tcp_offset, state.goal)
        push = np.clip(EXPERT_GAIN * (state.goal - hand - tcp_offset), -1.0, 1.0)
    return ret


def simulated_q_values(env: SawyerReachEnvV3, actions: np.ndarray, horizon: int = HORIZON) -> np.ndarray:
    """Q^E(s, a) [K] by MuJoCo: from ``env``'s current state, take each action then follow the expert.

    The ground truth ``expert_q_values`` approximates; costs (horizon − t) simulator steps per action.
    ``env`` (a stock reach-v3 env mid-episode) is left exactly as it was.
    """
    saved = np.empty(mujoco.mj_stateSize(env.model, _STATE_SPEC))
    mujoco.mj_getState(env.model, env.data, saved, _STATE_SPEC)
    prev_obs, t0, goal = env._prev_obs.copy(), env.curr_path_length, env._get_pos_goal().copy()
    out = np.zeros(len(actions))
    for i, action in enumerate(np.asarray(actions, dtype=np.float64)):
        a = action
        for _ in range(t0, horizon):
            env.step(a)
            out[i] += latent_reward(env.tcp_center, goal)
            a = _aim(np.asarray(env.tcp_center)[None], goal[None], EXPERT_GAIN)[0]
        mujoco.mj_setState(env.model, env.data, saved, _STATE_SPEC)
        mujoco.mj_forward(env.model, env.data)
        env._prev_obs, env.curr_path_length = prev_obs.copy(), t0
    return out


def normalized_return(returns: np.ndarray | float, uniform_return: float, expert_return: float) -> np.ndarray:
    """(R − R_uniform) / (R_expert − R_uniform): 0 for the uniform policy, 1 for the expert."""
    return (np.asarray(returns, dtype=np.float64) - uniform_return) / (expert_return - uniform_return)


class ReachOracle(Oracle):
    """The ``Oracle`` of ``families/base.py`` for Meta-World Reach (scripted TCP expert, surrogate Q^E)."""

    def __init__(self, family: TaskFamily) -> None:
        self.family = family  # only its horizon is read

    def uniform_actions(self, state: ReachOracleState, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, size=(len(state.hand), ACTION_DIM)).astype(np.float32)

    def optimal_actions(self, state: ReachOracleState) -> np.ndarray:
        return expert_actions(state)

    def utility(self, state: ReachOracleState, actions: np.ndarray) -> np.ndarray:
        """Q^E(s, a) of K candidates [K, N, 4]: at one state its differences are differences of A."""
        return expert_q_values(state, actions, self.family.horizon)
