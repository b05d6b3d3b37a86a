"""The cart-pole variants: own rewards that measure what they claim, and physics edits that change the pole."""

from __future__ import annotations

import numpy as np
import pytest

import envs
from envs.cartpole_variants import UPRIGHT_START_ANGLE, UPRIGHT_START_SPEED, cartpole_xml
from hrtc.errors import ConfigError
from skills.cartpole_model import CartpoleParams


def _set(env, x: float, theta: float, theta_dot: float = 0.0) -> None:
    physics = env.unwrapped.physics
    with physics.reset_context():
        physics.data.qpos[:] = [x, theta]
        physics.data.qvel[:] = [0.0, theta_dot]


def _reward(env) -> float:
    return float(env.unwrapped._env.task.get_reward(env.unwrapped.physics))


def test_energy_reward_is_zero_hanging_one_upright_and_counts_speed():
    env = envs.make("cartpole_energy")
    env.reset(seed=0)
    _set(env, 0.0, np.pi)
    assert _reward(env) == pytest.approx(0.0, abs=1e-9)
    _set(env, 0.0, 0.0)
    assert _reward(env) == pytest.approx(1.0)
    # Horizontal and still: half the swing's energy; moving fast enough to reach upright: full reward.
    _set(env, 0.0, np.pi / 2)
    assert _reward(env) == pytest.approx(0.5, abs=1e-6)
    p = CartpoleParams.from_mj_model(env.unwrapped.physics.model.ptr)
    speed = np.sqrt(2 * p.pole_mass * p.gravity * p.com_length / p.hinge_inertia)  # E = 0 at horizontal
    _set(env, 0.0, np.pi / 2, speed)
    assert _reward(env) == pytest.approx(1.0, abs=1e-6)


def test_upright_reward_peaks_upright_and_starts_near_it():
    env = envs.make("cartpole_upright")
    for seed in range(20):
        env.reset(seed=seed)
        state = env.unwrapped.skill_state()
        assert abs(state["pole_angle"][0]) <= UPRIGHT_START_ANGLE
        assert abs(state["pole_angular_velocity"][0]) <= UPRIGHT_START_SPEED
    _set(env, 0.0, 0.0)
    assert _reward(env) == pytest.approx(1.0)
    _set(env, 0.0, 0.25)
    assert _reward(env) == pytest.approx(np.exp(-0.5), abs=1e-9)
    _set(env, 0.0, np.pi)
    assert _reward(env) < 1e-6


@pytest.mark.parametrize(
    "task,mass,com", [("cartpole_swingup", 0.1, 0.5), ("cartpole_swingup_heavy", 0.3, 0.5),
                      ("cartpole_swingup_long", 0.1, 0.75)],
)  # fmt: skip
def test_changed_physics_changes_only_the_pole(task, mass, com):
    p = CartpoleParams.from_mj_model(envs.mj_model(task))
    assert p.pole_mass == pytest.approx(mass) and p.com_length == pytest.approx(com)
    assert p.cart_mass == pytest.approx(1.0) and p.gear == pytest.approx(10.0)
    env = envs.make(task)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (5,) and abs(abs(env.unwrapped.skill_state()["pole_angle"][0]) - np.pi) < 0.1  # hanging


def test_scales_are_keyword_arguments_and_are_checked():
    assert CartpoleParams.from_mj_model(
        envs.mj_model(envs.make("cartpole_swingup_heavy", pole_mass_scale=2.0).unwrapped.physics.model.ptr)
    ).pole_mass == pytest.approx(0.2)
    with pytest.raises(ConfigError, match="pole_length_scale must lie in"):
        cartpole_xml(pole_length_scale=0.0)
