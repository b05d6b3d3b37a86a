"""The mink skills on the Panda: mink-style properties of the IK reach (the error decreases strictly to a tolerance
within a step budget, zero motion at the goal, joint limits never crossed), the posture and avoidance skills on
their own, failures handled, and ``check_skill`` on real states of ``panda_reach``.

The property tests integrate the skills' joint velocities kinematically (``q += v dt``), as mink's own tests do;
the closed loop through the simulator is the environment's and the benchmark's business.
"""

from __future__ import annotations

from collections.abc import Iterator

import mink
import mujoco
import numpy as np
import pytest

import envs
from envs.panda_reach import HOME, PandaReachEnv
from hrtc.check import check_skill, task_states
from hrtc.cli import task_config
from hrtc.composition import build_library
from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from hrtc.skill import Skill
from skills.ik import (
    STATUS_NO_SOLUTION,
    STATUS_NONFINITE_STATE,
    STATUS_OK,
    AvoidObstacle,
    IKReach,
    PostureSkill,
)

DT = 0.02  # s, the task's control step


@pytest.fixture(scope="module")
def env() -> Iterator[PandaReachEnv]:
    task = envs.make("panda_reach")
    yield task.unwrapped
    task.close()


@pytest.fixture(scope="module")
def reach(env: PandaReachEnv) -> IKReach:
    return IKReach(env.model)


def fk(env: PandaReachEnv, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """End-effector position (3,) and quaternion (4,) of arm configuration ``q`` (7,)."""
    data = mujoco.MjData(env.model)
    data.qpos[env.arm_qpos_adr] = q
    mujoco.mj_kinematics(env.model, data)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[env.ee_site])
    return data.site_xpos[env.ee_site].copy(), quat


def within_limits(env: PandaReachEnv, q: np.ndarray, tol: float = 1e-6) -> bool:
    """Inside the joint ranges up to ``tol`` rad (the QP solver's feasibility tolerance is about 1e-7)."""
    return bool(np.all(q >= env.arm_range[:, 0] - tol) and np.all(q <= env.arm_range[:, 1] + tol))


def rollout(skill: IKReach, env: PandaReachEnv, q: np.ndarray, target: tuple, steps: int) -> tuple[list, np.ndarray]:
    """Integrate the reach kinematically; returns the weighted task errors before each step and the final q."""
    trace = []
    pos, quat = target
    for _ in range(steps):
        out = skill.act(np.concatenate([q, pos, quat]))
        assert out.info["status"] == STATUS_OK
        error = np.concatenate([out.info["position_error"] * np.ones(1), out.info["orientation_error"] * np.ones(1)])
        trace.append(float(np.hypot(error[0], 0.5 * error[1])))
        q = q + out.action * DT
        assert within_limits(env, q)
    return trace, q


def test_skills_follow_the_protocol(env: PandaReachEnv, reach: IKReach) -> None:
    skills = [reach, PostureSkill(env.model), AvoidObstacle(env.model)]
    assert all(isinstance(s, Skill) for s in skills)
    assert reach.state_keys == ("arm_qpos", "target_pos", "target_quat")
    assert skills[1].state_keys == ("arm_qpos",)
    assert skills[2].state_keys == ("arm_qpos", "target_pos", "target_quat")


@pytest.mark.parametrize("family", ["free", "limit"])
def test_reach_error_decreases_strictly_to_a_tolerance_within_a_step_budget(env: PandaReachEnv, reach: IKReach,
                                                                              family: str) -> None:  # fmt: skip
    """From HOME to reachable pose targets (the FK of sampled configurations, some with a joint within 0.02-0.15 rad
    of its limit): the weighted pose error falls at every step until it is within 1 mm / 0.01 rad, in 150 steps."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        pos, quat, _ = env.sample_target(("free", "limit").index(family), rng)
        trace, q = rollout(reach, env, HOME.copy(), (pos, quat), 150)
        reached = int(np.argmax(np.asarray(trace) < 1e-3)) if min(trace) < 1e-3 else None
        assert reached is not None, f"stalled at {min(trace):.4f} for target {pos}"
        diffs = np.diff(trace[: reached + 1])
        assert np.all(diffs < 0), f"error rose at step {int(np.argmax(diffs >= 0))}: {trace[: reached + 1]}"
        final_pos, _ = fk(env, q)
        assert np.linalg.norm(final_pos - pos) < 1e-3


def test_reach_proposes_zero_motion_when_the_target_is_met(env: PandaReachEnv, reach: IKReach) -> None:
    rng = np.random.default_rng(3)
    for q in [HOME, *(HOME + rng.uniform(-0.4, 0.4, 7) for _ in range(3))]:
        pos, quat = fk(env, q)
        out = reach.act(np.concatenate([q, pos, quat]))
        assert out.info["position_error"] < 1e-9 and out.info["orientation_error"] < 1e-6
        np.testing.assert_allclose(out.action, 0.0, atol=1e-6)


def test_reach_never_crosses_a_joint_limit_even_toward_unreachable_targets(env: PandaReachEnv, reach: IKReach) -> None:
    """Targets beyond the arm's reach drive joints into their limits: they arrive at most at the limit."""
    rng = np.random.default_rng(0)
    for target in ([1.5, 0.0, 0.3], [0.0, -1.4, 0.5], [0.1, 0.0, 1.6], [-0.9, 0.9, 0.0]):
        q = np.clip(HOME + rng.uniform(-0.3, 0.3, 7), env.arm_range[:, 0], env.arm_range[:, 1])
        for _ in range(200):
            out = reach.act(np.concatenate([q, target, [1.0, 0.0, 0.0, 0.0]]))
            q = q + out.action * DT
            assert within_limits(env, q)
            assert np.max(np.abs(out.action)) <= reach.max_velocity + 1e-9
        margins = np.minimum(q - env.arm_range[:, 0], env.arm_range[:, 1] - q)
        assert margins.min() < 0.05, "the far target should have pushed some joint to its limit"


def test_plain_posture_converges_to_its_posture_and_leaves_the_limits(env: PandaReachEnv) -> None:
    skill = PostureSkill(env.model, hand_cost=0.0)
    q = env.arm_range[:, 1] - 0.01  # every joint 0.01 rad from its upper limit
    first = skill.act(q).info["limit_margin"]
    for _ in range(200):
        out = skill.act(q)
        q = q + out.action * DT
    assert first == pytest.approx(0.01)
    np.testing.assert_allclose(q, HOME, atol=1e-3)
    assert out.info["limit_margin"] > 0.3


def test_null_space_posture_moves_the_joints_off_a_limit_but_not_the_hand(env: PandaReachEnv) -> None:
    """A configuration with the elbow 0.02 rad from its limit: the default posture skill reconfigures the arm
    (the posture error and the elbow's margin improve) while the hand stays within 1 cm of where it was over 2 s
    (the hand task is soft and re-anchored at every step: it drifts by a few mm)."""
    skill = PostureSkill(env.model)
    q = HOME.copy()
    q[3] = env.arm_range[3, 0] + 0.02
    q[0], q[2] = 0.4, -0.5
    hand, _ = fk(env, q)
    error0 = skill.act(q).info["posture_error"]
    for _ in range(100):
        q = q + skill.act(q).action * DT
        assert within_limits(env, q)
    moved, _ = fk(env, q)
    assert np.linalg.norm(moved - hand) < 1e-2
    assert skill.act(q).info["posture_error"] < 0.9 * error0
    assert q[3] - env.arm_range[3, 0] > 0.02


def wall_clearance(env: PandaReachEnv, skill: AvoidObstacle, q: np.ndarray) -> float:
    """Smallest distance, m, between the arm's moving geoms and the wall at configuration ``q``."""
    data = skill.scratch
    data.qpos[env.arm_qpos_adr] = q
    mujoco.mj_kinematics(env.model, data)
    wall = env.model.geom("obstacle").id
    return min(mujoco.mj_geomDistance(env.model, data, g, wall, 1.0, None) for g in skill.robot_geoms)


def test_reach_alone_goes_through_the_wall_avoid_goes_over_it_and_stops_above(env: PandaReachEnv,
                                                                                 reach: IKReach) -> None:  # fmt: skip
    """The partial skills: to targets low behind the wall, the reach's straight path crosses the wall; the avoidance
    skill keeps its distance (the collision-avoidance limit) and ends above the target, at the via point."""
    avoid = AvoidObstacle(env.model)
    avoid.scratch = mujoco.MjData(env.model)  # type: ignore[attr-defined]
    rng = np.random.default_rng(11)
    crossed = 0
    for _ in range(3):
        pos, quat, _ = env.sample_target(2, rng)
        q_reach, q_avoid = HOME.copy(), HOME.copy()
        closest_reach, closest_avoid = np.inf, np.inf
        for _ in range(100):
            state = np.concatenate([q_reach, pos, quat])
            q_reach = q_reach + reach.act(state).action * DT
            q_avoid = q_avoid + avoid.act(np.concatenate([q_avoid, pos, quat])).action * DT
            closest_reach = min(closest_reach, wall_clearance(env, avoid, q_reach))
            closest_avoid = min(closest_avoid, wall_clearance(env, avoid, q_avoid))
        crossed += closest_reach < 0.0
        assert closest_avoid > 0.0, "the avoidance skill touched the wall"
        ee, _ = fk(env, q_avoid)
        # At the via point's height, and horizontally within the hand-over radius where its proposal fades out.
        assert ee[2] == pytest.approx(avoid.clearance_height, abs=0.01)
        assert np.linalg.norm(ee[:2] - pos[:2]) <= avoid.handover[1] + 1e-3
    assert crossed >= 2, "the reach alone should run into the wall for most targets behind it"


def test_non_finite_state_gives_zero_velocity_and_a_status(env: PandaReachEnv, reach: IKReach) -> None:
    bad = np.concatenate([HOME, [0.5, np.nan, 0.3], [1.0, 0.0, 0.0, 0.0]])
    out = reach.act(bad)
    np.testing.assert_array_equal(out.action, np.zeros(7))
    assert out.info["status"] == STATUS_NONFINITE_STATE
    out = PostureSkill(env.model).act(np.full(7, np.inf))
    assert out.info["status"] == STATUS_NONFINITE_STATE and not np.any(out.action)


def test_a_solver_failure_gives_zero_velocity_and_a_status(env: PandaReachEnv, monkeypatch) -> None:
    """mink raises NoSolutionFound when the QP solver fails: the skill holds still and reports it."""
    skill = IKReach(env.model)

    def failing_solve(*args, **kwargs):
        raise mink.NoSolutionFound("daqp")

    monkeypatch.setattr(mink, "solve_ik", failing_solve)
    out = skill.act(np.concatenate([HOME, [0.5, 0.0, 0.3], [1.0, 0.0, 0.0, 0.0]]))
    assert out.info["status"] == STATUS_NO_SOLUTION
    np.testing.assert_array_equal(out.action, np.zeros(7))
    assert all(np.isfinite(v) for v in out.info.values())


def test_bad_construction_and_input_are_refused(env: PandaReachEnv, reach: IKReach) -> None:
    with pytest.raises(ShapeError, match=r"\(14,\)"):
        reach.act(np.zeros(7))
    with pytest.raises(UnknownNameError, match="valid joints"):
        IKReach(env.model, joints=("elbow",))
    with pytest.raises(UnknownNameError, match="obstacle geom"):
        AvoidObstacle(env.model, obstacles=("lamp",))
    with pytest.raises(ConfigError, match="posture"):
        PostureSkill(env.model, posture=[0.0] * 7)  # joint 4 must stay below -0.4 rad
    with pytest.raises(ConfigError):
        IKReach(env.model, max_velocity=0.0)
    with pytest.raises(ConfigError):
        AvoidObstacle(env.model, handover=(0.05, 0.02))
    with pytest.raises(ConfigError):
        IKReach(3.0)  # type: ignore[arg-type]


def test_every_skill_of_the_task_passes_check_skill() -> None:
    cfg = task_config("panda_reach")
    states = task_states("panda_reach", n=40, seed=0)
    library = build_library(cfg["skills"])
    space = envs.make("panda_reach").action_space
    for slot in library.slots:
        summary = check_skill(slot.skill, states, space, slot.state_filter)
        assert summary["steps"] == 40
    assert library.names == ("reach", "posture", "avoid", "hold")
