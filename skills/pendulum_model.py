"""Physical parameters of the single pendulum, read from the task's own MuJoCo model.

Conventions (those of ``envs.pendulum``): ``theta`` the pole's angle from upright (rad), positive about the hinge
axis +y; torque ``gear * u`` N m. Equation of motion: ``I theta_ddot = m g l sin(theta) - b theta_dot + gear u``.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from skills.acrobot_model import _hinge_inertia


@dataclass(frozen=True)
class PendulumParams:
    mass: float  # kg
    com_length: float  # m, hinge to the centre of mass
    com_inertia: float  # kg m^2, about the centre of mass, around the hinge axis
    damping: float  # N m s/rad
    gear: float  # N m per unit of control
    gravity: float  # m/s^2, positive
    control_min: float
    control_max: float

    @classmethod
    def from_mj_model(cls, model: Any) -> PendulumParams:
        """Read the parameters off a ``mujoco.MjModel`` of dm_control's pendulum (body ``pole``, joint ``hinge``)."""
        import mujoco

        pole = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "pole")
        hinge = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "hinge")
        if min(pole, hinge) < 0 or model.nu != 1 or model.nv != 1:
            raise ValueError("the model has no pole body or hinge joint with one motor: not dm_control's pendulum")
        ctrlrange = model.actuator_ctrlrange[0]
        return cls(
            mass=float(model.body_mass[pole]),
            com_length=float(model.body_ipos[pole][2]),
            com_inertia=_hinge_inertia(model, pole),
            damping=float(model.dof_damping[model.jnt_dofadr[hinge]]),
            gear=float(model.actuator_gear[0][0]),
            gravity=float(-model.opt.gravity[2]),
            control_min=float(ctrlrange[0]),
            control_max=float(ctrlrange[1]),
        )

    @property
    def hinge_inertia(self) -> float:
        """kg m^2, about the hinge."""
        return self.com_inertia + self.mass * self.com_length**2

    @property
    def swing_energy(self) -> float:
        """J, between hanging and upright at rest: ``2 m g l``."""
        return 2.0 * self.mass * self.gravity * self.com_length

    def energy(self, theta: Any, theta_dot: Any, math: ModuleType = np) -> Any:
        """Mechanical energy, J: 0 upright at rest, ``-2 m g l`` hanging at rest."""
        return 0.5 * self.hinge_inertia * theta_dot**2 + self.mass * self.gravity * self.com_length * (
            math.cos(theta) - 1.0
        )

    def acceleration(self, theta: Any, theta_dot: Any, u: Any, math: ModuleType = np) -> Any:
        """theta_ddot, rad/s^2, for control ``u``."""
        torque = self.mass * self.gravity * self.com_length * math.sin(theta) - self.damping * theta_dot
        return (torque + self.gear * u) / self.hinge_inertia
