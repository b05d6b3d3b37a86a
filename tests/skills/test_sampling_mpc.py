"""Predictive sampling on the acrobot's own MuJoCo model: its forward kinematics and rollouts against the task's
physics, the spline, that a call never picks a plan worse than its nominal, the swing-up to the target, check_skill."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import envs
from hrtc.check import check_skill, task_states
from hrtc.errors import ConfigError, ShapeError
from skills.sampling_mpc import AcrobotPredictiveSampling, _interpolation_matrix
from tests.skills.conftest import filtered_state

STATE_KEYS = ("shoulder_angle", "elbow_angle", "shoulder_velocity", "elbow_velocity")


@pytest.fixture
def acrobot() -> Any:
    env = envs.make("acrobot_swingup")
    env.reset(seed=0)
    yield env
    env.close()


def test_tip_is_mujocos_tip_site() -> None:
    skill = AcrobotPredictiveSampling(samples=2)
    env = envs.make("acrobot_swingup")
    env.reset(seed=0)
    physics = env.unwrapped.physics
    rng = np.random.default_rng(0)
    for _ in range(10):
        with physics.reset_context():
            physics.data.qpos[:] = rng.uniform(-np.pi, np.pi, 2)
        tip = physics.named.data.site_xpos["tip"][[0, 2]]
        np.testing.assert_allclose(skill.tip(physics.data.qpos.copy()), tip, atol=1e-12)
        assert abs(np.linalg.norm(skill.tip(physics.data.qpos.copy()) - skill._target) - physics.to_target()) < 1e-12
    env.close()


def test_spline_interpolates_linearly_through_its_knots() -> None:
    basis = _interpolation_matrix(knots=5, steps=40, horizon=2.0)  # knots every 0.5 s, steps of 0.05 s
    np.testing.assert_allclose(basis.sum(axis=0), 1.0)
    knot_times = np.linspace(0.0, 2.0, 5)
    line = 0.3 - 0.2 * knot_times  # a linear function is reproduced exactly
    np.testing.assert_allclose(line @ basis, 0.3 - 0.2 * np.arange(40) * 0.05, atol=1e-12)
    np.testing.assert_allclose((np.eye(5) @ basis)[:, ::10], np.eye(5)[:, :4], atol=1e-12)  # knot values at knots


def test_rollout_cost_is_the_cost_of_the_real_task_trajectory(acrobot: Any) -> None:
    """At the task's own step (0.01 s) the planner's rollout is the env's trajectory under the same controls."""
    skill = AcrobotPredictiveSampling(horizon=0.5, dt=0.01, spline_points=3, samples=2)
    knots = np.array([[0.8, -0.5, 0.3]])
    state = filtered_state(acrobot, STATE_KEYS)
    predicted = skill.rollout_costs(state, knots)[0]
    controls = (knots @ skill._basis)[0]
    w_d, w_v, w_u = skill.weights
    cost = 0.0
    for u in controls:
        acrobot.step(np.array([u], dtype=np.float32))
        s = acrobot.unwrapped.skill_state()
        cost += (w_d * s["tip_distance"][0] ** 2 + w_v * (s["shoulder_velocity"][0] ** 2 + s["elbow_velocity"][0] ** 2)
                 + w_u * u**2) * skill.dt  # fmt: skip
    assert predicted == pytest.approx(cost, rel=1e-4)  # float32 actions in the env, float64 in the planner


def test_a_call_never_picks_a_plan_worse_than_its_nominal(acrobot: Any) -> None:
    skill = AcrobotPredictiveSampling(samples=16)
    skill.reset(np.random.default_rng(0))
    for _ in range(20):
        out = skill.act(filtered_state(acrobot, STATE_KEYS))
        assert out.info["improvement"] >= 0.0 and out.info["status"] == 0.0
        for _ in range(5):
            acrobot.step(out.action.astype(np.float32))


def test_brings_the_tip_to_the_target_from_a_random_start(acrobot: Any) -> None:
    """From dm_control's start of seed 0 (angles 0.31 and 1.35 rad, at rest) the tip reaches the target's 0.2 m (full
    reward) within 4 s; it is a swing-up, not a balance (see the module's docstring)."""
    acrobot.reset(seed=0)
    skill = AcrobotPredictiveSampling()
    skill.reset(np.random.default_rng(0))
    distances, solve_ms = [], []
    for step in range(400):
        if step % 5 == 0:  # call_interval 0.05 s
            out = skill.act(filtered_state(acrobot, STATE_KEYS))
            solve_ms.append(out.info["solve_ms"])
        acrobot.step(out.action.astype(np.float32))
        distances.append(acrobot.unwrapped.skill_state()["tip_distance"][0])
    assert distances[0] > 1.5 and min(distances) < 0.2, f"closest {min(distances):.2f} m"
    print(
        f"\npredictive sampling: tip within 0.2 m after {np.argmax(np.array(distances) < 0.2) * 0.01:.2f} s; "
        f"median {np.median(solve_ms):.1f} ms per call"
    )


def test_passes_check_skill() -> None:
    env = envs.make("acrobot_swingup")
    check_skill(AcrobotPredictiveSampling(samples=8), task_states(env, n=50), env.action_space)
    env.close()


def test_bad_input() -> None:
    for kwargs in ({"model": "pendulum_swingup"}, {"horizon": 1.03}, {"samples": 0}, {"noise": -0.1},
                   {"spline_points": 1}, {"w_distance": -1.0}):  # fmt: skip
        with pytest.raises(ConfigError):
            AcrobotPredictiveSampling(**kwargs)
    with pytest.raises(ShapeError):
        AcrobotPredictiveSampling(samples=2).act(np.zeros(3))
    out = AcrobotPredictiveSampling(samples=2).act(np.array([np.nan, 0.0, 0.0, 0.0]))
    assert out.action[0] == 0.0 and out.info["status"] == 3.0
