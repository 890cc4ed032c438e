"""The ``icprl/...`` Gymnasium ids (``families/registration.py``): ``gymnasium.make`` builds the single env and
Gymnasium's ``check_env`` passes on it; ``gymnasium.make_vec`` builds the project's batched env (one call steps N
episodes) whose metadata declares that it never autoresets; a seed fixes an episode; bad kwargs are one-line errors."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from icprl_lightning.families import registration
from icprl_lightning.families.darkroom.env import DarkRoomVectorEnv

GOAL = [3, 4]
REACH_GOAL = [0.0, 0.85, 0.2]


def _check_env_quietly(env: gym.Env) -> list[str]:
    """Run Gymnasium's ``check_env`` on the unwrapped env; return the messages of the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    return [str(w.message) for w in caught]


def test_registering_imports_neither_torch_nor_mujoco_and_is_idempotent():
    code = ("import sys, warnings\nwarnings.simplefilter('error')\n"
            "import gymnasium as gym\nfrom icprl_lightning.families import registration\n"
            "registration.register_envs()\n"
            "print(sorted(i for i in gym.registry if i.startswith('icprl/')), "
            "[m for m in ('torch', 'mujoco', 'metaworld') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "['icprl/DarkRoom-v0', 'icprl/MetaWorldReach-v0'] []"


@pytest.mark.parametrize("imports", ["gymnasium as gym, icprl_lightning", "icprl_lightning, gymnasium as gym"])
def test_importing_the_package_registers_the_ids_without_torch(imports):
    code = (f"import sys, {imports}\n"
            "print(sorted(i for i in gym.registry if i.startswith('icprl/')), "
            "[m for m in ('torch', 'mujoco', 'metaworld', 'lightning') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "['icprl/DarkRoom-v0', 'icprl/MetaWorldReach-v0'] []"


@pytest.mark.parametrize("env_id", sorted(registration.ENV_IDS))
def test_every_id_makes_a_valid_env_from_its_defaults_alone(env_id):
    env = gym.make(env_id)
    # check_env passes; its only remarks: Reach's unbounded observation Box, as metaworld's own
    assert all("infinity" in m for m in _check_env_quietly(env)), env_id
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                        **({"num_workers": 0} if "Reach" in env_id else {}))
    obs, _ = envs.reset(seed=0)
    assert obs.shape[0] == 2
    envs.close()


def test_the_defaults_are_documented_goals():
    from icprl_lightning.families.darkroom import DarkRoomFamily
    from icprl_lightning.families.metaworld_reach.env import GOAL_HIGH, GOAL_LOW

    assert gym.make("icprl/DarkRoom-v0").unwrapped.goal.tolist() == DarkRoomFamily().tasks("test")[0].tolist()
    assert np.allclose(gym.make("icprl/MetaWorldReach-v0").unwrapped.goals[0], (GOAL_LOW + GOAL_HIGH) / 2)


def test_the_module_prefix_form_registers_on_demand():
    env = gym.make("icprl_lightning.families.registration:icprl/DarkRoom-v0", goal=GOAL)
    assert env.spec.id == "icprl/DarkRoom-v0"


def test_the_dueling_bandit_is_not_registered():
    assert sorted(registration.ENV_IDS) == ["icprl/DarkRoom-v0", "icprl/MetaWorldReach-v0"]
    assert not [i for i in gym.registry if i.startswith("icprl/") and "andit" in i]


# --- DarkRoom --------------------------------------------------------------------------------------


def test_darkroom_make_passes_gymnasiums_check_env_without_warnings():
    env = gym.make("icprl/DarkRoom-v0", goal=GOAL)
    assert env.unwrapped.goal.tolist() == GOAL
    assert env.observation_space == gym.spaces.Box(0, 9, shape=(2,), dtype=np.float32)
    assert env.action_space == gym.spaces.Discrete(5)
    assert _check_env_quietly(env) == []


def test_darkroom_seed_fixes_an_episode():
    env = gym.make("icprl/DarkRoom-v0", goal=GOAL, horizon=6)
    actions = [0, 3, 3, 1, 4, 2]
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=11)
        steps = [env.step(a) for a in actions]
        runs.append((obs.tolist(), [(o.tolist(), r, te, tr) for o, r, te, tr, _ in steps]))
    assert runs[0] == runs[1]
    assert runs[0][1][-1][3] is True  # truncated at the horizon kwarg
    starts = {tuple(env.reset(seed=s)[0].tolist()) for s in range(20)}
    assert len(starts) > 1  # the seed picks the start cell


def test_darkroom_make_vec_is_the_projects_batched_env():
    envs = gym.make_vec("icprl/DarkRoom-v0", num_envs=4, vectorization_mode="vector_entry_point", goal=GOAL)
    assert type(envs) is DarkRoomVectorEnv  # one batched step, not SyncVectorEnv's loop over 4 envs
    assert envs.metadata["autoreset_mode"] is gym.vector.AutoresetMode.DISABLED
    assert envs.single_observation_space == gym.spaces.Box(0, 9, shape=(2,), dtype=np.float32)
    assert envs.observation_space == gym.spaces.Box(0, 9, shape=(4, 2), dtype=np.float32)
    assert envs.single_action_space == gym.spaces.Discrete(5)
    assert envs.action_space == gym.spaces.MultiDiscrete([5, 5, 5, 5])
    assert envs.goals.tolist() == [GOAL] * 4
    # the default mode, when an id has a vector entry point, is that entry point
    assert type(gym.make_vec("icprl/DarkRoom-v0", num_envs=2, goal=GOAL)) is DarkRoomVectorEnv


def test_darkroom_vector_seed_fixes_the_batch_and_episodes_end_together():
    goals = [[0, 0], [9, 9], [3, 4]]
    envs = gym.make_vec("icprl/DarkRoom-v0", num_envs=3, goals=goals, horizon=4)
    actions = np.random.default_rng(0).integers(0, 5, size=(4, 3))
    runs = []
    for _ in range(2):
        obs, _ = envs.reset(seed=5)
        assert envs.observation_space.contains(obs)
        steps = [envs.step(a) for a in actions]
        runs.append([obs] + [x for s in steps for x in s[:4]])
    assert all(np.array_equal(a, b) for a, b in zip(*runs, strict=True))
    truncations = [s[3].tolist() for s in steps]
    assert truncations == [[False] * 3] * 3 + [[True] * 3]
    with pytest.raises(RuntimeError, match="call reset"):  # no autoreset: the caller resets the batch
        envs.step(actions[0])


def test_darkroom_sync_and_vector_modes_agree_on_spaces():
    sync = gym.make_vec("icprl/DarkRoom-v0", num_envs=3, vectorization_mode="sync", goal=GOAL)
    batched = gym.make_vec("icprl/DarkRoom-v0", num_envs=3, goal=GOAL)
    assert sync.single_observation_space == batched.single_observation_space
    assert sync.single_action_space == batched.single_action_space


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"goal": GOAL, "goals": [GOAL, GOAL]}, "one of goal.*not both"),
    ({"goals": [GOAL]}, r"num_envs is 2 but goals has 1 rows .*pass num_envs=1"),
    ({"goals": [[1, 2, 3], [1, 2, 3]]}, r"shape \[2, 2\]"),
    ({"goal": [2.5, 1.0]}, "integer cells"),
    ({"goal": [3, 10]}, "cell of the 10x10 grid"),
    ({"goal": GOAL, "num_envs": 0}, "num_envs must be an integer >= 1"),
])
def test_darkroom_vector_kwargs_are_checked(kwargs, message):
    kwargs = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=f"icprl/DarkRoom-v0: .*{message}"):
        gym.make_vec("icprl/DarkRoom-v0", **kwargs)


def test_darkroom_single_goal_is_checked():
    with pytest.raises(ValueError, match="icprl/DarkRoom-v0: every goal must be a cell"):
        gym.make("icprl/DarkRoom-v0", goal=[-1, 0])


# --- Meta-World Reach (MuJoCo; no display needed for state observations) ------------------------------


def test_reach_make_passes_gymnasiums_check_env():
    env = gym.make("icprl/MetaWorldReach-v0", goal=REACH_GOAL, horizon=10)
    assert env.unwrapped.goals.tolist() == [REACH_GOAL]
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
    messages = _check_env_quietly(env)
    # the only remarks: the unbounded observation Box, as metaworld's own (its object slots are ±inf)
    assert all("infinity" in m for m in messages), messages
    obs, _ = env.reset(seed=2)
    assert not obs[36:39].any()  # the goal is hidden


def test_reach_make_vec_is_the_projects_batched_env_and_a_seed_fixes_it():
    goals = [REACH_GOAL, [0.05, 0.8, 0.1]]
    with gym.make_vec("icprl/MetaWorldReach-v0", num_envs=2, goals=goals, horizon=3, num_workers=0) as envs:
        assert type(envs).__name__ == "ReachVectorEnv"
        assert envs.metadata["autoreset_mode"] is gym.vector.AutoresetMode.DISABLED
        assert envs.single_observation_space.shape == (39,) and envs.observation_space.shape == (2, 39)
        assert envs.single_action_space.shape == (4,) and envs.action_space.shape == (2, 4)
        actions = np.random.default_rng(0).uniform(-1, 1, size=(3, 2, 4)).astype(np.float32)
        runs = []
        for _ in range(2):
            obs, _ = envs.reset(seed=7)
            steps = [envs.step(a) for a in actions]
            runs.append([obs] + [x for s in steps for x in s[:4]])
        assert all(np.array_equal(a, b) for a, b in zip(*runs, strict=True))
        assert steps[-1][3].all() and not steps[0][3].any()
        assert not np.array_equal(envs.reset(seed=8)[0], runs[0][0])  # another seed, other puck positions


def test_reach_vector_refuses_a_visible_goal():
    with pytest.raises(ValueError, match="icprl/MetaWorldReach-v0: goal_visible=True is for the single env"):
        gym.make_vec("icprl/MetaWorldReach-v0", num_envs=2, goal=REACH_GOAL, goal_visible=True, num_workers=0)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"goals": [REACH_GOAL]}, r"num_envs is 2 but goals has 1 rows .*pass num_envs=1"),
    ({"goals": [REACH_GOAL] * 3}, r"num_envs is 2 but goals has 3 rows .*pass num_envs=3"),
    ({"goal": [0.0, np.nan, 0.2]}, "finite points"),
])
def test_reach_vector_kwargs_are_checked(kwargs, message):
    with pytest.raises(ValueError, match=f"icprl/MetaWorldReach-v0: .*{message}"):
        gym.make_vec("icprl/MetaWorldReach-v0", num_envs=2, num_workers=0, **kwargs)


def test_a_partial_reset_is_refused():
    envs = gym.make_vec("icprl/DarkRoom-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        goals=np.array([[1, 2], [3, 4]]))
    with pytest.raises(ValueError, match="reset_mask"):
        envs.reset(options={"reset_mask": np.ones(2, bool)})
