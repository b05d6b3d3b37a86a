"""Physical parameters and rigid-body equations of the cart-pole, read from the task's own MuJoCo model.

Conventions (those of ``envs.cartpole``): ``x`` cart position (m), ``theta`` pole angle from upright (rad), positive
tilting the tip towards +x; the tip is at ``x + 2 l sin(theta)``. The motor force is ``gear * u`` N, ``u`` in [-1, 1].
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np


@dataclass(frozen=True)
class CartpoleParams:
    cart_mass: float  # kg
    pole_mass: float  # kg
    com_length: float  # m, hinge to the pole's centre of mass
    pole_inertia: float  # kg m^2, about the centre of mass, around the hinge axis
    gear: float  # N per unit of control
    cart_damping: float  # N s/m
    pole_damping: float  # N m s/rad
    gravity: float  # m/s^2, positive
    control_min: float
    control_max: float

    @classmethod
    def from_mj_model(cls, model: Any) -> CartpoleParams:
        """Read the parameters off a ``mujoco.MjModel`` of dm_control's single-pole cartpole."""
        import mujoco

        cart = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "cart")
        pole = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "pole_1")
        slider = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "slider")
        hinge = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "hinge_1")
        if min(cart, pole, slider, hinge) < 0:
            raise ValueError("the model has no cart/pole_1 bodies or slider/hinge_1 joints: not dm_control's cartpole")
        ctrlrange = model.actuator_ctrlrange[0]
        return cls(
            cart_mass=float(model.body_mass[cart]),
            pole_mass=float(model.body_mass[pole]),
            com_length=float(model.body_ipos[pole][2]),
            pole_inertia=float(model.body_inertia[pole][1]),
            gear=float(model.actuator_gear[0][0]),
            cart_damping=float(model.dof_damping[model.jnt_dofadr[slider]]),
            pole_damping=float(model.dof_damping[model.jnt_dofadr[hinge]]),
            gravity=float(-model.opt.gravity[2]),
            control_min=float(ctrlrange[0]),
            control_max=float(ctrlrange[1]),
        )

    @property
    def hinge_inertia(self) -> float:
        """Pole inertia about the hinge, kg m^2."""
        return self.pole_inertia + self.pole_mass * self.com_length**2

    def energy(self, theta: Any, theta_dot: Any) -> Any:
        """Pole mechanical energy (J) relative to resting upright: 0 upright at rest, ``-2 m g l`` hanging at rest."""
        return 0.5 * self.hinge_inertia * theta_dot**2 + self.pole_mass * self.gravity * self.com_length * (
            np.cos(theta) - 1.0
        )


def accelerations(
    p: CartpoleParams, theta: Any, theta_dot: Any, x_dot: Any, u: Any, math: ModuleType = np
) -> tuple[Any, Any]:
    """Cart and pole accelerations ``(x_ddot, theta_ddot)`` for control ``u`` (unitless, force = gear * u).

    ``math`` supplies ``sin`` and ``cos``: pass ``numpy`` or ``casadi`` to evaluate or build a symbolic model.
    Lagrange's equations, solved as a 2x2 linear system:
        (M + m) x'' + m l cos(th) th'' = F - b_x x' + m l sin(th) th'^2
        m l cos(th) x'' + (I + m l^2) th'' = m g l sin(th) - b_th th'
    """
    s, c = math.sin(theta), math.cos(theta)
    m, length = p.pole_mass, p.com_length
    a11, a12 = p.cart_mass + m, m * length * c
    a21, a22 = m * length * c, p.hinge_inertia
    b1 = p.gear * u - p.cart_damping * x_dot + m * length * s * theta_dot**2
    b2 = m * p.gravity * length * s - p.pole_damping * theta_dot
    det = a11 * a22 - a12 * a21
    return (a22 * b1 - a12 * b2) / det, (a11 * b2 - a21 * b1) / det
