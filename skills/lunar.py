"""Heuristic skills for the continuous LunarLander: gymnasium's landing heuristic taken apart.

gymnasium's ``heuristic`` lands the lander in one function: the side boosters tilt it towards the pad and damp its
rotation, the main engine slows the descent more the lower the lander is, and both engines are cut once a leg
touches. Here each of those is a skill of its own, useful and testable alone and none landing reliably alone:

- :class:`AttitudeHold`: side boosters keep the lander at a fixed angle (upright by default); never fires the main
  engine, so alone the lander falls upright and crashes.
- :class:`LateralCentring`: side boosters tilt the lander towards the pad (the tilt that turns main-engine thrust
  into a push towards ``x = 0``); alone it tilts but has no thrust to push with.
- :class:`DescentRate`: the main engine holds a target vertical speed (slower nearer the ground); with a zero target
  it hovers. Alone it has no attitude or lateral control: the initial push carries the lander off the pad.
- :class:`Touchdown`: once a leg touches, proposes the main engine off (``-1``) so that, summed with the others, the
  lander settles and the episode ends; before contact it proposes nothing.

The idle skill is ``skills.static.StaticIntent`` with ``[-1, 0]`` (engines off). Units are those of gymnasium's
observation (see ``envs.lunarlander``); actions are ``[main, lateral]`` in [-1, 1]: main ``<= 0`` off, ``(0, 1]``
50-100 % throttle; lateral ``abs(.) <= 0.5`` off, ``> 0.5`` the right booster (turns the lander clockwise, towards
negative angles), ``< -0.5`` the left one.

Every ``act`` checks its input's shape (:class:`~hrtc.errors.ShapeError`) and answers a non-finite state with the
zero action and ``status`` 3 rather than a NaN.
"""

from __future__ import annotations

import numpy as np

from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import SkillOutput

STATUS_OK = 0
STATUS_NONFINITE_STATE = 3  # the state had NaN / inf; the action is zero (codes shared with the other skills)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def _finite(name: str, value: float, low: float = -np.inf, high: float = np.inf) -> float:
    value = float(value)
    _require(
        bool(np.isfinite(value)) and low <= value <= high, f"{name} must be finite in [{low}, {high}], got {value}"
    )
    return value


class _LanderSkill:
    """Shared input checking: ``act`` validates the state, then calls ``_act`` on a finite (n,) float64 vector."""

    state_keys: tuple[str, ...] = ()

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless: nothing to forget (the heuristics are memoryless feedback laws)."""

    def act(self, state: np.ndarray) -> SkillOutput:
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (len(self.state_keys),):
            raise ShapeError(f"{type(self).__name__} reads {self.state_keys}: expected shape ({len(self.state_keys)},)"
                             f", got {state.shape}")  # fmt: skip
        if not np.all(np.isfinite(state)):
            return SkillOutput(np.zeros(2), {"status": float(STATUS_NONFINITE_STATE)})
        return self._act(state)

    def _act(self, state: np.ndarray) -> SkillOutput:
        raise NotImplementedError


def attitude_command(angle: float, rate: float, target: float, angle_gain: float, rate_gain: float) -> float:
    """The lateral command of a PD law on the angle: positive (right booster, clockwise) when the lander is turned
    or turning counter-clockwise of ``target``. ``angle`` in rad, ``rate`` (angular velocity) in units of 2.5 rad/s;
    clipped to [-1, 1]."""
    return float(np.clip(angle_gain * (angle - target) + rate_gain * rate, -1.0, 1.0))


class AttitudeHold(_LanderSkill):
    """Side boosters hold the angle at ``target_angle``; the main engine stays off (proposes 0).

    Args:
        target_angle: rad, 0 upright.
        angle_gain: lateral command per rad of angle error. The boosters ignore ``abs(command) <= 0.5``, so the angle
            rests within about ``0.5 / angle_gain`` rad of the target.
        rate_gain: lateral command per unit of angular velocity (2.5 rad/s); damps the rotation.

    ``act`` takes ``[angle (rad), angular_velocity (2.5 rad/s)]`` and returns ``[0, lateral]``. Info: ``angle_error``
    (rad), ``status``.
    """

    state_keys = ("angle", "angular_velocity")

    def __init__(self, target_angle: float = 0.0, angle_gain: float = 20.0, rate_gain: float = 20.0) -> None:
        self.target_angle = _finite("target_angle", target_angle, -np.pi / 2, np.pi / 2)
        self.angle_gain = _finite("angle_gain", angle_gain, 0.0)
        self.rate_gain = _finite("rate_gain", rate_gain, 0.0)
        _require(self.angle_gain > 0, "angle_gain must be positive")

    def _act(self, state: np.ndarray) -> SkillOutput:
        angle, rate = state
        lateral = attitude_command(angle, rate, self.target_angle, self.angle_gain, self.rate_gain)
        return SkillOutput(np.array([0.0, lateral]), {"angle_error": angle - self.target_angle, "status": 0.0})


class LateralCentring(_LanderSkill):
    """Side boosters tilt the lander towards the pad: target angle ``clip(kx x + kv vx, +-max_tilt)``.

    A positive angle points the main engine's thrust towards -x, so the target tilts the thrust against the offset
    and the drift; the booster law is :class:`AttitudeHold`'s on that moving target. It never fires the main engine:
    the tilt moves the lander only while another skill thrusts.

    Args:
        position_gain: kx, rad of tilt per unit of x (half viewport widths).
        velocity_gain: kv, rad of tilt per unit of vx (5 world units/s).
        max_tilt: rad; the largest tilt it asks for.
        angle_gain, rate_gain: the booster PD law (see :class:`AttitudeHold`).

    ``act`` takes ``[x, vx, angle, angular_velocity]`` and returns ``[0, lateral]``. Info: ``target_angle`` (rad),
    ``angle_error`` (rad), ``status``.
    """

    state_keys = ("x", "vx", "angle", "angular_velocity")

    def __init__(
        self,
        position_gain: float = 0.5,
        velocity_gain: float = 1.0,
        max_tilt: float = 0.4,
        angle_gain: float = 20.0,
        rate_gain: float = 20.0,
    ) -> None:
        self.position_gain = _finite("position_gain", position_gain, 0.0)
        self.velocity_gain = _finite("velocity_gain", velocity_gain, 0.0)
        self.max_tilt = _finite("max_tilt", max_tilt, 0.0, np.pi / 2)
        self.angle_gain = _finite("angle_gain", angle_gain, 0.0)
        self.rate_gain = _finite("rate_gain", rate_gain, 0.0)
        _require(self.angle_gain > 0, "angle_gain must be positive")

    def target_angle(self, x: float, vx: float) -> float:
        """rad: the tilt that turns the main engine's thrust against the offset ``x`` and the drift ``vx``."""
        return float(np.clip(self.position_gain * x + self.velocity_gain * vx, -self.max_tilt, self.max_tilt))

    def _act(self, state: np.ndarray) -> SkillOutput:
        x, vx, angle, rate = state
        target = self.target_angle(x, vx)
        lateral = attitude_command(angle, rate, target, self.angle_gain, self.rate_gain)
        info = {"target_angle": target, "angle_error": angle - target, "status": 0.0}
        return SkillOutput(np.array([0.0, lateral]), info)


class DescentRate(_LanderSkill):
    """The main engine holds the vertical speed at ``-min(max_speed, min_speed + altitude_gain * max(y, 0))``.

    The target slows the descent linearly with altitude down to ``min_speed`` at the pad's height; with
    ``min_speed = altitude_gain = 0`` the skill hovers (holds zero vertical speed). The law is
    ``main = clip(hover_throttle + gain * (vy_target - vy), -1, 1)``: below the target speed the engine fires (at
    least 50 % power once ``main > 0``), above it the engine is off. The side boosters stay off.

    Args:
        min_speed: vertical speed units (1 is 7.5 world units/s; 0.1 is 0.75 world units/s), >= 0: the
            target descent speed at the pad's height.
        altitude_gain: descent speed per unit of altitude y.
        max_speed: the fastest target descent speed.
        gain: main command per unit of speed error.
        hover_throttle: the main command that about cancels gravity for the upright lander (gymnasium's engine gives
            0.87 of the lander's weight at 50 % power).

    ``act`` takes ``[y, vy]`` and returns ``[main, 0]``. Info: ``target_speed`` (vy units, negative downwards),
    ``speed_error`` (target - vy), ``status``.
    """

    state_keys = ("y", "vy")

    def __init__(
        self,
        min_speed: float = 0.05,
        altitude_gain: float = 0.5,
        max_speed: float = 0.6,
        gain: float = 10.0,
        hover_throttle: float = 0.15,
    ) -> None:
        self.min_speed = _finite("min_speed", min_speed, 0.0, 10.0)
        self.altitude_gain = _finite("altitude_gain", altitude_gain, 0.0)
        self.max_speed = _finite("max_speed", max_speed, self.min_speed, 10.0)
        self.gain = _finite("gain", gain, 0.0)
        _require(self.gain > 0, "gain must be positive")
        self.hover_throttle = _finite("hover_throttle", hover_throttle, -1.0, 1.0)

    def target_speed(self, y: float) -> float:
        """The target vertical speed at altitude ``y`` (vy units; negative is down)."""
        return -min(self.max_speed, self.min_speed + self.altitude_gain * max(float(y), 0.0))

    def _act(self, state: np.ndarray) -> SkillOutput:
        y, vy = state
        target = self.target_speed(y)
        main = float(np.clip(self.hover_throttle + self.gain * (target - vy), -1.0, 1.0))
        info = {"target_speed": target, "speed_error": target - vy, "status": 0.0}
        return SkillOutput(np.array([main, 0.0]), info)


class Touchdown(_LanderSkill):
    """Once either leg touches the ground, propose the main engine off (``[-1, 0]``); before that, ``[0, 0]``.

    Summed with a descent skill's command (at most 1), the main engine is then off at touchdown, so the lander settles
    and comes to rest (gymnasium's +100). ``act`` takes ``[left_leg_contact, right_leg_contact]`` (1.0 or 0.0).
    Info: ``contact`` (1.0 when either leg touches), ``status``.
    """

    state_keys = ("left_leg_contact", "right_leg_contact")

    def _act(self, state: np.ndarray) -> SkillOutput:
        contact = bool(np.any(state > 0.5))
        action = np.array([-1.0, 0.0]) if contact else np.zeros(2)
        return SkillOutput(action, {"contact": float(contact), "status": 0.0})
