"""The pendulum's skills on the real dm_control pendulum: the model against MuJoCo, energy pumping (partial), the
LinearMPC balance (partial), the NMPC that swings up and balances alone, each skill through check_skill."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest

import envs
from hrtc.check import check_skill, task_states
from hrtc.errors import ConfigError, ShapeError
from skills.lqr_mpc import LinearMPC, finite_difference_transition, linearize
from skills.nmpc import UprightMPC
from skills.pendulum_model import PendulumParams
from skills.swingup import PendulumEnergySwingUp
from tests.skills.conftest import filtered_state

DT = 0.02  # s per env step
UPRIGHT_BAND = np.deg2rad(8.0)  # rad, where the task rewards


@pytest.fixture
def pendulum() -> Any:
    env = envs.make("pendulum_swingup")
    env.reset(seed=0)
    yield env
    env.close()


@pytest.fixture(scope="module")
def params() -> PendulumParams:
    return PendulumParams.from_mj_model(envs.mj_model("pendulum_swingup"))


def set_state(env: Any, theta: float, theta_dot: float) -> None:
    """A fresh episode (dm_control would restart one that reached its time limit on the next step) at this state."""
    env.reset(seed=0)
    physics = env.unwrapped.physics
    with physics.reset_context():
        physics.data.qpos[:] = theta
        physics.data.qvel[:] = theta_dot


def rollout(env: Any, skill: Any, theta: float, theta_dot: float, steps: int, every: int = 1) -> dict[str, np.ndarray]:
    set_state(env, theta, theta_dot)
    skill.reset(np.random.default_rng(0))
    angle, velocity, solve_ms = np.empty(steps), np.empty(steps), []
    for t in range(steps):
        if t % every == 0:
            out = skill.act(filtered_state(env, skill.state_keys))
            solve_ms.append(out.info.get("solve_ms", 0.0))
        env.step(out.action)
        s = env.unwrapped.skill_state()
        angle[t], velocity[t] = s["pole_angle"][0], s["pole_angular_velocity"][0]
    return {"angle": angle, "velocity": velocity, "solve_ms": np.array(solve_ms)}


def test_parameters_and_equations_are_mujocos(params: PendulumParams) -> None:
    model = envs.mj_model("pendulum_swingup")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    upright_energy = data.energy.sum()
    rng = np.random.default_rng(0)
    for _ in range(10):
        data.qpos[:], data.qvel[:], data.ctrl[:] = rng.uniform(-np.pi, np.pi), rng.uniform(-8, 8), rng.uniform(-1, 1)
        mujoco.mj_forward(model, data)
        assert params.acceleration(data.qpos[0], data.qvel[0], data.ctrl[0]) == pytest.approx(data.qacc[0], abs=1e-9)
        energy = data.energy.sum() - upright_energy  # the model enables MuJoCo's energy computation
        assert params.energy(data.qpos[0], data.qvel[0]) == pytest.approx(energy, abs=1e-9)
    assert params.gear * params.control_max < 0.25 * params.mass * params.gravity * params.com_length  # must pump


def test_swingup_raises_the_energy_to_upright_level_from_hanging_but_does_not_hold_it(
    pendulum: Any, params: PendulumParams
) -> None:
    skill = PendulumEnergySwingUp()
    r = rollout(pendulum, skill, np.pi - 0.01, 0.0, 1000)
    energy = params.energy(r["angle"], r["velocity"])
    tolerance = 0.05 * params.swing_energy
    reached = np.flatnonzero(np.abs(energy) < tolerance)
    assert reached.size and reached[0] * DT < 10.0, "the upright energy level within 10 s of hanging"
    assert np.all(np.abs(energy[-250:]) < tolerance)  # and it stays there
    assert np.mean(np.abs(r["angle"]) < UPRIGHT_BAND) < 0.1  # partial: it creeps past upright, nothing holds it
    print(f"\npendulum swing-up: |E| < {tolerance:.2f} J after {reached[0] * DT:.2f} s from hanging")


def test_balance_holds_perturbed_upright_states_for_1000_steps(pendulum: Any) -> None:
    skill = LinearMPC("pendulum_swingup", hinge_error="wrap", q_diag=[10.0, 1.0], r=0.1)
    rng = np.random.default_rng(1)
    for _ in range(5):
        r = rollout(pendulum, skill, rng.uniform(-0.08, 0.08), rng.uniform(-0.15, 0.15), 1000)
        assert np.all(np.abs(r["angle"][-500:]) < 0.01)
        assert np.all(np.abs(r["angle"]) < 0.3)
    print(f"\npendulum balance: OSQP median {np.median(r['solve_ms']):.3f} ms")


def test_balance_cannot_swing_up(pendulum: Any) -> None:
    skill = LinearMPC("pendulum_swingup", hinge_error="wrap", q_diag=[10.0, 1.0], r=0.1)
    r = rollout(pendulum, skill, np.pi - 0.05, 0.0, 500)
    assert np.all(np.abs(r["angle"]) > np.pi / 2)


def test_linearisation_matches_finite_differences_of_mj_step() -> None:
    """The Euler model goes through mjd_transitionFD; our own central differences of mj_step must agree."""
    model = envs.mj_model("pendulum_swingup")
    zero = np.zeros(1)
    A, B, drift = linearize(model, zero, zero, zero)
    A_fd, B_fd = finite_difference_transition(model, zero, zero, zero, eps=1e-5)
    np.testing.assert_allclose(A, A_fd, atol=1e-6)
    np.testing.assert_allclose(B, B_fd, atol=1e-6)
    np.testing.assert_allclose(drift, 0.0, atol=1e-12)
    assert np.max(np.abs(np.linalg.eigvals(A))) > 1.0  # upright is unstable


def test_nmpc_swings_up_and_balances_alone(pendulum: Any) -> None:
    skill = UprightMPC("pendulum_swingup", dt=0.04, horizon=40)
    r = rollout(pendulum, skill, np.pi - 0.01, 0.0, 1000, every=2)
    inside = np.abs(r["angle"]) < UPRIGHT_BAND
    first = int(np.argmax(inside))
    assert inside.any() and first * DT < 10.0
    assert np.all(inside[first + 100 :]), "held within 8 degrees once there"
    print(f"\npendulum NMPC: upright after {first * DT:.2f} s; solve median {np.median(r['solve_ms']):.2f} ms, "
          f"p99 {np.percentile(r['solve_ms'], 99):.2f} ms")  # fmt: skip


def test_every_skill_passes_check_skill() -> None:
    env = envs.make("pendulum_swingup")
    states = task_states(env, n=100)
    skills = [PendulumEnergySwingUp(), LinearMPC("pendulum_swingup", hinge_error="wrap"), UprightMPC(horizon=20)]
    for skill in skills:
        check_skill(skill, states, env.action_space)


def test_bad_input() -> None:
    with pytest.raises(ShapeError):
        PendulumEnergySwingUp().act(np.zeros(3))
    with pytest.raises(ShapeError):
        UprightMPC(horizon=5).act(np.zeros(4))
    with pytest.raises(ConfigError):
        PendulumEnergySwingUp(model="cartpole_swingup")
    with pytest.raises(ConfigError):
        PendulumEnergySwingUp(gain=0.0)
    with pytest.raises(ConfigError):
        UprightMPC(model="cartpole_swingup")
    with pytest.raises(ConfigError):
        UprightMPC(horizon=0)
    assert np.all(np.isfinite(PendulumEnergySwingUp().act(np.array([np.nan, 0.0])).action))
    assert np.all(np.isfinite(UprightMPC(horizon=5).act(np.array([np.nan, 0.0])).action))


def test_the_untrained_blend_reaches_upright_from_hanging() -> None:
    """Where a fresh Beta meta-policy starts (every weight 0.5) must earn some reward, or an off-policy learner sees
    none to learn from: with the balance's angle error as sin it damped every blend's swing and this scored 0."""
    from hrtc.cli import task_config
    from hrtc.environments import make_env

    task = task_config("pendulum_swingup")
    env = make_env("pendulum_swingup", "hrtc", task["skills"], decision_every=2)  # the task's decision rate
    env.reset(seed=1001002)  # starts 2.95 rad from upright, at rest
    assert abs(env.unwrapped.skill_state()["pole_angle"][0]) > 2.9
    total, done = 0.0, False
    while not done:
        _, reward, terminated, truncated, _ = env.step(np.full(len(env.skill_names), 0.5))
        total, done = total + reward, terminated or truncated
    env.close()
    assert total > 200.0, f"the untrained blend scored {total:.0f} from hanging"
