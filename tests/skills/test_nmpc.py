"""CartTrackingMPC on the real dm_control cart-pole: tracking, bounds, model fidelity, warm starts, failures.

The skill is re-solved every 5 env steps (its dt of 0.05 s over the env's 0.01 s) and its action held in between.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np
import pytest

import envs
from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from hrtc.skill import Skill
from skills.nmpc import STATUS_NONFINITE_STATE, STATUS_OK, CartTrackingMPC

ENV_DT = 0.01  # s per env step
HOLD = 5  # env steps per MPC solve: 0.05 s / 0.01 s
TOLERANCE = 0.05  # m, the band the cart must settle into


def filtered_state(env: Any, skill: CartTrackingMPC) -> np.ndarray:
    s = env.unwrapped.skill_state()
    return np.concatenate([np.atleast_1d(s[k]) for k in skill.state_keys])


def set_physics_state(env: Any, x: float, theta: float, x_dot: float = 0.0, theta_dot: float = 0.0) -> None:
    physics = env.unwrapped.physics
    with physics.reset_context():
        physics.data.qpos[:] = (x, theta)
        physics.data.qvel[:] = (x_dot, theta_dot)


class Rollout(NamedTuple):
    states: np.ndarray  # (T, 4) filtered state after each env step
    actions: np.ndarray  # (S,) one per solve
    solve_ms: np.ndarray  # (S,)
    status: np.ndarray  # (S,)
    iterations: np.ndarray  # (S,)
    solve_states: np.ndarray  # (S, 4) the state each solve started from


def run(env: Any, skill: CartTrackingMPC, steps: int) -> Rollout:
    """Closed loop for ``steps`` env steps, re-solving every ``HOLD`` steps."""
    states, actions, ms, status, iters, solve_states = [], [], [], [], [], []
    action = np.zeros(1)
    for i in range(steps):
        if i % HOLD == 0:
            state = filtered_state(env, skill)
            out = skill.act(state)
            action = out.action
            solve_states.append(state)
            actions.append(float(action[0]))
            ms.append(out.info["solve_ms"])
            status.append(out.info["status"])
            iters.append(out.info["iterations"])
        env.step(action)
        states.append(filtered_state(env, skill))
    return Rollout(*(np.asarray(a) for a in (states, actions, ms, status, iters, solve_states)))


def settle_time(positions: np.ndarray, x_ref: float, tolerance: float = TOLERANCE) -> float:
    """Seconds until the cart enters the band ``|x - x_ref| <= tolerance`` for good (inf if it ends outside)."""
    outside = np.nonzero(np.abs(positions - x_ref) > tolerance)[0]
    if len(outside) == 0:
        return 0.0
    if outside[-1] == len(positions) - 1:
        return float("inf")
    return (outside[-1] + 1) * ENV_DT


@pytest.fixture(scope="module")
def env() -> Iterator[Any]:
    e = envs.make("cartpole_swingup")
    yield e
    e.close()


@pytest.fixture(scope="module")
def tracking(env: Any) -> dict[float, Rollout]:
    """From the hanging rest state: x_ref = +0.5 m for 3 s, then -0.5 m for 3 s (one rollout, warm-started)."""
    skill = CartTrackingMPC()
    env.reset(seed=0)
    skill.reset(np.random.default_rng(0))
    rollouts = {}
    for x_ref in (0.5, -0.5):
        skill.set_reference(x_ref)
        rollouts[x_ref] = run(env, skill, 300)
    return rollouts


def test_is_a_skill() -> None:
    skill = CartTrackingMPC()
    assert isinstance(skill, Skill)
    assert skill.state_keys == ("cart_position", "pole_angle", "cart_velocity", "pole_angular_velocity")


@pytest.mark.parametrize(("x_ref", "max_settle_s"), [(0.5, 1.5), (-0.5, 2.0)])
def test_tracks_cart_reference(tracking: dict[float, Rollout], x_ref: float, max_settle_s: float) -> None:
    # measured: about 0.8 s to reach +0.5 m from rest, 1.1 s for the 1 m move to -0.5 m
    rollout = tracking[x_ref]
    assert np.all(rollout.status == STATUS_OK)
    positions = rollout.states[:, 0]
    t = settle_time(positions, x_ref)
    error_last_second = np.abs(positions[-100:] - x_ref).max()
    print(
        f"\nx_ref {x_ref:+.1f} m: within {TOLERANCE} m for good after {t:.2f} s; "
        f"last-second error {error_last_second:.4f} m"
    )
    assert t <= max_settle_s
    assert error_last_second < 0.01
    # no large overshoot past the reference on the far side
    direction = np.sign(x_ref - rollout.solve_states[0, 0])
    assert np.max(direction * (positions - x_ref)) < TOLERANCE


def test_returns_from_cart_offset(env: Any) -> None:
    skill = CartTrackingMPC(x_ref=0.0)
    env.reset(seed=1)
    set_physics_state(env, x=1.0, theta=np.pi)
    skill.reset(np.random.default_rng(0))
    rollout = run(env, skill, 300)
    positions = rollout.states[:, 0]
    t = settle_time(positions, 0.0)
    print(f"\nfrom x = 1.0 m back to 0: within {TOLERANCE} m for good after {t:.2f} s")
    assert np.all(rollout.status == STATUS_OK)
    assert t <= 2.0
    assert np.abs(positions[-100:]).max() < 0.01


def test_actions_bounded_finite_and_fast(tracking: dict[float, Rollout]) -> None:
    actions = np.concatenate([r.actions for r in tracking.values()])
    ms = np.concatenate([r.solve_ms for r in tracking.values()])
    assert np.all(np.isfinite(actions))
    assert np.all((actions >= -1.0) & (actions <= 1.0))
    assert np.any(np.abs(actions) > 0.99)  # the steps saturate the motor: the bounds are active, not idle
    assert np.all(np.isfinite(ms)) and np.all(ms > 0.0)
    print(f"\nwarm-started solve_ms over {len(ms)} solves: median {np.median(ms):.3f}, p99 {np.percentile(ms, 99):.3f}")
    assert np.median(ms) < 20.0  # generous: about 0.4 ms measured


def test_cart_stays_inside_bounds(tracking: dict[float, Rollout]) -> None:
    skill = CartTrackingMPC()
    positions = np.concatenate([r.states[:, 0] for r in tracking.values()])
    assert np.all((positions > skill.position_min) & (positions < skill.position_max))


def test_partial_pole_stays_down(tracking: dict[float, Rollout], env: Any) -> None:
    # the pole is never penalised: the cart moves swing it, but it never rises above the horizontal
    states = np.concatenate([r.states for r in tracking.values()])
    assert np.all(np.cos(states[:, 1]) < 0.0)
    # alone for a whole episode at x_ref = 0 from hanging, it earns next to nothing of the swing-up reward
    skill = CartTrackingMPC()
    env.reset(seed=2)
    skill.reset(np.random.default_rng(0))
    rewards, action = [], np.zeros(1)
    for i in range(1000):
        if i % HOLD == 0:
            action = skill.act(filtered_state(env, skill)).action
        _, reward, _, _, _ = env.step(action)
        rewards.append(reward)
        assert np.cos(filtered_state(env, skill)[1]) < -0.9
    print(f"\nalone from hanging: return {sum(rewards):.1f} of 1000")


@pytest.mark.parametrize(
    "start",
    [
        (0.0, np.pi, 0.0, 0.0),
        (0.3, 2.5, 0.8, -1.5),
        (-1.2, 0.4, -1.0, 3.0),  # a pole near upright, falling: the most nonlinear case
        (0.5, -0.1, 0.0, 0.0),
    ],
)
@pytest.mark.parametrize("u", [-1.0, 0.3, 1.0])
def test_one_step_prediction_matches_mujoco(env: Any, start: tuple[float, ...], u: float) -> None:
    skill = CartTrackingMPC()
    x, theta, x_dot, theta_dot = start
    env.reset(seed=0)
    set_physics_state(env, x, theta, x_dot, theta_dot)
    for _ in range(HOLD):
        env.step(np.array([u]))
    qpos, qvel = env.unwrapped.physics.data.qpos, env.unwrapped.physics.data.qvel
    simulated = np.array([qpos[0], qpos[1], qvel[0], qvel[1]])  # unwrapped angle, as the model integrates it
    predicted = np.asarray(skill.step(np.array(start), u)).ravel()
    # RK4 at 0.05 s against MuJoCo's RK4 at 0.01 s: the same ODE, only the step differs (measured error < 2e-5)
    np.testing.assert_allclose(predicted, simulated, atol=1e-4, rtol=0)


def test_zero_action_when_at_reference_and_at_rest() -> None:
    skill = CartTrackingMPC(x_ref=0.3)
    out = skill.act(np.array([0.3, np.pi, 0.0, 0.0]))
    assert out.info["status"] == STATUS_OK
    assert abs(out.action[0]) < 1e-6
    assert out.info["cost"] < 1e-9


def test_warm_start_needs_fewer_iterations(tracking: dict[float, Rollout]) -> None:
    warm_iters = np.concatenate([r.iterations for r in tracking.values()])
    warm_ms = np.concatenate([r.solve_ms for r in tracking.values()])
    warm_actions = np.concatenate([r.actions for r in tracking.values()])
    cold = CartTrackingMPC()
    cold_iters, cold_ms, cold_actions = [], [], []
    for x_ref, rollout in tracking.items():
        cold.set_reference(x_ref)
        for state in rollout.solve_states:
            cold.reset(np.random.default_rng(0))
            out = cold.act(state)
            assert out.info["status"] == STATUS_OK
            cold_iters.append(out.info["iterations"])
            cold_ms.append(out.info["solve_ms"])
            cold_actions.append(out.action[0])
    print(
        f"\niterations: warm {warm_iters.mean():.2f}, cold {np.mean(cold_iters):.2f}; solve_ms median/p99: "
        f"warm {np.median(warm_ms):.3f}/{np.percentile(warm_ms, 99):.3f}, "
        f"cold {np.median(cold_ms):.3f}/{np.percentile(cold_ms, 99):.3f}"
    )
    assert warm_iters.mean() < 0.7 * np.mean(cold_iters)
    # both converge to the same optimum from the same states
    np.testing.assert_allclose(warm_actions, cold_actions, atol=1e-2)


def test_reset_clears_warm_start() -> None:
    skill = CartTrackingMPC(x_ref=0.5)
    state = np.array([0.0, np.pi, 0.0, 0.0])
    first = skill.act(state)
    assert skill.plan is not None
    skill.reset(np.random.default_rng(0))
    assert skill.plan is None
    again = skill.act(state)
    assert again.info["iterations"] == first.info["iterations"]
    np.testing.assert_allclose(again.action, first.action, atol=1e-9)


def test_unconverged_solve_falls_back_to_pd() -> None:
    # one SQP iteration cannot solve a 0.5 m step from a cold start (3-4 are needed)
    skill = CartTrackingMPC(x_ref=0.5, max_iter=1)
    out = skill.act(np.array([0.0, np.pi, 0.0, 0.0]))
    assert out.info["status"] != STATUS_OK
    assert np.all(np.isfinite(out.action)) and out.action.shape == (1,)
    assert -1.0 <= out.action[0] <= 1.0
    assert out.action[0] > 0.0  # the PD fallback pushes towards the reference


def test_infeasible_state_falls_back_within_bounds() -> None:
    # at 1.75 m and 3 m/s towards the rail, no control keeps the cart inside 1.7 m: the problem is infeasible
    skill = CartTrackingMPC()
    out = skill.act(np.array([1.75, np.pi, 3.0, 0.0]))
    assert out.info["status"] != STATUS_OK
    assert np.all(np.isfinite(out.action)) and -1.0 <= out.action[0] <= 1.0
    assert out.action[0] < 0.0  # brakes


def test_nonfinite_state_replays_previous_plan() -> None:
    skill = CartTrackingMPC(x_ref=0.5)
    skill.act(np.array([0.0, np.pi, 0.0, 0.0]))
    plan = skill.plan
    assert plan is not None
    for k in (1, 2):
        out = skill.act(np.array([np.nan, np.pi, 0.0, 0.0]))
        assert out.info["status"] == STATUS_NONFINITE_STATE
        assert out.action[0] == pytest.approx(plan[k])
    skill.reset(np.random.default_rng(0))
    out = skill.act(np.array([np.inf, np.nan, 0.0, 0.0]))  # no plan, no usable position: zero force
    assert out.info["status"] == STATUS_NONFINITE_STATE
    np.testing.assert_array_equal(out.action, [0.0])


def test_recovers_after_a_failure() -> None:
    skill = CartTrackingMPC(x_ref=0.5)
    skill.act(np.array([np.nan, np.pi, 0.0, 0.0]))
    out = skill.act(np.array([0.0, np.pi, 0.0, 0.0]))
    assert out.info["status"] == STATUS_OK


def test_set_reference_changes_the_target() -> None:
    skill = CartTrackingMPC()
    state = np.array([0.0, np.pi, 0.0, 0.0])
    skill.set_reference(0.5)
    assert skill.act(state).action[0] > 0.5
    skill.set_reference(-0.5)
    assert skill.act(state).action[0] < -0.5


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": float("nan")}, "dt"),
        ({"horizon": 0}, "horizon"),
        ({"horizon": 2.5}, "horizon"),
        ({"max_iter": 0}, "max_iter"),
        ({"w_velocity": -1.0}, "w_velocity"),
        ({"w_control": 0.0}, "w_control"),
        ({"w_position": 0.0, "w_terminal_position": 0.0}, "w_position"),
        ({"rail_margin": 2.0}, "rail_margin"),
        ({"x_ref": 1.75}, "x_ref"),
        ({"x_ref": float("nan")}, "x_ref"),
    ],
)
def test_rejects_bad_arguments(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        CartTrackingMPC(**kwargs)


def test_unknown_model_names_the_valid_tasks() -> None:
    with pytest.raises(UnknownNameError, match="unknown task 'no_such_task'; valid tasks: .*cartpole_swingup"):
        CartTrackingMPC(model="no_such_task")


def test_rejects_bad_state_shape_and_reference() -> None:
    skill = CartTrackingMPC()
    with pytest.raises(ShapeError, match="shape"):
        skill.act(np.zeros(5))
    with pytest.raises(ConfigError, match="x_ref"):
        skill.set_reference(-3.0)


def test_ctrl_c_during_a_solve_stops_the_caller_instead_of_a_fallback() -> None:
    """CasADi turns most KeyboardInterrupts raised by a signal handler during a solve into a RuntimeError; the skill
    must raise it again (a run's Ctrl-C or SIGTERM lands in the MPC most of the time), not return a fallback. A timer
    interrupts a loop of solves 30 times at varied points."""
    import signal

    skill = CartTrackingMPC()
    skill.reset(np.random.default_rng(0))
    rng = np.random.default_rng(0)
    states = [np.array([0.5, 3.0, 0.0, 0.0]) + rng.normal(0.0, 0.3, 4) for _ in range(40)]
    assert all(skill.act(s).info["status"] == STATUS_OK for s in states)  # undisturbed, every solve converges

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGALRM, interrupt)
    statuses, surfaced = [], 0
    try:
        for trial in range(30):
            try:
                signal.setitimer(signal.ITIMER_REAL, 0.001 + 0.0003 * trial)
                for state in states * 5:
                    statuses.append(skill.act(state).info["status"])
            except KeyboardInterrupt:
                surfaced += 1
            except SystemError as error:  # a C extension returned with the interrupt pending: it is the cause
                surfaced += isinstance(error.__cause__, KeyboardInterrupt)
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
    finally:
        signal.signal(signal.SIGALRM, previous)
    # No interrupt becomes a fallback. CasADi itself swallows some whole (5 % alone, 20 % beside the test suite: the
    # solve returns as if none came), which the run's signal callback raises again at the end of the step
    # (tests/hrtc/test_callbacks.py); before the skill raised them again, 2 of 30 surfaced.
    assert set(statuses) == {STATUS_OK} and surfaced >= 15
