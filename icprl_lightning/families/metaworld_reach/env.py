"""Meta-World Reach (paper, appendix "MDP Environment Details"): the Sawyer arm moves its tool-centre
point (TCP) to a hidden 3-D goal; H = 150; 45 training goals, 5 held out.

This runs the real ``reach-v3`` of metaworld 3.x (MuJoCo); only the reward and the observation mask
are ours:

* latent reward r_h = −‖tcp_h − goal‖ (the paper's "negative Euclidean distance to the goal"), where
  tcp is metaworld's ``tcp_center`` (midpoint of the two fingers); metaworld's own shaped reward in
  [0, 10] is ignored. Success is ‖tcp − goal‖ ≤ 0.05, metaworld's criterion.
* the goal is hidden: metaworld's goal-hidden (ML) tasks already zero obs[36:39]; we zero it again so
  the invariant does not depend on a metaworld flag.

Tasks. The goals are metaworld's own ML1 ``reach-v3`` task sampling: ``ML1("reach-v3", seed)`` draws
50 distinct training tasks i.i.d. from the env's goal space x ∈ [−0.1, 0.1], y ∈ [0.8, 0.9],
z ∈ [0.05, 0.3]. ``ReachTaskFamily`` keeps their goals in ML1's (random) order: the first ``n_train``
are the training tasks, the last ``n_test`` the held-out ones, so the split is fixed by the seed.
(ML1's own test tasks are not used: they are ML1(seed + 1)'s training tasks, so family seeds s and
s + 1 would share goals.) A task is its goal; the puck on the table (obs[4:7]) is a distractor whose
position ``ReachVectorEnv`` redraws at every reset from its ``np_random`` (seeded by ``reset(seed=)``).

Pitfalls of metaworld 3.1.1 handled here:

* ``reset()`` loops *forever* when the puck and the goal are closer than 0.15 in xy (``reset_model``
  redraws from a frozen random vector). Puck positions are drawn with a margin above that bound, and a
  task that violates it is refused with a ValueError instead of hanging.
* metaworld's ``env.reset(seed=...)`` is ignored. Once ``set_task`` freezes the random vector, reach-v3
  has no randomness left, so determinism comes from choosing the task vector (goal, puck) ourselves,
  from the vector env's own ``np_random``.
* ``set_task`` deletes the cached ``sawyer_observation_space`` when observability changes; we only
  ever use goal-hidden tasks (the default), so the cache is never invalidated.
* Compiling the MuJoCo XML takes ≈0.25 s per env and a model holds ≈20 MB (meshes). Each worker
  compiles it once and its envs *share* that model, each with its own MjData (≈0.1 MB), so a thousand
  envs fit in memory. Sharing is safe because the only per-task model write, ``reset_model`` setting
  the goal *site* position, is visual: sites neither collide nor enter reach-v3's observation or
  reward (which read ``_target_pos``); the mocap-weld reset writes the same constants for every env.
  Dynamics are bit-identical to a stock env (tested).

``ReachVectorEnv.place_hands`` moves every hand to a given point mid-episode (metaworld's own reset-time
hand placement, from the episode's post-reset state), so a state can be drawn independently of the
actions taken (``ReachTaskFamily.independent_state_rollouts``).
"""

from __future__ import annotations

import ast
import contextlib
import multiprocessing as mp
import pickle
import sys
import traceback
import weakref
from functools import lru_cache
from multiprocessing.connection import Connection
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import metaworld
import mujoco
import numpy as np
from metaworld.envs.sawyer_reach_v3 import SawyerReachEnvV3
from metaworld.types import Task

OBS_DIM = 39
ACTION_DIM = 4
HORIZON = 150
SUCCESS_RADIUS = 0.05
GOAL_SLICE = slice(36, 39)
# reach-v3's goal box (its goal_space, from which ML1 draws the goals).
GOAL_LOW = np.array([-0.1, 0.8, 0.05])
GOAL_HIGH = np.array([0.1, 0.9, 0.3])
# reach-v3's object (puck) box; z is the table height.
PUCK_LOW = np.array([-0.1, 0.6, 0.02])
PUCK_HIGH = np.array([0.1, 0.7, 0.02])
# SawyerReachEnvV3.reset_model spins while the puck–goal xy distance is below this.
MIN_PUCK_GOAL_XY = 0.15
_PUCK_GOAL_MARGIN = 0.01
# reach-v3's mocap box (SawyerReachEnvV3 passes hand_low/high and leaves mocap_low/high to default to
# them): where ``set_xyz_action`` clips the mocap, i.e. every target an action sequence can reach.
HAND_LOW = np.array([-0.5, 0.40, 0.05])
HAND_HIGH = np.array([0.5, 1.0, 0.5])
# Simulator steps (of frame_skip frames) ``place_hands`` lets the hand settle: ``_reset_hand``'s default.
PLACE_STEPS = 50
_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


class ReachOracleState(NamedTuple):
    """Privileged per-env state for oracles and evaluation only (never for a preference learner)."""

    hand: np.ndarray       # [B, 3] hand body position, obs[0:3] (what metaworld's expert steers)
    prev_hand: np.ndarray  # [B, 3] hand position one step earlier, obs[18:21]
    tcp: np.ndarray        # [B, 3] tool-centre point; the reward measures its distance to the goal
    mocap: np.ndarray      # [B, 3] mocap target the hand is welded to; actions move it by 0.01·a
    goal: np.ndarray       # [B, 3]
    t: int                 # steps taken in the current episode
    obs: np.ndarray | None = None  # [B, 39] float32 observation with the goal *visible* (the SAC oracle's input)


def latent_reward(tcp: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """r = −‖tcp − goal‖ over the last axis (float64)."""
    return -np.linalg.norm(np.asarray(tcp, np.float64) - np.asarray(goal, np.float64), axis=-1)


def sample_puck_positions(goals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Uniform puck positions in reach-v3's object box, redrawn until ≥ 0.16 from the goal in xy."""
    goals = np.asarray(goals, dtype=np.float64)
    pucks = rng.uniform(PUCK_LOW, PUCK_HIGH, size=goals.shape)
    bad = _too_close(pucks, goals, MIN_PUCK_GOAL_XY + _PUCK_GOAL_MARGIN)
    while bad.any():
        pucks[bad] = rng.uniform(PUCK_LOW, PUCK_HIGH, size=(int(bad.sum()), 3))
        bad = _too_close(pucks, goals, MIN_PUCK_GOAL_XY + _PUCK_GOAL_MARGIN)
    return pucks


def _too_close(pucks: np.ndarray, goals: np.ndarray, bound: float) -> np.ndarray:
    return np.linalg.norm(pucks[..., :2] - goals[..., :2], axis=-1) < bound


def reach_task(goal: np.ndarray, puck: np.ndarray) -> Task:
    """A goal-hidden metaworld ``reach-v3`` task with this goal and puck; refuses pairs that hang reset."""
    goal, puck = np.asarray(goal, np.float64), np.asarray(puck, np.float64)
    if goal.shape != (3,) or puck.shape != (3,):
        raise ValueError(f"goal and puck must have shape [3], got {list(goal.shape)} and {list(puck.shape)}")
    if _too_close(puck, goal, MIN_PUCK_GOAL_XY):
        raise ValueError(f"puck {puck} is within {MIN_PUCK_GOAL_XY} of goal {goal} in xy: metaworld's "
                         "reset() would loop forever")
    data = {"rand_vec": np.concatenate([puck, goal]), "env_cls": SawyerReachEnvV3,
            "partially_observable": True}
    return Task(env_name="reach-v3", data=pickle.dumps(data))


class _CompiledReachEnv(SawyerReachEnvV3):
    """Stock ``SawyerReachEnvV3`` on a once-per-process compiled MuJoCo model shared by all its envs."""

    _compiled: dict[tuple[str, int, int], mujoco.MjModel] = {}

    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        key = (self.fullpath, self.width, self.height)
        if key not in self._compiled:
            self._compiled[key] = super()._initialize_simulation()[0]
        # Shared, not copied: see the module docstring (only the visual goal site differs per task).
        model = self._compiled[key]
        return model, mujoco.MjData(model)


@lru_cache(maxsize=8)
def ml1_goals(seed: int) -> np.ndarray:
    # ML1 seeds numpy's global generator internally and restores its state afterwards (≈5 s).
    tasks = metaworld.ML1("reach-v3", seed=seed).train_tasks
    goals = np.array([pickle.loads(t.data)["rand_vec"][3:] for t in tasks], dtype=np.float64)
    goals.flags.writeable = False
    return goals


class ReachVectorEnv(gym.vector.VectorEnv):
    """B reach-v3 episodes stepping together, each with its own goal, spread over worker processes.

    Gymnasium's vector API: ``reset(seed=, options=)`` returns (obs [B, 39] float32 with the goal zeroed,
    {}); ``step(actions [B, 4])`` returns (obs, reward [B] = −‖tcp − goal‖, terminated [B] (always
    False: reach-v3 has no terminal state), truncated [B] (True at the horizon),
    info = {"success": bool [B], ‖tcp − goal‖ ≤ 0.05}). Actions are clipped to [−1, 1]. Stepping past
    the horizon raises. ``options={"goals": [B, 3]}`` swaps the goals at reset. As in Gymnasium,
    ``reset(seed=s)`` reseeds ``self.np_random``, the source of all randomness (the puck positions drawn
    at each reset), so a seed and an action sequence fix every observation and reward.
    ``place_hands(positions [B, 3])`` moves the hands mid-episode without counting a step.

    ``num_workers=0`` steps in this process; otherwise the envs are split into that many contiguous
    slices, one worker process each, exchanging actions and observations through shared memory (one
    process per slice rather than gymnasium's one per env: B ≈ 20–100 envs share 2 cores). Workers
    start by ``forkserver`` (safe when the parent runs threads, e.g. torch or wandb). Use as a context
    manager or call ``close()``; a worker's exception is re-raised here with its traceback.
    """

    # No autoreset: the batch shares one clock, every episode ends at the horizon, and reset() restarts all.
    metadata = {"autoreset_mode": gym.vector.AutoresetMode.DISABLED}

    def __init__(self, goals: np.ndarray, horizon: int = HORIZON, num_workers: int = 2,
                 start_method: str = "forkserver") -> None:
        goals = np.array(goals, dtype=np.float64)
        if goals.ndim != 2 or goals.shape[1] != 3 or len(goals) == 0:
            raise ValueError(f"goals must have shape [B, 3] with B ≥ 1, got {list(goals.shape)}")
        if not 1 <= horizon <= SawyerReachEnvV3.max_path_length:
            raise ValueError(f"horizon must be in [1, {SawyerReachEnvV3.max_path_length}], got {horizon}")
        self.num_envs = len(goals)
        self.horizon = horizon
        self.obs_dim, self.action_dim = OBS_DIM, ACTION_DIM
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(ACTION_DIM,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.num_envs, OBS_DIM), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.num_envs, ACTION_DIM), dtype=np.float32)
        self._goals = goals
        self.puck_positions = np.zeros_like(goals)
        self.t = horizon  # no episode until reset()
        self._pool = _WorkerPool(self.num_envs, horizon, num_workers, start_method)

    @property
    def goals(self) -> np.ndarray:
        return self._goals.copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start new episodes (``options["goals"]`` [B, 3] replaces the goals); redraws the pucks."""
        super().reset(seed=seed)
        if options and "reset_mask" in options:
            raise ValueError(f"{type(self).__name__}.reset: options['reset_mask'] (a partial reset) is not supported: "
                             "the batch shares one clock; call reset() to restart every episode")
        goals = (options or {}).get("goals")
        if goals is not None:
            goals = np.array(goals, dtype=np.float64)
            if goals.shape != self._goals.shape:
                raise ValueError(f"goals must have shape {list(self._goals.shape)}, got {list(goals.shape)}")
            self._goals = goals
        self.puck_positions = sample_puck_positions(self._goals, self.np_random)
        self._pool.arrays["tasks"][:] = np.concatenate([self.puck_positions, self._goals], axis=1)
        self._pool.run("reset")
        self.t = 0
        return self._masked_obs(), {}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs, ACTION_DIM):
            raise ValueError(f"actions must have shape [{self.num_envs}, {ACTION_DIM}], "
                             f"got {list(actions.shape)}")
        if self.t >= self.horizon:
            raise RuntimeError("episode is over (horizon reached or never reset): call reset()")
        self._pool.arrays["actions"][:] = np.clip(actions, -1.0, 1.0)
        self._pool.run("step")
        self.t += 1
        reward = latent_reward(self._pool.arrays["tcp"], self._goals)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.full(self.num_envs, self.t >= self.horizon)
        return self._masked_obs(), reward, terminated, truncated, {"success": -reward <= SUCCESS_RADIUS}

    def place_hands(self, positions: np.ndarray) -> np.ndarray:
        """Move each env's hand to ``positions`` [B, 3] (inside ``HAND_LOW``–``HAND_HIGH``) mid-episode;
        returns the new observations [B, 39] float32, goal zeroed.

        Per env, from the MuJoCo state saved right after this episode's ``reset`` (so the placed state depends
        on the position and the episode only, never on the actions taken since): the mocap is set to the
        position and the arm simulated ``PLACE_STEPS`` steps with the gripper open, exactly metaworld's
        ``_reset_hand``; then the joint velocities are zeroed (an arm at rest) and the observation recomputed
        with its previous frame obs[18:36] equal to the current one, as after a reset. The episode's step
        count ``t`` does not change; the puck is back at its post-reset place, unless the arm pushed it on its
        way there. The mocap ends exactly at the position and the hand close to it where the arm reaches (the weld's
        gravity sag), but the box is larger than the arm's reach: draws far out (large y or |x|) leave the hand
        short of its target, so placed hands are not uniform over the box even though the targets are.
        """
        positions = np.array(positions, dtype=np.float64)
        if positions.shape != (self.num_envs, 3):
            raise ValueError(f"positions must have shape [{self.num_envs}, 3], got {list(positions.shape)}")
        if np.any(positions < HAND_LOW) or np.any(positions > HAND_HIGH):
            raise ValueError(f"positions must lie in the hand box [{HAND_LOW.tolist()}, {HAND_HIGH.tolist()}]")
        self._pool.arrays["place"][:] = positions
        self._pool.run("place")
        return self._masked_obs()

    def oracle_state(self) -> ReachOracleState:
        """Hand, previous hand, TCP, mocap, goal and the goal-visible observation per env (copies): for
        oracles and evaluation only."""
        obs = self._pool.arrays["obs"]
        visible = obs.astype(np.float32)
        visible[:, GOAL_SLICE] = self._goals
        return ReachOracleState(hand=obs[:, 0:3].copy(), prev_hand=obs[:, 18:21].copy(),
                                tcp=self._pool.arrays["tcp"].copy(), mocap=self._pool.arrays["mocap"].copy(),
                                goal=self._goals.copy(), t=self.t, obs=visible)

    def close_extras(self, **kwargs: object) -> None:
        self._pool.close()

    def __enter__(self) -> ReachVectorEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _masked_obs(self) -> np.ndarray:
        obs = self._pool.arrays["obs"].astype(np.float32)
        obs[:, GOAL_SLICE] = 0.0
        return obs


# Per env: puck + goal (the task vector), action, raw metaworld observation, tcp, mocap position, and
# the hand position ``place_hands`` asks for.
_FIELDS = {"tasks": 6, "actions": ACTION_DIM, "obs": OBS_DIM, "tcp": 3, "mocap": 3, "place": 3}


class _EnvSlice:
    """Stock reach-v3 envs for rows [lo, hi) of the shared arrays; the code every worker runs."""

    def __init__(self, lo: int, hi: int, horizon: int) -> None:
        self.lo = lo
        self.envs = [_CompiledReachEnv() for _ in range(lo, hi)]
        for env in self.envs:
            env.max_path_length = horizon
        self._after_reset: list[np.ndarray | None] = [None] * len(self.envs)  # MuJoCo state after reset

    def run(self, command: str, arrays: dict[str, np.ndarray]) -> None:
        for i, env in enumerate(self.envs, start=self.lo):
            if command == "reset":
                task = arrays["tasks"][i]
                env.set_task(reach_task(goal=task[3:], puck=task[:3]))
                obs, _ = env.reset()
                self._after_reset[i - self.lo] = _get_state(env)
            elif command == "place":
                obs = self._place_hand(env, self._after_reset[i - self.lo], arrays["place"][i].copy())
            else:
                obs, *_ = env.step(arrays["actions"][i].copy())
            arrays["obs"][i] = obs
            arrays["tcp"][i] = env.tcp_center
            arrays["mocap"][i] = env.data.mocap_pos[0]

    @staticmethod
    def _place_hand(env: SawyerReachEnvV3, after_reset: np.ndarray | None, position: np.ndarray) -> np.ndarray:
        """``ReachVectorEnv.place_hands`` for one env: metaworld's ``_reset_hand`` aimed at ``position``."""
        if after_reset is None:
            raise RuntimeError("place_hands needs an episode: call reset() first")
        mujoco.mj_setState(env.model, env.data, after_reset, _STATE_SPEC)
        mocap_id = env.model.body_mocapid[env.data.body("mocap").id]
        for _ in range(PLACE_STEPS):  # SawyerXYZEnv._reset_hand with hand_init_pos = position
            env.data.mocap_pos[mocap_id][:] = position
            env.data.mocap_quat[mocap_id][:] = np.array([1, 0, 1, 0])
            env.do_simulation([-1, 1], env.frame_skip)
        env.data.qvel[:] = 0.0
        mujoco.mj_forward(env.model, env.data)
        env._prev_obs = env._get_curr_obs_combined_no_goal()  # previous frame = current, as after reset
        return env._get_obs()


def _get_state(env: SawyerReachEnvV3) -> np.ndarray:
    state = np.empty(mujoco.mj_stateSize(env.model, _STATE_SPEC))
    mujoco.mj_getState(env.model, env.data, state, _STATE_SPEC)
    return state


def _views(raw: dict[str, object], num_envs: int) -> dict[str, np.ndarray]:
    return {k: np.frombuffer(raw[k], dtype=np.float64).reshape(num_envs, w) for k, w in _FIELDS.items()}


def _worker_main(conn: Connection, raw: dict[str, object], num_envs: int, lo: int, hi: int,
                 horizon: int) -> None:
    arrays = _views(raw, num_envs)
    envs = _EnvSlice(lo, hi, horizon)
    while True:
        command = conn.recv()
        if command == "close":
            return
        try:
            envs.run(command, arrays)
            conn.send(None)
        except Exception:  # the parent re-raises it with the worker's traceback
            conn.send(traceback.format_exc())


def _shutdown(conns: list[Connection], procs: list[mp.process.BaseProcess]) -> None:
    for conn in conns:
        with contextlib.suppress(BrokenPipeError, OSError):
            conn.send("close")
    for proc in procs:
        proc.join(timeout=5)
        if proc.is_alive():
            proc.terminate()
            proc.join()
    for conn in conns:
        conn.close()


def _has_main_guard(path: str) -> bool | None:
    """Whether the script at ``path`` has a top-level ``if __name__ == "__main__":`` (None: unreadable)."""
    try:
        tree = ast.parse(Path(path).read_text(), filename=path)
    except (OSError, SyntaxError, ValueError):
        return None
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare) and len(node.test.comparators) == 1:
            sides = {ast.unparse(node.test.left), ast.unparse(node.test.comparators[0])}
            if "__name__" in sides and ({"'__main__'", '"__main__"'} & sides):
                return True
    return False


def _startup_death_message(start_method: str) -> str:
    """One line saying why a worker died before answering its first command, and what to do.

    Under ``spawn`` and ``forkserver`` (not ``fork``) Python imports the parent's main script again before a
    worker runs (the forkserver preloads it once for all workers): a script that builds a ReachVectorEnv at
    top level then starts processes while being imported, which multiprocessing refuses, and the worker dies
    with that error on stderr. The parent only sees a closed pipe, so it names the likely cause here.
    """
    main_path = getattr(sys.modules.get("__main__"), "__file__", None)
    if start_method in ("spawn", "forkserver") and main_path and _has_main_guard(main_path) is False:
        return (f"a reach-v3 worker process died at start-up: under the {start_method!r} start method every worker "
                f"first imports your main script {main_path}, whose top-level code builds Meta-World envs again; "
                "put that code under `if __name__ == \"__main__\":` (Python's multiprocessing rule, "
                "https://docs.python.org/3/library/multiprocessing.html#multiprocessing-programming)")
    return ("a reach-v3 worker process died at start-up, before answering its first command; its own error "
            "is printed above on stderr")


class _WorkerPool:
    """Shared float64 arrays plus the processes (or, with 0 workers, the local envs) that fill them."""

    def __init__(self, num_envs: int, horizon: int, num_workers: int, start_method: str) -> None:
        if num_workers < 0:
            raise ValueError(f"num_workers must be ≥ 0, got {num_workers}")
        self._conns: list[Connection] = []
        self._start_method = start_method
        self._answered = False  # whether every worker has answered a command: a death before that is at start-up
        self._local: _EnvSlice | None = None
        self._finalizer: weakref.finalize | None = None
        self._closed = False
        if num_workers == 0:
            self.arrays = {k: np.zeros((num_envs, w)) for k, w in _FIELDS.items()}
            self._local = _EnvSlice(0, num_envs, horizon)
            return
        ctx = mp.get_context(start_method)
        if start_method == "forkserver":
            # Workers fork from a server that has imported this module (metaworld, and torch through the
            # package) once, instead of importing it each (≈3 s); no effect if the server already runs.
            ctx.set_forkserver_preload(["__main__", __name__])
        raw = {k: ctx.RawArray("d", num_envs * w) for k, w in _FIELDS.items()}
        self.arrays = _views(raw, num_envs)
        procs = []
        bounds = np.linspace(0, num_envs, min(num_workers, num_envs) + 1).round().astype(int)
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker_main, args=(child, raw, num_envs, int(lo), int(hi), horizon),
                               daemon=True, name=f"reach-worker-{lo}-{hi}")
            proc.start()
            child.close()
            self._conns.append(parent)
            procs.append(proc)
        self._finalizer = weakref.finalize(self, _shutdown, self._conns, procs)

    def run(self, command: str) -> None:
        if self._closed:
            raise RuntimeError("the environment is closed")
        if self._local is not None:
            self._local.run(command, self.arrays)
            return
        for conn in self._conns:
            conn.send(command)
        errors = []
        for conn in self._conns:
            try:
                reply = conn.recv()
            except (EOFError, OSError):
                if not self._answered:
                    raise RuntimeError(_startup_death_message(self._start_method)) from None
                reply = "worker process died"
            if reply is not None:
                errors.append(reply)
        self._answered = True
        if errors:
            raise RuntimeError("reach-v3 worker failed:\n" + "\n".join(errors))

    def close(self) -> None:
        self._closed = True
        if self._finalizer is not None:
            self._finalizer()
