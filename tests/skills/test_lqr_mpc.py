"""LinearMPC: the linearisation against MuJoCo itself, balance on the real cart-pole, bounds, failures, generality."""

from __future__ import annotations

import copy
from typing import Any

import mujoco
import numpy as np
import pytest

import envs
from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import Skill
from skills.lqr_mpc import (
    STATUS_NONFINITE_STATE,
    STATUS_NOT_CONVERGED,
    STATUS_OK,
    LinearMPC,
    finite_difference_transition,
    linearize,
)
from tests.skills.conftest import filtered_state, set_cartpole_state

STEPS = 1000  # one episode of 0.01 s steps
RAIL = 1.8  # m
UPRIGHT_BAND = 0.2  # rad

# A point mass on a plane: two slide joints, two bounded motors, Euler integration (mjd_transitionFD's path).
POINT_MASS_XML = """
<mujoco>
  <option timestep="0.01" integrator="Euler"/>
  <worldbody>
    <body name="mass">
      <joint name="x" type="slide" axis="1 0 0" damping="0.1"/>
      <joint name="y" type="slide" axis="0 1 0" damping="0.1"/>
      <geom type="sphere" size="0.05" mass="1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="x" gear="2" ctrlrange="-1 1" ctrllimited="true"/>
    <motor joint="y" gear="2" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
</mujoco>
"""

_solve_ms: list[float] = []  # every balance solve in this module, for the timing report


@pytest.fixture(scope="module")
def mpc() -> LinearMPC:
    return LinearMPC()


def test_is_a_skill(mpc: LinearMPC) -> None:
    assert isinstance(mpc, Skill)
    assert mpc.state_keys == ("qpos", "qvel")


def test_linearisation_shapes_and_upright_is_an_unstable_equilibrium(mpc: LinearMPC) -> None:
    A, B, drift = mpc.linearization
    assert A.shape == (4, 4) and B.shape == (4, 1) and drift.shape == (4,)
    np.testing.assert_allclose(drift, 0.0, atol=1e-12)  # upright at rest, zero control: an equilibrium
    assert np.max(np.abs(np.linalg.eigvals(A))) > 1.0  # the inverted pole is open-loop unstable
    closed_loop = A - B @ mpc.lqr_gain
    assert np.max(np.abs(np.linalg.eigvals(closed_loop))) < 1.0  # the LQR law stabilises the linear model


def test_one_predicted_step_matches_mujoco(cartpole: Any, mpc: LinearMPC) -> None:
    """x_next = A x + B u for a tiny perturbation of upright, against the env's actual RK4 step."""
    A, B, drift = mpc.linearization
    rng = np.random.default_rng(0)
    cartpole.reset(seed=0)
    for _ in range(5):
        dx = 1e-4 * rng.normal(size=4)
        du = 1e-3 * rng.normal(size=1)
        set_cartpole_state(cartpole, dx[:2], dx[2:])
        cartpole.step(du)
        actual = mpc.error(filtered_state(cartpole, mpc.state_keys))
        predicted = A @ dx + B @ du + drift
        # second-order remainder: ~|dx|^2, far below the first-order change |x_next - x| ~ 1e-4
        assert np.linalg.norm(predicted - actual) < 1e-3 * np.linalg.norm(actual - dx)
        assert np.linalg.norm(predicted - actual) < 1e-7


def test_rk4_finite_differences_agree_with_mjd_transitionFD() -> None:
    """The hand-made central differences (needed for RK4) equal MuJoCo's on a model mjd_transitionFD accepts."""
    model = copy.copy(envs.mj_model("cartpole_swingup"))
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    qpos, qvel, ctrl = np.array([0.2, 0.4]), np.array([0.3, -1.0]), np.array([0.5])
    A_ours, B_ours = finite_difference_transition(model, qpos, qvel, ctrl)
    A_mj, B_mj, _ = linearize(model, qpos, qvel, ctrl)
    np.testing.assert_allclose(A_ours, A_mj, atol=1e-7)
    np.testing.assert_allclose(B_ours, B_mj, atol=1e-7)


def test_zero_action_at_upright_and_hinge_angles_are_wrapped(mpc: LinearMPC) -> None:
    mpc.reset(np.random.default_rng(0))
    out = mpc.act(np.zeros(4))
    assert out.info["status"] == STATUS_OK
    assert out.action.shape == (1,) and out.action.dtype == np.float64
    assert abs(out.action[0]) < 1e-9
    assert abs(mpc.act(np.array([0.0, 2.0 * np.pi, 0.0, 0.0])).action[0]) < 1e-9
    tilted = mpc.act(np.array([0.1, 0.05, 0.0, 0.0])).action
    wrapped = mpc.act(np.array([0.1, 0.05 - 4.0 * np.pi, 0.0, 0.0])).action
    np.testing.assert_allclose(tilted, wrapped, atol=1e-6)
    assert tilted[0] > 0.0  # the pole leans to +x: the cart goes under it


def test_without_active_bounds_the_mpc_is_the_lqr_law() -> None:
    """With the DARE terminal cost, the unconstrained finite-horizon optimum is the infinite-horizon LQR control."""
    model = copy.copy(envs.mj_model("cartpole_swingup"))
    model.actuator_ctrlrange[:] = (-1e3, 1e3)
    mpc = LinearMPC(model, eps_abs=1e-8, eps_rel=1e-8, max_iter=4000)
    rng = np.random.default_rng(1)
    for _ in range(5):
        state = np.concatenate([rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.5, 0.5, 2)])
        out = mpc.act(state)
        assert out.info["status"] == STATUS_OK
        np.testing.assert_allclose(out.action, -mpc.lqr_gain @ mpc.error(state), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("hinge_error", ["wrap", "sin"])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_balances_from_perturbed_upright(cartpole: Any, seed: int, hinge_error: str) -> None:
    mpc = LinearMPC(hinge_error=hinge_error)  # "sin" is what the cartpole_swingup task uses
    rng = np.random.default_rng(seed)
    cartpole.reset(seed=seed)
    mpc.reset(rng)
    side = rng.choice([-1.0, 1.0])
    qpos = (rng.uniform(-0.5, 0.5), side * 0.15)
    qvel = (rng.uniform(-0.3, 0.3), side * rng.uniform(0.0, 0.3))  # falling further at first
    set_cartpole_state(cartpole, qpos, qvel)
    angles, carts, actions, status = (np.empty(STEPS) for _ in range(4))
    for t in range(STEPS):
        out = mpc.act(filtered_state(cartpole, mpc.state_keys))
        _solve_ms.append(out.info["solve_ms"])
        _, _, terminated, truncated, _ = cartpole.step(out.action)
        s = cartpole.unwrapped.skill_state()
        angles[t], carts[t], actions[t], status[t] = (
            s["pole_angle"][0],
            s["cart_position"][0],
            out.action[0],
            out.info["status"],
        )
        assert np.isfinite(out.info["cost"]) and out.info["iterations"] >= 1
        assert not terminated and (t == STEPS - 1) == truncated
    assert np.all(np.abs(angles) < UPRIGHT_BAND)
    assert np.all(np.abs(carts) < RAIL)
    assert np.all(np.abs(actions) <= 1.0)
    assert np.all(status == STATUS_OK)
    assert np.max(np.abs(actions)) == pytest.approx(1.0)  # the bounds were active: a constrained problem
    assert abs(angles[-1]) < 1e-3 and abs(carts[-1]) < 1e-2  # settled at the reference
    times = np.asarray(_solve_ms)
    print(
        f"\nLinearMPC seed {seed}: max |angle| {np.max(np.abs(angles)):.3f} rad, "
        f"max |x| {np.max(np.abs(carts)):.2f} m; "
        f"solve ms over {times.size} solves so far: median {np.median(times):.3f}, p99 {np.percentile(times, 99):.3f}"
    )


def test_sin_hinge_error_is_continuous_and_vanishes_hanging() -> None:
    mpc = LinearMPC(hinge_error="sin")
    for angle in (0.1, -0.4, 2.0):
        assert mpc.error(np.array([0.3, angle, 0.5, -1.0]))[1] == pytest.approx(np.sin(angle))
    # Either side of hanging the error is about 0, where the wrapped error jumps from +pi to -pi.
    near_pi = [mpc.error(np.array([0.0, np.pi + d, 0.0, 0.0]))[1] for d in (-1e-3, 1e-3)]
    assert np.allclose(near_pi, 0.0, atol=2e-3)


def test_cannot_swing_up_from_hanging(cartpole: Any, mpc: LinearMPC) -> None:
    cartpole.reset(seed=0)
    mpc.reset(np.random.default_rng(0))
    near_upright = 0
    for _ in range(STEPS):
        out = mpc.act(filtered_state(cartpole, mpc.state_keys))
        assert np.all(np.isfinite(out.action)) and np.all(np.abs(out.action) <= 1.0)
        cartpole.step(out.action)
        near_upright += abs(cartpole.unwrapped.skill_state()["pole_angle"][0]) < UPRIGHT_BAND
    assert near_upright / STEPS < 0.05


def test_solver_failure_falls_back_to_the_clipped_lqr_law() -> None:
    mpc = LinearMPC(max_iter=1)
    for state in (np.array([0.0, 0.01, 0.0, 0.0]), np.array([0.3, 0.15, 0.5, 0.4])):
        out = mpc.act(state)
        assert out.info["status"] == STATUS_NOT_CONVERGED
        assert out.info["osqp_status"] != 1.0
        assert np.all(np.isfinite(out.action)) and np.isfinite(out.info["cost"])
        np.testing.assert_allclose(out.action, np.clip(-mpc.lqr_gain @ mpc.error(state), -1.0, 1.0))


def test_non_finite_state_gives_the_reference_control(mpc: LinearMPC) -> None:
    out = mpc.act(np.array([0.0, np.nan, 0.0, 0.0]))
    assert out.info["status"] == STATUS_NONFINITE_STATE
    np.testing.assert_array_equal(out.action, [0.0])
    assert mpc.act(np.zeros(4)).info["status"] == STATUS_OK  # and the next solve is unaffected


def test_rejects_a_wrongly_shaped_state(mpc: LinearMPC) -> None:
    with pytest.raises(ShapeError):
        mpc.act(np.zeros(3))


def test_any_model_with_several_actuators_and_a_shifted_reference() -> None:
    """A 2-actuator point mass regulated to qpos_ref = (0.3, -0.2) m, with bounded controls."""
    model = mujoco.MjModel.from_xml_string(POINT_MASS_XML)
    data = mujoco.MjData(model)
    mpc = LinearMPC(model, qpos_ref=[0.3, -0.2], horizon=20, q_diag=[10.0, 10.0, 1.0, 1.0], r=0.1)
    assert mpc.linearization.B.shape == (4, 2)
    saturated = False
    for _ in range(400):
        out = mpc.act(np.concatenate([data.qpos, data.qvel]))
        assert out.action.shape == (2,) and out.info["status"] == STATUS_OK
        assert np.all(np.abs(out.action) <= 1.0)
        saturated |= bool(np.any(np.abs(out.action) > 1.0 - 1e-6))
        data.ctrl[:] = out.action
        mujoco.mj_step(model, data)
    assert saturated
    np.testing.assert_allclose(data.qpos, [0.3, -0.2], atol=1e-3)
    np.testing.assert_allclose(data.qvel, 0.0, atol=1e-3)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"horizon": 0},
        {"horizon": 2.5},
        {"r": 0.0},
        {"r": [0.1, 0.1]},
        {"q_diag": [1.0, 1.0]},
        {"q_diag": [1.0, -1.0, 1.0, 1.0]},
        {"qpos_ref": [0.0]},
        {"qvel_ref": [np.nan, 0.0]},
        {"ctrl_ref": [2.0]},
        {"eps": 0.0},
        {"max_iter": 0},
    ],
)
def test_rejects_bad_arguments(kwargs: dict[str, Any]) -> None:
    with pytest.raises(ConfigError):
        LinearMPC(**kwargs)


def test_rejects_a_model_without_actuators() -> None:
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint/><geom size='0.1'/></body></worldbody></mujoco>"
    )
    with pytest.raises(ConfigError, match="no actuators"):
        LinearMPC(model)
