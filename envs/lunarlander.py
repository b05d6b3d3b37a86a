"""gymnasium's LunarLander-v3 with continuous actions, with the named quantities skills read.

The task is gymnasium's own (``LunarLander(continuous=True)`` in a 1000-step ``TimeLimit``, as ``gym.make`` builds
it): same physics, reward, observation and action. :meth:`LunarLanderTask.skill_state` names the observation's
entries, in the units gymnasium's observation uses (not SI; the factors are gymnasium's constants):

| name | unit (from the Box2D body's position ``p`` and velocity ``v``, world units) |
|---|---|
| ``x`` | half viewport widths from the pad centre, ``(px - 10) / 10``; ``abs(x) >= 1`` ends the episode |
| ``y`` | half viewport heights above the resting height on the pad, ``(py - 3.93) / 6.67`` (0 landed, 1.4 at start) |
| ``vx`` | ``vx * 10 / 50``: 1 is 5 world units/s, i.e. 0.5 x units per second (gymnasium's scaling) |
| ``vy`` | ``vy * 6.67 / 50``: 1 is 7.5 world units/s, i.e. 1.125 y units per second |
| ``angle`` | rad, 0 upright, positive counter-clockwise (a positive angle tips the main engine's thrust towards -x) |
| ``angular_velocity`` | ``20 omega / 50`` with omega in rad/s: 1 is 2.5 rad/s; positive counter-clockwise |
| ``left_leg_contact``, ``right_leg_contact`` | 1.0 when the leg touches the ground, else 0.0 |

(World units: the viewport is 20 x 13.3 of them; gravity is -10 world units/s^2; the pad is ``abs(x) < 0.2``.)
The action is ``[main, lateral]`` in [-1, 1]^2: main ``<= 0`` is off, ``(0, 1]`` throttles 50-100 %; lateral
``abs(.) <= 0.5`` is off, ``< -0.5`` fires the left booster (turns the lander counter-clockwise), ``> 0.5`` the right.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.box2d import lunar_lander as ll

from envs.registry import register
from hrtc.errors import ConfigError, ShapeError

FPS = ll.FPS  # env steps per second (one step is 0.02 s)
HALF_W = ll.VIEWPORT_W / ll.SCALE / 2  # world units: x = (px - HALF_W) / HALF_W
HALF_H = ll.VIEWPORT_H / ll.SCALE / 2  # world units
STATE_KEYS = ("x", "y", "vx", "vy", "angle", "angular_velocity", "left_leg_contact", "right_leg_contact")
MAX_EPISODE_STEPS = 1000  # gymnasium's registered time limit for LunarLander-v3


class LunarLanderTask(ll.LunarLander):
    """``LunarLander(continuous=True)`` plus :meth:`skill_state` and :meth:`set_state` (for tests and demos)."""

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        kwargs.setdefault("continuous", True)
        if not kwargs["continuous"]:
            raise ConfigError("the lunarlander task is the continuous variant (HRTC blends continuous actions)")
        super().__init__(render_mode=render_mode, **kwargs)

    def skill_state(self) -> dict[str, np.ndarray]:
        """The named quantities of the current state (the table in the module doc), each a (1,) float64 array.

        Computed from the Box2D bodies in float64 with gymnasium's own formulas: equal to the last observation up to
        its float32 rounding."""
        if self.lander is None:
            raise RuntimeError("skill_state() before reset()")
        pos, vel = self.lander.position, self.lander.linearVelocity
        values = (
            (pos.x - HALF_W) / HALF_W,
            (pos.y - (self.helipad_y + ll.LEG_DOWN / ll.SCALE)) / HALF_H,
            vel.x * HALF_W / FPS,
            vel.y * HALF_H / FPS,
            self.lander.angle,
            20.0 * self.lander.angularVelocity / FPS,
            1.0 if self.legs[0].ground_contact else 0.0,
            1.0 if self.legs[1].ground_contact else 0.0,
        )
        return {k: np.array([float(v)]) for k, v in zip(STATE_KEYS, values, strict=True)}

    def set_state(
        self,
        x: float,
        y: float,
        vx: float = 0.0,
        vy: float = 0.0,
        angle: float = 0.0,
        angular_velocity: float = 0.0,
    ) -> np.ndarray:
        """Move the lander (body and legs, rigidly) to a state given in the observation's units (module doc).

        Call after ``reset``. The next step's reward carries no shaping difference (the jump is not the agent's
        doing). Returns the observation of the new state (8,) float32.
        """
        if self.lander is None:
            raise RuntimeError("set_state() before reset()")
        values = np.array([x, y, vx, vy, angle, angular_velocity], dtype=np.float64)
        if not np.all(np.isfinite(values)):
            raise ShapeError(f"set_state needs finite values, got {values}")
        centre = np.array([x * HALF_W + HALF_W, y * HALF_H + self.helipad_y + ll.LEG_DOWN / ll.SCALE])
        velocity = np.array([vx * FPS / HALF_W, vy * FPS / HALF_H])  # world units/s
        omega = angular_velocity * FPS / 20.0  # rad/s
        old_centre = np.array(self.lander.position)
        turn = angle - self.lander.angle
        rotation = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
        for body in (self.lander, *self.legs):
            offset = rotation @ (np.array(body.position) - old_centre)  # from the lander's centre, world units
            body.position = tuple(centre + offset)
            body.angle = body.angle + turn
            body.linearVelocity = tuple(velocity + omega * np.array([-offset[1], offset[0]]))  # v + omega x r
            body.angularVelocity = omega
            body.awake = True
        self.prev_shaping = None
        return self.observation()

    def observation(self) -> np.ndarray:
        """The current observation (8,) float32, as ``step`` would return it."""
        return np.concatenate(list(self.skill_state().values())).astype(np.float32)


@register("lunarlander")
def lunarlander(time_limit: float | None = None, **kwargs: Any) -> gym.Env:
    """Land softly on the pad; 1000 steps of 0.02 s at most; solved at a mean return of 200.

    Args:
        time_limit: episode length in seconds (default 20 s, gymnasium's 1000 steps).
        kwargs: passed to ``LunarLander`` (``gravity``, ``enable_wind``, ``wind_power``, ``turbulence_power``,
            ``render_mode``).
    """
    steps = MAX_EPISODE_STEPS if time_limit is None else max(1, round(float(time_limit) * FPS))
    return gym.wrappers.TimeLimit(LunarLanderTask(**kwargs), max_episode_steps=steps)


class GymnasiumHeuristic:
    """gymnasium's own landing heuristic (the controller the skills take apart) as a benchmark reference: not a rule
    over the skills but a controller of the task itself (``acts_on_env``, see :mod:`hrtc.benchmark.metrics`)."""

    acts_on_env = True

    def act(self, env: gym.Env, obs: np.ndarray) -> np.ndarray:
        return ll.heuristic(env.unwrapped, obs).astype(np.float32)
