"""Physical parameters and rigid-body equations of the acrobot, read from the task's own MuJoCo model.

Conventions (those of ``envs.acrobot``): ``q1`` the upper link's angle from upright, ``q2`` the lower link's angle
relative to the upper one, both rad, positive about the hinge axis +y (which takes +z towards +x); only the elbow is
driven, with torque ``gear * u`` N m, ``u`` in the control range. Manipulator form:

    M(q) q_ddot + h(q, q_dot) = (0, gear u),    h = Coriolis and centrifugal + gravity + joint damping.

Energy is 0 for the acrobot upright at rest and ``-2 g (m1 lc1 + m2 (l1 + lc2))`` hanging at rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np


def _hinge_inertia(model: Any, body: int) -> float:
    """The body's moment of inertia about its centre of mass around the world y axis (the hinge axis), kg m^2."""
    import mujoco

    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.body_iquat[body])
    rotation = rotation.reshape(3, 3)  # principal axes in the body frame
    return float((rotation @ np.diag(model.body_inertia[body]) @ rotation.T)[1, 1])


@dataclass(frozen=True)
class AcrobotParams:
    m1: float  # kg, upper link
    m2: float  # kg, lower link
    l1: float  # m, shoulder to elbow
    lc1: float  # m, shoulder to the upper link's centre of mass
    lc2: float  # m, elbow to the lower link's centre of mass
    i1: float  # kg m^2, upper link about its centre of mass (hinge axis)
    i2: float  # kg m^2, lower link about its centre of mass
    b1: float  # N m s/rad, shoulder damping
    b2: float  # N m s/rad, elbow damping
    gear: float  # N m per unit of control
    gravity: float  # m/s^2, positive
    control_min: float
    control_max: float

    @classmethod
    def from_mj_model(cls, model: Any) -> AcrobotParams:
        """Read the parameters off a ``mujoco.MjModel`` of dm_control's acrobot (bodies ``upper_arm`` and
        ``lower_arm``, joints ``shoulder`` and ``elbow``, one motor on the elbow)."""
        import mujoco

        upper = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "upper_arm")
        lower = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "lower_arm")
        shoulder = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "shoulder")
        elbow = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "elbow")
        if min(upper, lower, shoulder, elbow) < 0:
            raise ValueError("the model has no upper_arm/lower_arm bodies or shoulder/elbow joints: not an acrobot")
        if model.nu != 1 or model.actuator_trnid[0, 0] != elbow:
            raise ValueError("the acrobot must have exactly one actuator, on the elbow")
        ctrlrange = model.actuator_ctrlrange[0]
        return cls(
            m1=float(model.body_mass[upper]),
            m2=float(model.body_mass[lower]),
            l1=float(model.body_pos[lower][2]),
            lc1=float(model.body_ipos[upper][2]),
            lc2=float(model.body_ipos[lower][2]),
            i1=_hinge_inertia(model, upper),
            i2=_hinge_inertia(model, lower),
            b1=float(model.dof_damping[model.jnt_dofadr[shoulder]]),
            b2=float(model.dof_damping[model.jnt_dofadr[elbow]]),
            gear=float(model.actuator_gear[0][0]),
            gravity=float(-model.opt.gravity[2]),
            control_min=float(ctrlrange[0]),
            control_max=float(ctrlrange[1]),
        )

    @property
    def swing_energy(self) -> float:
        """J: the energy between hanging at rest and upright at rest, ``2 g (m1 lc1 + m2 (l1 + lc2))``."""
        return 2.0 * self.gravity * (self.m1 * self.lc1 + self.m2 * (self.l1 + self.lc2))

    def mass_matrix(self, q2: Any, math: ModuleType = np) -> tuple[Any, Any, Any]:
        """``(M11, M12, M22)`` of the symmetric 2x2 mass matrix, kg m^2."""
        c2 = math.cos(q2)
        m22 = self.i2 + self.m2 * self.lc2**2
        m12 = m22 + self.m2 * self.l1 * self.lc2 * c2
        m11 = self.i1 + self.m1 * self.lc1**2 + self.m2 * self.l1**2 + m22 + 2.0 * self.m2 * self.l1 * self.lc2 * c2
        return m11, m12, m22

    def bias(self, q1: Any, q2: Any, dq1: Any, dq2: Any, math: ModuleType = np) -> tuple[Any, Any]:
        """``h = (h1, h2)``, N m: Coriolis and centrifugal, gravity and damping torques (MuJoCo's ``qfrc_bias``
        minus ``qfrc_passive``)."""
        s1, s2, s12 = math.sin(q1), math.sin(q2), math.sin(q1 + q2)
        coupling = self.m2 * self.l1 * self.lc2 * s2
        g = self.gravity
        gravity1 = -g * (self.m1 * self.lc1 + self.m2 * self.l1) * s1 - g * self.m2 * self.lc2 * s12
        gravity2 = -g * self.m2 * self.lc2 * s12
        h1 = -coupling * (2.0 * dq1 * dq2 + dq2**2) + gravity1 + self.b1 * dq1
        h2 = coupling * dq1**2 + gravity2 + self.b2 * dq2
        return h1, h2

    def energy(self, q1: Any, q2: Any, dq1: Any, dq2: Any, math: ModuleType = np) -> Any:
        """Mechanical energy, J: 0 upright at rest."""
        m11, m12, m22 = self.mass_matrix(q2, math)
        kinetic = 0.5 * (m11 * dq1**2 + 2.0 * m12 * dq1 * dq2 + m22 * dq2**2)
        height = self.m1 * self.lc1 * math.cos(q1) + self.m2 * (self.l1 * math.cos(q1) + self.lc2 * math.cos(q1 + q2))
        upright = self.m1 * self.lc1 + self.m2 * (self.l1 + self.lc2)
        return kinetic + self.gravity * (height - upright)

    def accelerations(self, q1: Any, q2: Any, dq1: Any, dq2: Any, u: Any, math: ModuleType = np) -> tuple[Any, Any]:
        """``(q1_ddot, q2_ddot)``, rad/s^2, for control ``u`` (torque ``gear * u`` on the elbow)."""
        m11, m12, m22 = self.mass_matrix(q2, math)
        h1, h2 = self.bias(q1, q2, dq1, dq2, math)
        tau = self.gear * u
        det = m11 * m22 - m12 * m12
        return (-m22 * h1 - m12 * (tau - h2)) / det, (m12 * h1 + m11 * (tau - h2)) / det
