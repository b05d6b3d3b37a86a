"""Every registered task passes the same conformance checks (in the spirit of dm_control's suite_test)."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from hrtc.errors import UnknownNameError

TASKS = [name for name in envs.names() if not name.startswith("test_")]
CARTPOLES = [name for name in TASKS if name.startswith("cartpole")]  # dm_control cart-poles: time limits, physics
DM_CONTROL = [*CARTPOLES, "acrobot_swingup", "pendulum_swingup"]  # the tasks through envs.dm_control_env


def _actions(env, n, seed=0):
    """``n`` actions spread over the task's action space (a fixed sequence for a seed)."""
    space = env.action_space
    rng = np.random.default_rng(seed)
    return [rng.uniform(space.low, space.high).astype(space.dtype) for _ in range(n)]


def test_registry_lists_the_dm_control_tasks():
    assert {"cartpole_swingup", "cartpole_balance", "acrobot_swingup", "pendulum_swingup"} <= set(envs.names())


def test_unknown_task_names_the_valid_ones():
    with pytest.raises(UnknownNameError, match="valid tasks: .*cartpole_swingup"):
        envs.make("cartpol")


@pytest.mark.parametrize("task", TASKS)
def test_gymnasium_conformance(task):
    env = envs.make(task)
    check_env(env, skip_render_check=True)
    assert isinstance(env, gym.Env)
    assert isinstance(env.action_space, gym.spaces.Box) and env.action_space.dtype == np.float32
    assert env.observation_space.dtype in (np.float32, np.uint8)  # vectors, or pixels (carracing)


@pytest.mark.parametrize("task", TASKS)
def test_observations_are_finite_and_match_the_space(task):
    env = envs.make(task)
    obs, _ = env.reset(seed=0)
    for action in _actions(env, 200):
        obs, reward, terminated, truncated, _ = env.step(action)
        assert obs.shape == env.observation_space.shape and np.all(np.isfinite(obs))
        assert np.isfinite(reward)
        if terminated or truncated:
            obs, _ = env.reset(seed=1)


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_episode_different_seed_different_start(task):
    def rollout(seed):
        env = envs.make(task)
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for action in _actions(env, 50):
            obs, _, terminated, truncated, _ = env.step(action)
            trace.append(obs)
            if terminated or truncated:
                break
        return np.stack(trace)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3)[0], rollout(4)[0])


@pytest.mark.parametrize("task", DM_CONTROL)
def test_time_limit_is_truncation_not_termination(task):
    env = envs.make(task)
    env = envs.make(task, time_limit=10 * env.unwrapped.dt)  # 10 steps
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, np.float32))[2:4] for _ in range(10)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])


@pytest.mark.parametrize("task", TASKS)
def test_skill_state_is_named_finite_arrays(task):
    env = envs.make(task)
    env.reset(seed=0)
    for action in _actions(env, 5):
        env.step(action)
        state = env.unwrapped.skill_state()
        assert state and all(isinstance(k, str) for k in state)
        assert all(isinstance(v, np.ndarray) and np.all(np.isfinite(v)) for v in state.values())


@pytest.mark.parametrize("task", CARTPOLES)
def test_skill_state_names_physical_quantities(task):
    env = envs.make(task)
    env.reset(seed=0)
    state = env.unwrapped.skill_state()
    physics = env.unwrapped.physics
    np.testing.assert_array_equal(state["qpos"], physics.data.qpos)
    np.testing.assert_array_equal(state["cart_position"], physics.data.qpos[:1])
    angle = state["pole_angle"][0]
    assert -np.pi < angle <= np.pi
    assert np.cos(angle) == pytest.approx(physics.named.data.xmat["pole_1", "zz"], abs=1e-9)


def test_swingup_starts_hanging_balance_starts_upright():
    down = envs.make("cartpole_swingup")
    down.reset(seed=0)
    up = envs.make("cartpole_balance")
    up.reset(seed=0)
    assert abs(down.unwrapped.skill_state()["pole_angle"][0]) > 3.0
    assert abs(up.unwrapped.skill_state()["pole_angle"][0]) < 0.05


def test_render_gives_an_rgb_frame():
    env = envs.make("cartpole_swingup", render_size=(48, 64))
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0
    env.close()


def test_acrobot_state_names_physical_quantities():
    env = envs.make("acrobot_swingup")
    physics = env.unwrapped.physics
    for seed in range(5):
        env.reset(seed=seed)
        for action in _actions(env, 20, seed):
            env.step(action)
        state = env.unwrapped.skill_state()
        q1, q2 = state["shoulder_angle"][0], state["elbow_angle"][0]
        assert -np.pi < q1 <= np.pi and -np.pi < q2 <= np.pi
        # the links' world z axes: upper at q1 from upright, lower at q1 + q2 (both hinges about +y)
        assert np.cos(q1) == pytest.approx(physics.named.data.xmat["upper_arm", "zz"], abs=1e-9)
        assert np.sin(q1) == pytest.approx(physics.named.data.xmat["upper_arm", "xz"], abs=1e-9)
        assert np.sin(q1 + q2) == pytest.approx(physics.named.data.xmat["lower_arm", "xz"], abs=1e-9)
        np.testing.assert_array_equal(state["shoulder_velocity"], physics.data.qvel[:1])
        np.testing.assert_array_equal(state["elbow_velocity"], physics.data.qvel[1:])
        tip = np.array([np.sin(q1) + np.sin(q1 + q2), 2.0 + np.cos(q1) + np.cos(q1 + q2)])  # (x, z), m
        assert state["tip_distance"][0] == pytest.approx(np.hypot(tip[0], tip[1] - 4.0), abs=1e-9)


def test_pendulum_state_names_physical_quantities():
    env = envs.make("pendulum_swingup")
    physics = env.unwrapped.physics
    for seed in range(5):
        env.reset(seed=seed)
        for action in _actions(env, 20, seed):
            env.step(action)
        state = env.unwrapped.skill_state()
        angle = state["pole_angle"][0]
        assert -np.pi < angle <= np.pi
        assert np.cos(angle) == pytest.approx(physics.named.data.xmat["pole", "zz"], abs=1e-9)
        assert np.sin(angle) == pytest.approx(physics.named.data.xmat["pole", "xz"], abs=1e-9)
        np.testing.assert_array_equal(state["pole_angular_velocity"], physics.data.qvel)


@pytest.mark.parametrize("task", ["acrobot_swingup", "pendulum_swingup"])
def test_swingup_tasks_start_at_random_angles_at_rest(task):
    env = envs.make(task)
    starts = []
    for seed in range(20):
        env.reset(seed=seed)
        starts.append(env.unwrapped.physics.data.qpos.copy())
        np.testing.assert_array_equal(env.unwrapped.physics.data.qvel, 0.0)
    starts = np.array(starts)
    assert np.all(np.abs(starts) <= np.pi) and np.ptp(starts[:, 0]) > np.pi  # spread over the circle
