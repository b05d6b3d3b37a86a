"""Energy-pumping swing-ups, partial skills: the cart-pole's (Åström and Furuta, Automatica 2000), the pendulum's and
the acrobot's (collocated pumping, then Spong's partial feedback linearisation of the elbow); below, the cart-pole's.

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


def _pumping_direction(velocity: float, scale: float) -> float:
    """A smooth sign of ``velocity``; +1 at rest, so that a start exactly at rest still gets a first push."""
    return float(np.tanh(velocity / scale)) if velocity != 0.0 else 1.0


def _positive(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{name} must be positive and finite, got {value}")


class PendulumEnergySwingUp:
    """Energy pumping for the torque-limited pendulum: raise ``E`` to the upright level; not a balancer.

    ``dE/dt = gear u theta_dot - b theta_dot^2``, so torque along the motion raises ``E``. The law

        u = clip(k (E_target - E) tanh(theta_dot / w) + b theta_dot / gear, u_min, u_max)

    pushes along the motion in proportion to the energy still missing and cancels the hinge damping. With ``E`` at the
    upright level the pole creeps up to upright and falls through it: nothing holds it there.

    Args:
        model: a task name for ``envs.mj_model`` or a ``mujoco.MjModel`` of dm_control's pendulum.
        gain: k, control units per J of missing energy (``2 m g l`` is about 4.9 J for dm_control's pole).
        energy_target: E_target, J; 0 is the upright level.
        velocity_scale: w, rad/s.

    ``act`` takes ``[pole_angle (rad, 0 upright), pole_angular_velocity (rad/s)]``; info: ``energy`` (J),
    ``energy_error`` (E_target - E, J), ``status`` (0 ok, 3 non-finite state).
    """

    state_keys: tuple[str, ...] = ("pole_angle", "pole_angular_velocity")

    def __init__(
        self,
        model: str | Any = "pendulum_swingup",
        gain: float = 2.0,
        energy_target: float = 0.0,
        velocity_scale: float = 0.1,
    ) -> None:
        import envs
        from skills.pendulum_model import PendulumParams

        try:
            self.params = PendulumParams.from_mj_model(envs.mj_model(model))
        except (ValueError, AttributeError, TypeError) as error:
            raise ConfigError(f"model must be dm_control's pendulum: {error}") from None
        _positive(gain=gain, velocity_scale=velocity_scale)
        swing = self.params.swing_energy
        if not (np.isfinite(energy_target) and -swing < energy_target <= swing):
            raise ConfigError(f"energy_target must lie in (-2 m g l, 2 m g l] = (-{swing:.3g}, {swing:.3g}] J")
        self.gain, self.energy_target, self.velocity_scale = float(gain), float(energy_target), float(velocity_scale)

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless: nothing to forget."""

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose u (1,) for ``state`` (2,) ordered as ``state_keys``."""
        state = np.asarray(state, dtype=float)
        if state.shape != (2,):
            raise ShapeError(f"PendulumEnergySwingUp expects a state of shape (2,) ordered {self.state_keys}, "
                             f"got {state.shape}")  # fmt: skip
        if not np.all(np.isfinite(state)):
            return SkillOutput(
                np.zeros(1), {"energy": 0.0, "energy_error": 0.0, "status": float(STATUS_NONFINITE_STATE)}
            )
        p = self.params
        theta, theta_dot = state
        energy = float(p.energy(theta, theta_dot))
        missing = self.energy_target - energy
        u = self.gain * missing * _pumping_direction(theta_dot, self.velocity_scale) + p.damping * theta_dot / p.gear
        action = np.array([np.clip(u, p.control_min, p.control_max)])
        return SkillOutput(action, {"energy": energy, "energy_error": missing, "status": float(STATUS_OK)})


PHASE_PUMP, PHASE_RIGIDIFY = 0, 1  # AcrobotEnergySwingUp's info["phase"]


class AcrobotEnergySwingUp:
    """Swing the acrobot's energy up with its elbow, then stiffen the elbow so it rises as one pendulum.

    The acrobot's energy obeys ``dE/dt = tau q2_dot - b1 q1_dot^2 - b2 q2_dot^2`` (``tau`` the elbow torque), so
    while ``E`` is more than ``rigid_band`` below the target the skill **pumps**: it drives the elbow along its own
    motion in proportion to the missing energy, ``u = k (E_target - E) tanh(q2_dot / w)``. Within the band it
    **stiffens** the elbow by Spong's collocated partial feedback linearisation: the elbow torque that gives the
    elbow the acceleration ``v = -kp q2 - kd q2_dot`` whatever the shoulder does,

        tau = (M22 - M21 M12 / M11) v + h2 - M21 h1 / M11,

    from the manipulator equation ``M(q) q_ddot + h(q, q_dot) = (0, tau)``. With a straight elbow and the upright
    energy the acrobot is one rigid pendulum on its homoclinic orbit, which passes by upright. The masses, lengths,
    inertias and damping are the MuJoCo model's own (``skills.acrobot_model``). The torque limit (2 N m) saturates
    both phases; the skill reaches the upright energy and passes near upright but never holds it there (a partial
    skill: the balance must catch it).

    Args:
        model: a task name for ``envs.mj_model`` or a ``mujoco.MjModel`` of dm_control's acrobot.
        gain: k, control units per J of missing energy (``E`` is -39.2 J hanging at rest).
        energy_target: E_target, J; 0 is upright at rest.
        rigid_band: J; pump below ``E_target - rigid_band``, stiffen above.
        kp: 1/s^2, the elbow's stiffness in the linearised loop.
        kd: 1/s, its damping.
        velocity_scale: w, rad/s.

    ``act`` takes ``[shoulder_angle, elbow_angle (rad, 0 straight up), shoulder_velocity, elbow_velocity (rad/s)]``;
    info: ``energy`` (J), ``energy_error`` (E_target - E, J), ``phase`` (0 pump, 1 stiffen), ``status``.
    """

    state_keys: tuple[str, ...] = ("shoulder_angle", "elbow_angle", "shoulder_velocity", "elbow_velocity")

    def __init__(
        self,
        model: str | Any = "acrobot_swingup",
        gain: float = 1.0,
        energy_target: float = 0.0,
        rigid_band: float = 1.0,
        kp: float = 20.0,
        kd: float = 5.0,
        velocity_scale: float = 0.1,
    ) -> None:
        import envs
        from skills.acrobot_model import AcrobotParams

        try:
            self.params = AcrobotParams.from_mj_model(envs.mj_model(model))
        except (ValueError, AttributeError, TypeError) as error:
            raise ConfigError(f"model must be dm_control's acrobot: {error}") from None
        _positive(gain=gain, rigid_band=rigid_band, kp=kp, kd=kd, velocity_scale=velocity_scale)
        swing = self.params.swing_energy
        if not (np.isfinite(energy_target) and -swing < energy_target - rigid_band and energy_target <= swing):
            raise ConfigError(f"energy_target - rigid_band and energy_target must lie in (-{swing:.3g}, {swing:.3g}] J")
        self.gain, self.energy_target, self.rigid_band = float(gain), float(energy_target), float(rigid_band)
        self.kp, self.kd, self.velocity_scale = float(kp), float(kd), float(velocity_scale)

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless: nothing to forget."""

    def elbow_torque(self, state: np.ndarray, elbow_acceleration: float) -> float:
        """The elbow torque (N m) that gives the elbow ``elbow_acceleration`` (rad/s^2) in ``state`` (4,)."""
        q1, q2, dq1, dq2 = state
        m11, m12, m22 = self.params.mass_matrix(q2)
        h1, h2 = self.params.bias(q1, q2, dq1, dq2)
        return float((m22 - m12 * m12 / m11) * elbow_acceleration + h2 - m12 * h1 / m11)

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose u (1,) for ``state`` (4,) ordered as ``state_keys``."""
        state = np.asarray(state, dtype=float)
        if state.shape != (4,):
            raise ShapeError(f"AcrobotEnergySwingUp expects a state of shape (4,) ordered {self.state_keys}, "
                             f"got {state.shape}")  # fmt: skip
        p = self.params
        if not np.all(np.isfinite(state)):
            info = {"energy": 0.0, "energy_error": 0.0, "phase": 0.0, "status": float(STATUS_NONFINITE_STATE)}
            return SkillOutput(np.zeros(1), info)
        q1, q2, dq1, dq2 = state
        energy = float(p.energy(q1, q2, dq1, dq2))
        missing = self.energy_target - energy
        if missing > self.rigid_band:
            phase, u = PHASE_PUMP, self.gain * missing * _pumping_direction(dq2, self.velocity_scale)
        else:
            elbow_error = float(np.arctan2(np.sin(q2), np.cos(q2)))
            torque = self.elbow_torque(state, -self.kp * elbow_error - self.kd * dq2)
            phase, u = PHASE_RIGIDIFY, torque / p.gear
        action = np.array([np.clip(u, p.control_min, p.control_max)])
        info = {"energy": energy, "energy_error": missing, "phase": float(phase), "status": float(STATUS_OK)}
        return SkillOutput(action, info)
