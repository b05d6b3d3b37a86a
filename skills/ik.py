"""Differential-IK skills for a 7-DoF arm with mink: reach a pose, return to a comfortable posture, keep off obstacles.

Every skill proposes a joint-velocity command for the arm, rad/s, (7,), the action of ``panda_reach``. The mink
skills solve one QP per step (``mink.solve_ik`` with the daqp solver) on their own ``mink.Configuration``, updated
from the measured arm joint positions; the velocity is the QP's solution for one step of ``dt`` seconds. The QP's
limits keep the joints inside their ranges (``ConfigurationLimit``) and the speeds inside the action bounds
(``VelocityLimit``). A failed solve or a non-finite state gives zero velocity (hold still) and a status code:

- ``status`` 0: solved; 1: the QP solver found no solution; 2: it returned NaN / inf; 3: the state had NaN / inf.

Each skill is partial on purpose (the meta-policy composes them): the reach follows the error gradient straight
into the wall when the target lies behind it; the posture skill ignores the target (it reconfigures the arm around
a still hand); the avoidance skill goes over the wall without touching it but stops above the target.
"""

from __future__ import annotations

import copy
import logging
import time
from collections.abc import Sequence
from typing import Any

import mink
import mujoco
import numpy as np

from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from hrtc.skill import SkillOutput

log = logging.getLogger(__name__)

STATUS_OK = 0
STATUS_NO_SOLUTION = 1
STATUS_NONFINITE_SOLUTION = 2
STATUS_NONFINITE_STATE = 3

PANDA_JOINTS: tuple[str, ...] = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
PANDA_HOME: tuple[float, ...] = (0.0, -0.785, 0.0, -2.356, 0.0, 0.0, 0.785)


def arm_model(model: str | mujoco.MjModel) -> mujoco.MjModel:
    """The ``MjModel`` a skill plans with: a copy of task ``model``'s model when it is a task name (an env exposing
    ``unwrapped.model``, like ``panda_reach``), the model itself when it already is one."""
    if isinstance(model, mujoco.MjModel):
        return model
    if not isinstance(model, str):
        raise ConfigError(f"model must be a task name or a mujoco.MjModel, got {type(model).__name__}")
    import envs

    env = envs.make(model)
    try:
        return copy.copy(env.unwrapped.model)
    finally:
        env.close()


class _ArmSkill:
    """Shared plumbing: the model, the arm's joints (qpos and dof addresses), the speed bound, status bookkeeping."""

    state_keys: tuple[str, ...] = ("arm_qpos",)

    def __init__(
        self,
        model: str | mujoco.MjModel,
        joints: Sequence[str] = PANDA_JOINTS,
        max_velocity: float = 1.5,
        dt: float = 0.02,
    ) -> None:
        self.model = arm_model(model)
        names = [self.model.joint(j).name for j in range(self.model.njnt)]
        unknown = [j for j in joints if j not in names]
        if unknown:
            raise UnknownNameError("joint", unknown[0], names)
        if max_velocity <= 0 or dt <= 0:
            raise ConfigError(f"max_velocity and dt must be positive, got {max_velocity}, {dt}")
        self.joints = tuple(joints)
        ids = [self.model.joint(j).id for j in self.joints]
        self.qpos_adr = np.array([self.model.jnt_qposadr[i] for i in ids])
        self.dof_adr = np.array([self.model.jnt_dofadr[i] for i in ids])
        self.range = self.model.jnt_range[ids].copy()  # (n, 2) rad
        self.max_velocity, self.dt = float(max_velocity), float(dt)
        self.n = len(self.joints)
        self.configuration = mink.Configuration(self.model)
        self._q_full = self.configuration.q.copy()  # (nq,): the joints outside the arm stay at their qpos0
        self._q_measured = np.zeros(self.n)  # the last state's arm joint positions, rad

    def _arm_q(self, state: np.ndarray, expected: int) -> np.ndarray | None:
        """The arm joint positions from ``state`` (clipped into the ranges by 1e-6 rad: the simulator may sit a hair
        outside them); None if the state is not finite."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (expected,):
            raise ShapeError(f"{type(self).__name__} expects a state of shape ({expected},) {self.state_keys}, got "
                             f"{state.shape}")  # fmt: skip
        if not np.all(np.isfinite(state)):
            log.warning("%s got a non-finite state; proposing zero velocity", type(self).__name__)
            return None
        self._q_measured = state[: self.n].copy()
        return np.clip(state[: self.n], self.range[:, 0] + 1e-6, self.range[:, 1] - 1e-6)

    def _update(self, q_arm: np.ndarray) -> None:
        q = self._q_full.copy()
        q[self.qpos_adr] = q_arm
        self.configuration.update(q)

    def _bounded(self, velocity: np.ndarray) -> np.ndarray:
        """Scale (keeping the direction) into the speed bound; then clip so that one step of ``dt`` from the
        measured joint positions ends inside the ranges (the QP's own limit holds only up to the solver's
        tolerance, about 1e-7 rad, which would otherwise accumulate)."""
        peak = np.max(np.abs(velocity))
        if peak > self.max_velocity:
            velocity = velocity * (self.max_velocity / peak)
        q, vmax = self._q_measured, self.max_velocity
        low = np.minimum((self.range[:, 0] - q) / self.dt, vmax)  # a joint past its limit returns at most at vmax
        high = np.maximum((self.range[:, 1] - q) / self.dt, -vmax)
        return np.clip(velocity, low, high)

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless between steps (each QP starts from the measured state): nothing to forget."""


class _MinkSkill(_ArmSkill):
    """A skill whose velocity is one ``mink.solve_ik`` step with its ``tasks`` under joint and speed limits."""

    def __init__(self, *args: Any, solver: str = "daqp", damping: float = 1e-4, limit_gain: float = 0.5,
                 **kwargs: Any) -> None:  # fmt: skip
        super().__init__(*args, **kwargs)
        self.solver, self.damping = solver, float(damping)
        self.limits: list[Any] = [
            mink.ConfigurationLimit(self.model, gain=limit_gain),
            mink.VelocityLimit(self.model, {j: self.max_velocity for j in self.joints}),
        ]
        self.tasks: list[Any] = []

    def _solve(self) -> tuple[np.ndarray, int, float]:
        """(arm velocity (n,) rad/s, status, solve time ms) for the configuration's current state."""
        tic = time.perf_counter()
        try:
            v = mink.solve_ik(self.configuration, self.tasks, self.dt, self.solver, self.damping, limits=self.limits)
        except mink.NoSolutionFound:
            log.warning("%s: the %s QP found no solution; proposing zero velocity", type(self).__name__, self.solver)
            return np.zeros(self.n), STATUS_NO_SOLUTION, (time.perf_counter() - tic) * 1e3
        ms = (time.perf_counter() - tic) * 1e3
        v = np.asarray(v, dtype=np.float64)[self.dof_adr]
        if not np.all(np.isfinite(v)):
            log.warning("%s: the %s QP returned NaN / inf; proposing zero velocity", type(self).__name__, self.solver)
            return np.zeros(self.n), STATUS_NONFINITE_SOLUTION, ms
        return self._bounded(v), STATUS_OK, ms


class IKReach(_MinkSkill):
    """Differential IK to an end-effector pose: a ``mink.FrameTask`` on ``frame`` under ``ConfigurationLimit``.

    State: ``arm_qpos`` (7,) rad, ``target_pos`` (3,) m, ``target_quat`` (4,) w, x, y, z (world frame), (14,).
    Info: ``status``, ``solve_ms``, ``position_error`` (m), ``orientation_error`` (rad), both before the step.

    Args:
        model: a task name (``"panda_reach"``) or an ``MjModel`` with the arm and ``frame``.
        frame, frame_type: the controlled frame (the Panda's ``end_effector`` site).
        position_cost: per m of position error; orientation_cost: per rad of orientation error.
        gain: fraction of the error the QP asks to remove in one step of ``dt``.
        posture_cost: a small ``PostureTask`` toward ``posture`` that regularises the redundant joint (0 disables).
    """

    state_keys = ("arm_qpos", "target_pos", "target_quat")

    def __init__(
        self,
        model: str | mujoco.MjModel,
        frame: str = "end_effector",
        frame_type: str = "site",
        position_cost: float = 1.0,
        orientation_cost: float = 0.5,
        gain: float = 0.15,
        posture_cost: float = 0.0,
        posture: Sequence[float] = PANDA_HOME,
        **kwargs: Any,
    ) -> None:
        super().__init__(model, **kwargs)
        self.frame_task = mink.FrameTask(frame, frame_type, position_cost, orientation_cost, gain=gain)
        self.frame, self.frame_type = frame, frame_type
        self.tasks = [self.frame_task]
        if posture_cost > 0:
            posture_task = mink.PostureTask(self.model, posture_cost)
            target = self._q_full.copy()
            target[self.qpos_adr] = np.asarray(posture, dtype=np.float64)
            posture_task.set_target(target)
            self.tasks.append(posture_task)

    def act(self, state: np.ndarray) -> SkillOutput:
        q = self._arm_q(state, self.n + 7)
        state = np.asarray(state, dtype=np.float64)
        if q is None:
            return SkillOutput(np.zeros(self.n), {"status": float(STATUS_NONFINITE_STATE), "solve_ms": 0.0,
                                                  "position_error": 0.0, "orientation_error": 0.0})  # fmt: skip
        pos, quat = state[self.n : self.n + 3], state[self.n + 3 : self.n + 7]
        quat = quat / max(np.linalg.norm(quat), 1e-12)
        self._update(q)
        target = mink.SE3.from_rotation_and_translation(mink.SO3(wxyz=quat), pos)
        self.frame_task.set_target(target)
        error = self.frame_task.compute_error(self.configuration)  # (6,): position m, then rotation rad
        v, status, ms = self._solve()
        info = {"status": float(status), "solve_ms": ms, "position_error": float(np.linalg.norm(error[:3])),
                "orientation_error": float(np.linalg.norm(error[3:]))}  # fmt: skip
        return SkillOutput(v, info)


class PostureSkill(_MinkSkill):
    """Pull the joints toward a comfortable configuration (mid-range, away from the limits): a ``mink.PostureTask``,
    by default in the null space of the hand: a ``FrameTask`` (``hand_cost``) holds the hand where it is, so the
    arm reconfigures without moving it (a 7-DoF arm has one redundant degree of freedom for a 6-D hand pose).
    ``hand_cost=0`` gives the plain posture task that moves the whole arm back to ``posture``.

    State: ``arm_qpos`` (7,) rad. Info: ``status``, ``solve_ms``, ``posture_error`` (rad, norm before the step),
    ``limit_margin`` (rad, the smallest distance of a joint to its limit).

    Args:
        posture: (7,) rad, the comfortable configuration. gain: fraction of the posture error asked for per step.
        hand_cost: cost per m (and per rad of hand orientation) of moving the hand; posture_cost: per rad.
    """

    def __init__(self, model: str | mujoco.MjModel, posture: Sequence[float] = PANDA_HOME, gain: float = 0.3,
                 hand_cost: float = 10.0, posture_cost: float = 0.1, frame: str = "end_effector",
                 frame_type: str = "site", **kwargs: Any) -> None:  # fmt: skip
        super().__init__(model, **kwargs)
        posture = np.asarray(posture, dtype=np.float64)
        if posture.shape != (self.n,) or np.any(posture < self.range[:, 0]) or np.any(posture > self.range[:, 1]):
            raise ConfigError(f"posture must be {self.n} joint positions inside the joint ranges, got {posture}")
        if hand_cost < 0 or posture_cost <= 0:
            raise ConfigError(f"hand_cost must be >= 0 and posture_cost > 0, got {hand_cost}, {posture_cost}")
        self.posture = posture
        self.posture_task = mink.PostureTask(self.model, cost=posture_cost, gain=gain)
        target = self._q_full.copy()
        target[self.qpos_adr] = posture
        self.posture_task.set_target(target)
        self.tasks = [self.posture_task]
        self.hand_task = None
        if hand_cost > 0:
            self.hand_task = mink.FrameTask(frame, frame_type, hand_cost, hand_cost, gain=1.0)
            self.tasks.append(self.hand_task)

    def act(self, state: np.ndarray) -> SkillOutput:
        q = self._arm_q(state, self.n)
        if q is None:
            return SkillOutput(np.zeros(self.n), {"status": float(STATUS_NONFINITE_STATE), "solve_ms": 0.0,
                                                  "posture_error": 0.0, "limit_margin": 0.0})  # fmt: skip
        self._update(q)
        if self.hand_task is not None:
            self.hand_task.set_target_from_configuration(self.configuration)  # hold the hand where it is now
        v, status, ms = self._solve()
        margin = float(np.min(np.minimum(q - self.range[:, 0], self.range[:, 1] - q)))
        info = {"status": float(status), "solve_ms": ms, "posture_error": float(np.linalg.norm(q - self.posture)),
                "limit_margin": margin}  # fmt: skip
        return SkillOutput(v, info)


class AvoidObstacle(_MinkSkill):
    """Approach the target from above, around the obstacle: differential IK of the end-effector position toward the
    *via point* ``(target x, target y, max(target z, clearance_height))`` under mink's ``CollisionAvoidanceLimit``
    between the arm's collision geoms and the obstacle geoms (plus the joint and speed limits).

    It carries the hand over a wall without touching it, but alone it stops above a low target (short of it by the
    wall's height): the final descent is the reach skill's. Its proposal fades to zero as the hand comes within
    ``handover`` m (horizontally) of the target, so it never pulls against that descent.

    The via point has the target's orientation (weighted by ``orientation_cost`` per rad), so that the reach's
    final descent from it is nearly a pure translation.

    State: ``arm_qpos`` (7,) rad, ``target_pos`` (3,) m, ``target_quat`` (4,), (14,). Info: ``status``,
    ``solve_ms``, ``via_error`` (m, distance to the via point before the step).

    Args:
        obstacles: names of the obstacle geoms the arm keeps off (the table is left out: targets lie near it).
        clearance_height: m, world z the hand rises to before it moves over low targets.
        min_distance: m, the smallest robot-obstacle distance the limit allows; detection: m, the distance at which
            a pair starts to constrain the motion.
        gain: fraction of the via-point error the QP asks to remove in one step of ``dt``.
    """

    state_keys = ("arm_qpos", "target_pos", "target_quat")

    def __init__(
        self,
        model: str | mujoco.MjModel,
        obstacles: Sequence[str] = ("obstacle",),
        clearance_height: float = 0.45,
        frame: str = "end_effector",
        frame_type: str = "site",
        min_distance: float = 0.02,
        detection: float = 0.10,
        gain: float = 0.15,
        orientation_cost: float = 0.5,
        handover: tuple[float, float] = (0.02, 0.05),
        **kwargs: Any,
    ) -> None:
        super().__init__(model, **kwargs)
        if not 0 <= handover[0] < handover[1]:
            raise ConfigError(f"handover must be (inner, outer) m with 0 <= inner < outer, got {handover}")
        self.handover = (float(handover[0]), float(handover[1]))
        geom_names = [self.model.geom(g).name for g in range(self.model.ngeom)]
        unknown = [o for o in obstacles if o not in geom_names]
        if unknown:
            raise UnknownNameError("obstacle geom", unknown[0], [n for n in geom_names if n])
        self.clearance_height = float(clearance_height)
        self.robot_geoms = self._moving_geoms()
        self.limits.append(
            mink.CollisionAvoidanceLimit(
                self.model,
                [(self.robot_geoms, list(obstacles))],
                minimum_distance_from_collisions=min_distance,
                collision_detection_distance=detection,
            )
        )
        self.frame, self.frame_type = frame, frame_type
        self.frame_task = mink.FrameTask(frame, frame_type, 1.0, orientation_cost, gain=gain)
        self.tasks = [self.frame_task]

    def _moving_geoms(self) -> list[int]:
        """The colliding geoms on bodies the arm joints move (the fixed base never approaches the obstacle)."""
        moving = {int(self.model.jnt_bodyid[self.model.joint(j).id]) for j in self.joints}

        def moved(body: int) -> bool:
            while body > 0:
                if body in moving:
                    return True
                body = int(self.model.body_parentid[body])
            return False

        colliding = (self.model.geom_contype != 0) | (self.model.geom_conaffinity != 0)
        return [g for g in range(self.model.ngeom) if colliding[g] and moved(int(self.model.geom_bodyid[g]))]

    def act(self, state: np.ndarray) -> SkillOutput:
        q = self._arm_q(state, self.n + 7)
        if q is None:
            return SkillOutput(np.zeros(self.n), {"status": float(STATUS_NONFINITE_STATE), "solve_ms": 0.0,
                                                  "via_error": 0.0, "fade": 0.0})  # fmt: skip
        state = np.asarray(state, dtype=np.float64)
        target, quat = state[self.n : self.n + 3], state[self.n + 3 : self.n + 7]
        via = np.array([target[0], target[1], max(target[2], self.clearance_height)])
        self._update(q)
        rotation = mink.SO3(wxyz=quat / max(np.linalg.norm(quat), 1e-12))
        self.frame_task.set_target(mink.SE3.from_rotation_and_translation(rotation, via))
        error = self.frame_task.compute_error(self.configuration)
        v, status, ms = self._solve()
        # Its job ends above the target: the proposal fades out as the hand comes within ``handover`` (m,
        # horizontally) of it, so that it never pulls against the final descent.
        hand = self.configuration.get_transform_frame_to_world(self.frame, self.frame_type).translation()
        inner, outer = self.handover
        fade = float(np.clip((np.linalg.norm(hand[:2] - target[:2]) - inner) / (outer - inner), 0.0, 1.0))
        info = {"status": float(status), "solve_ms": ms, "via_error": float(np.linalg.norm(error[:3])), "fade": fade}
        return SkillOutput(v * fade, info)
