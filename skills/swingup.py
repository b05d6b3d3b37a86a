"""Energy-pumping swing-up for the cart-pole (Åström and Furuta, Automatica 2000), a partial skill.

With ``E`` the pole's mechanical energy (J, 0 upright at rest, ``-2 m g l`` hanging at rest), the pole's equation
gives ``dE/dt = -m l cos(theta) theta_dot x_ddot - b theta_dot^2``: accelerating the cart against
``theta_dot cos(theta)`` raises ``E``. The law pushes that way in proportion to the energy still missing,

    u = clip(-k (E_target - E) tanh(theta_dot cos(theta) / w), -u_pump, u_pump) - k_x x - k_v x_dot,

with a weak cart-centring term so the cart stays off the rails (+-1.8 m). It brings ``E`` to the upright level but
has no feedback that stabilises the upright pole: once ``E`` is right its output is small and the pole swings
through upright (or turns back just short of it). A hanging pole exactly at rest is an equilibrium of the law;
any motion at all starts the pumping.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import SkillOutput
from skills.cartpole_model import CartpoleParams

STATUS_OK = 0
STATUS_NONFINITE_STATE = 3  # the state had NaN / inf; the action is zero (codes shared with skills.nmpc)


class EnergySwingUp:
    """Raise the pole's energy to ``energy_target``; not a balancer.

    Args:
        model: a task name for ``envs.mj_model`` or a ``mujoco.MjModel`` of dm_control's cart-pole.
        gain: k, control units per J of missing energy (``2 m g l`` is about 0.98 J for dm_control's pole).
        energy_target: E_target, J; 0 is the upright level.
        max_pump: u_pump, the largest control the pumping term uses, in control units; keeps the cart's swings
            short enough for the rails.
        velocity_scale: w, rad/s; ``tanh(theta_dot cos(theta) / w)`` is a smooth sign of the pumping direction.
        centring_gain: k_x, control units per m of cart offset.
        centring_damping: k_v, control units per m/s of cart velocity.

    ``act`` takes ``[pole_angle (rad, 0 upright), pole_angular_velocity (rad/s), cart_position (m),
    cart_velocity (m/s)]`` and returns u (1,) within the control range. Info: ``energy`` (J), ``energy_error``
    (E_target - E, J), ``status`` (0 ok, 3 non-finite state).
    """

    state_keys: tuple[str, ...] = ("pole_angle", "pole_angular_velocity", "cart_position", "cart_velocity")

    def __init__(
        self,
        model: str | Any = "cartpole_swingup",
        gain: float = 10.0,
        energy_target: float = 0.0,
        max_pump: float = 1.0,
        velocity_scale: float = 0.1,
        centring_gain: float = 0.6,
        centring_damping: float = 0.3,
    ) -> None:
        import envs  # here: envs pulls in dm_control, needed only to read the model

        model = envs.mj_model(model)
        try:
            self.params = CartpoleParams.from_mj_model(model)
        except (ValueError, AttributeError, TypeError) as error:
            raise ConfigError(f"model must be dm_control's cart-pole: {error}") from None
        p = self.params
        for name, value in (("gain", gain), ("velocity_scale", velocity_scale), ("max_pump", max_pump)):
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be positive and finite, got {value}")
        for name, value in (("centring_gain", centring_gain), ("centring_damping", centring_damping)):
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be >= 0 and finite, got {value}")
        swing = 2.0 * p.pole_mass * p.gravity * p.com_length  # J, energy from hanging to upright
        if not (np.isfinite(energy_target) and -swing < energy_target <= swing):
            raise ConfigError(f"energy_target must lie in (-2 m g l, 2 m g l] = (-{swing:.3g}, {swing:.3g}] J")
        if max_pump > max(-p.control_min, p.control_max):
            raise ConfigError(f"max_pump {max_pump} exceeds the control range [{p.control_min}, {p.control_max}]")
        self.gain = float(gain)
        self.energy_target = float(energy_target)
        self.max_pump = float(max_pump)
        self.velocity_scale = float(velocity_scale)
        self.centring_gain = float(centring_gain)
        self.centring_damping = float(centring_damping)

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless: nothing to forget."""

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose u (1,) for ``state`` (4,) ordered as ``state_keys``."""
        state = np.asarray(state, dtype=float)
        if state.shape != (4,):
            raise ShapeError(
                f"EnergySwingUp expects a state of shape (4,) ordered {self.state_keys}, got {state.shape}"
            )
        if not np.all(np.isfinite(state)):
            return SkillOutput(
                np.zeros(1), {"energy": 0.0, "energy_error": 0.0, "status": float(STATUS_NONFINITE_STATE)}
            )
        theta, theta_dot, x, x_dot = state
        energy = float(self.params.energy(theta, theta_dot))
        missing = self.energy_target - energy
        direction = np.tanh(theta_dot * np.cos(theta) / self.velocity_scale)
        pump = np.clip(-self.gain * missing * direction, -self.max_pump, self.max_pump)
        u = pump - self.centring_gain * x - self.centring_damping * x_dot
        action = np.array([np.clip(u, self.params.control_min, self.params.control_max)])
        return SkillOutput(action, {"energy": energy, "energy_error": missing, "status": float(STATUS_OK)})
