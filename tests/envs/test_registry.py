"""Every registered task passes the same conformance checks (in the spirit of dm_control's suite_test)."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from hrtc.errors import UnknownNameError

TASKS = [name for name in envs.names() if not name.startswith("test_")]


def test_registry_lists_the_cartpole_tasks():
    assert {"cartpole_swingup", "cartpole_balance"} <= set(envs.names())


def test_unknown_task_names_the_valid_ones():
    with pytest.raises(UnknownNameError, match="valid tasks: .*cartpole_swingup"):
        envs.make("cartpol")


@pytest.mark.parametrize("task", TASKS)
def test_gymnasium_conformance(task):
    env = envs.make(task)
    check_env(env, skip_render_check=True)
    assert isinstance(env, gym.Env)
    assert env.observation_space.dtype == np.float32 and env.action_space.dtype == np.float32


@pytest.mark.parametrize("task", TASKS)
def test_observations_are_finite_and_match_the_space(task):
    env = envs.make(task)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(200):
        obs, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        assert obs.shape == env.observation_space.shape and np.all(np.isfinite(obs))
        assert np.isfinite(reward)


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_episode_different_seed_different_start(task):
    def rollout(seed):
        env = envs.make(task)
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for t in range(50):
            trace.append(env.step(np.array([np.sin(t / 5)], np.float32))[0])
        return np.stack(trace)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3)[0], rollout(4)[0])


@pytest.mark.parametrize("task", TASKS)
def test_time_limit_is_truncation_not_termination(task):
    env = envs.make(task, time_limit=0.1)  # 10 steps of 0.01 s
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, np.float32))[2:4] for _ in range(10)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])


@pytest.mark.parametrize("task", TASKS)
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
