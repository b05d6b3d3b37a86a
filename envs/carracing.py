"""gymnasium's CarRacing with fast frames: the paper's main experiment (HRTC §4, Table 1).

:class:`FastCarRacing` *is* gymnasium's ``CarRacing`` (a subclass: the same track generation, Box2D car, rewards
and termination, driven by the same code) with one override: the 96x96 ``state_pixels`` frame is drawn by
:class:`~envs.car_raster.CarRaster` instead of pygame: a step is 10-30x faster, measured side by side with gymnasium's
on the shared project machine (``scripts/bench_carracing_speed.py``, ``benchmarks/results/carracing/speed/``). Its
frames match gymnasium's within a mean absolute difference of 0.4 of 255 (bounds in ``tests/envs/test_carracing.py``).

:class:`CarRacingTask` is the task the trainer sees (registered as ``carracing``): greyscale frames, a stack of the
last ``frame_stack`` of them (oldest first), ``action_repeat`` physics frames per step (rewards summed, only the last
frame drawn), gymnasium's 1000-frame time limit counted in frames, and :meth:`CarRacingTask.skill_state`.
The action is gymnasium's: ``[steer, gas, brake]`` in ``[-1, 1] x [0, 1] x [0, 1]`` (steer -1 is full left).
Reward: -0.1 per frame, +1000/N per new tile of an N-tile track, -100 (and the end) when the car leaves the
playfield. Solved (the paper's rule): a mean return of 900 over 10 consecutive tracks.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.box2d import car_dynamics as cd
from gymnasium.envs.box2d import car_racing as cr
from gymnasium.utils import EzPickle

from envs.car_raster import FRAME, Camera, CarRaster, CarShape, pack_polygons
from envs.registry import register
from hrtc.errors import ConfigError

MAX_FRAMES = 1000  # gymnasium's registered time limit for CarRacing-v3, frames (one frame is 1/50 s)
# The reference protocol's constants (xtma/pytorch_car_caring train.py, Env.step and Env.reward_memory).
NO_PROGRESS_WINDOW = 100  # frames whose shaped rewards the early stop averages
NO_PROGRESS_MEAN = -0.1  # ...and the mean at or below which it ends the episode
GRASS_GREEN = 185.0  # a frame is "grass" when its green channel's mean exceeds this (0-255)
SOLVE_RETURN = 900.0  # the return both solve rules ask for, averaged over 10 (the paper) or 100 (gym) tracks
STATE_KEYS = ("speed", "forward_speed", "lateral_speed", "yaw_rate", "steering_angle", "heading", "position",
              "wheels_on_road", "progress", "track_heading_error", "track_offset", "track_turn_ahead")  # fmt: skip
TURN_AHEAD_POINTS = 12  # centre-line points (3.5 world units apart) over which track_turn_ahead measures the bend

_HULL_RGB = tuple(float(int(c * 255)) for c in (0.8, 0.0, 0.0))  # Car.draw: [int(c * 255) for c in obj.color]
_WHEEL_RGB = tuple(float(c) for c in cd.WHEEL_COLOR)


class FastCarRacing(cr.CarRacing):
    """gymnasium's ``CarRacing`` whose ``state_pixels`` frames come from :class:`~envs.car_raster.CarRaster`.

    Physics, track generation, rewards, termination and every other render mode are gymnasium's own code. Frames are
    (96, 96, 3) uint8 RGB as gymnasium's, or (96, 96) uint8 luma with ``grey=True`` (``GREY_WEIGHTS``).

    Args:
        grey: greyscale frames.
        samples: the rasteriser's point samples per pixel along each axis.
        **kwargs: gymnasium's ``CarRacing`` arguments (``lap_complete_percent``, ``domain_randomize``, ...).
    """

    def __init__(self, render_mode: str | None = None, *, grey: bool = False, samples: int = 3, **kwargs: Any) -> None:
        super().__init__(render_mode=render_mode, **kwargs)
        if not self.continuous:
            raise ConfigError("FastCarRacing supports continuous actions only (HRTC blends continuous actions)")
        self.grey = bool(grey)
        self.raster = CarRaster(grey=self.grey, samples=samples)
        self._green: CarRaster | None = None  # the green channel alone, one sample a pixel (green_mean)
        self._skip_frame = False  # set while repeating an action: gymnasium's step() then draws nothing
        self._car_id: int | None = None

    # ------------------------------------------------------------------ the scene
    def _create_track(self) -> bool:
        success = super()._create_track()
        if success:
            self._adopt_track()
        return success

    def _adopt_track(self) -> None:
        """Hand the new track to the rasteriser in gymnasium's drawing order (background, grass, road and kerbs).

        The road tiles' colours move into one table: gymnasium recolours a tile in place (``tile.color[:] = ...``)
        when the car touches it, so each tile's ``color`` (and its ``road_poly`` entry) becomes a view of a row of
        that table and the rasteriser reads the live colours without a per-frame Python loop."""
        b = cr.PLAYFIELD
        polygons = [[(b, b), (b, -b), (-b, -b), (-b, b)]]
        colours = [self.bg_color]
        g = cr.GRASS_DIM
        for x in range(-20, 20, 2):
            for y in range(-20, 20, 2):
                polygons.append([(g * x + g, g * y), (g * x, g * y), (g * x, g * y + g), (g * x + g, g * y + g)])
                colours.append(self.grass_color)
        first_road = len(polygons)
        for vertices, colour in self.road_poly:
            polygons.append(vertices)
            colours.append(np.asarray(colour, dtype=np.float64))
        world = pack_polygons(polygons, np.stack(colours))
        tiles = {id(tile.color): tile for tile in self.road}
        for k, (vertices, colour) in enumerate(self.road_poly):
            tile = tiles.get(id(colour))
            if tile is not None:
                view = world.rgb[first_road + k]
                tile.color = view
                self.road_poly[k] = (vertices, view)
        self.raster.set_world(world, field_half=cr.PLAYFIELD)
        if self._green is not None:
            self._green.set_world(world, field_half=cr.PLAYFIELD)

    def _adopt_car(self) -> None:
        """Hand the new car's shape to the rasteriser: every fixture's vertices in its body's frame (Box2D's order)."""
        car = self.car
        polygons, bodies, colours = [], [], []
        for index, body in enumerate(car.drawlist):  # the four wheels, then the hull
            for fixture in body.fixtures:
                polygons.append(list(fixture.shape.vertices))
                bodies.append(index)
                colours.append(_WHEEL_RGB if "phase" in body.__dict__ else _HULL_RGB)
        packed = pack_polygons(polygons, np.array(colours))
        shape = CarShape(packed.vertices, packed.counts, np.array(bodies, np.int64), packed.rgb)
        self.raster.set_car(shape)
        if self._green is not None:
            self._green.set_car(shape)
        self._car_id = id(car)

    def _camera(self) -> Camera:
        zoom = 0.1 * cr.SCALE * max(1 - self.t, 0) + cr.ZOOM * cr.SCALE * min(self.t, 1)  # gymnasium's zoom-in
        x, y = self.car.hull.position
        return Camera(float(x), float(y), -float(self.car.hull.angle), float(zoom))

    def draw_frame(self) -> np.ndarray:
        """The current ``state_pixels`` frame: (96, 96, 3) RGB or, with ``grey``, (96, 96), uint8."""
        frame = self._draw(self.raster)
        return frame[:, :, 0] if self.grey else frame

    def green_mean(self) -> float:
        """The mean of the green channel (0-255) of the current ``state_pixels`` frame, the whole 96x96 frame with
        its indicator bar, drawn with one sample a pixel (a frame's mean differs from the 3x3-sampled one's by about
        0.2 of 255). The reference's grass test: ``np.mean(frame[:, :, 1]) > 185``."""
        if self._green is None:
            self._green = CarRaster(channel=1, samples=1)
            self._adopt_track_to(self._green)
        return float(self._draw(self._green).mean())

    def _adopt_track_to(self, raster: CarRaster) -> None:
        if self.raster.world is not None:
            raster.set_world(self.raster.world, field_half=cr.PLAYFIELD)
        if self.raster.car is not None:
            raster.set_car(self.raster.car)

    def _draw(self, raster: CarRaster) -> np.ndarray:
        car = self.car
        if self._car_id != id(car):  # a new car each reset
            self._adopt_car()
        poses = np.array([(*body.position, body.angle) for body in car.drawlist])  # (5, 3) wheels then hull
        phases = np.array([wheel.phase for wheel in car.wheels])
        velocity = car.hull.linearVelocity
        indicators = np.array([math.sqrt(velocity[0] ** 2 + velocity[1] ** 2), *(w.omega for w in car.wheels),
                               car.wheels[0].joint.angle, car.hull.angularVelocity])  # fmt: skip
        return raster.render(self._camera(), poses, phases, indicators, f"{self.reward:04.0f}")

    def _render(self, mode: str) -> Any:
        if mode != "state_pixels":
            return super()._render(mode)
        if "t" not in self.__dict__ or self._skip_frame:
            return None
        return self.draw_frame()

    def gym_frame(self) -> np.ndarray:
        """The frame gymnasium itself draws for the current state, (96, 96, 3) uint8 (slow: for tests)."""
        return super()._render("state_pixels")

    # ------------------------------------------------------------------ named state
    def skill_state(self) -> dict[str, np.ndarray]:
        """Named quantities of the current state, each a float64 array (world units: a track is 40/6 = 6.7 wide):

        ``speed`` (1,) world units/s; ``forward_speed``, ``lateral_speed`` (1,) along the car's nose and to its
        right; ``yaw_rate`` (1,) rad/s, counter-clockwise; ``steering_angle`` (1,) rad of the front-left wheel,
        positive left; ``heading`` (1,) rad; ``position`` (2,) world units; ``wheels_on_road`` (1,) 0-4;
        ``progress`` (1,) fraction of the track's tiles visited. Relative to the track's centre line at its point
        nearest the car (privileged: the frames show the road, not its centre line): ``track_heading_error`` (1,)
        rad from the car's nose to the centre line's direction, counter-clockwise (positive: the road turns left of
        the nose); ``track_offset`` (1,) world units, positive left of the centre line; ``track_turn_ahead`` (1,)
        rad, the largest change of the centre line's direction over the next :data:`TURN_AHEAD_POINTS` points
        (~42 world units; 0 on a straight)."""
        car = self.car
        if car is None:
            raise RuntimeError("skill_state() before reset()")
        vx, vy = car.hull.linearVelocity
        heading = float(car.hull.angle)
        heading_error, offset, turn = self._track_relative(np.array(car.hull.position, dtype=np.float64), heading)
        forward = np.array([-math.sin(heading), math.cos(heading)])  # the car's nose points along local +y
        velocity = np.array([vx, vy], dtype=np.float64)
        return {
            "speed": np.array([np.hypot(vx, vy)]),
            "forward_speed": np.array([velocity @ forward]),
            "lateral_speed": np.array([velocity @ np.array([forward[1], -forward[0]])]),
            "yaw_rate": np.array([float(car.hull.angularVelocity)]),
            "steering_angle": np.array([float(car.wheels[0].joint.angle)]),
            "heading": np.array([heading]),
            "position": np.array(car.hull.position, dtype=np.float64),
            "wheels_on_road": np.array([float(sum(1 for w in car.wheels if w.tiles))]),
            "progress": np.array([self.tile_visited_count / max(len(self.track), 1)]),
            "track_heading_error": np.array([heading_error]),
            "track_offset": np.array([offset]),
            "track_turn_ahead": np.array([turn]),
        }

    def _track_relative(self, position: np.ndarray, heading: float) -> tuple[float, float, float]:
        """(heading error, offset, turn ahead) of the car against the centre line (see :meth:`skill_state`)."""
        if getattr(self, "_centre_of", None) is not self.track:  # a new track each reset: everything per point, once
            centre = np.array([(t[2], t[3]) for t in self.track], dtype=np.float64)
            steps = np.roll(centre, -1, axis=0) - centre  # the centre line runs in the direction the car drives
            direction = np.arctan2(steps[:, 1], steps[:, 0])
            ahead = direction[(np.arange(len(centre))[:, None] + np.arange(TURN_AHEAD_POINTS)) % len(centre)]
            turn = np.max(np.abs(np.unwrap(ahead, axis=1) - ahead[:, :1]), axis=1)
            self._centre, self._direction, self._turn, self._centre_of = centre, direction, turn, self.track
        nearest = int(np.argmin(((self._centre - position) ** 2).sum(1)))
        along = float(self._direction[nearest])
        dx, dy = position - self._centre[nearest]
        offset = math.cos(along) * dy - math.sin(along) * dx
        heading_error = math.remainder(along - (heading + math.pi / 2), math.tau)  # the nose: the body's +y
        return heading_error, float(offset), float(self._turn[nearest])


class CarRacingTask(FastCarRacing):
    """The ``carracing`` task: stacked greyscale frames, action repeat, gymnasium's time limit in frames.

    Observation: the last ``frame_stack`` greyscale frames, oldest first, uint8; flattened to
    ``(frame_stack * 96 * 96,)`` (the trainer's buffers are flat; :attr:`frame_shape` says how to reshape) or
    ``(frame_stack, 96, 96)`` with ``flatten=False``. After a reset the stack holds copies of the first frame.

    Args:
        action_repeat: physics frames per step; rewards summed, the episode ends at the first terminal frame.
        frame_stack: frames in an observation.
        max_frames: the time limit in physics frames (truncation).
        flatten: flat observations.
        episode_log: if set, a CSV file that gets one line per finished episode (appended, safe across processes):
            ``wall_time, pid, reset_seed (-1 when reset without a seed), return, frames, lap_finished, true_return,
            early_stop``: ``return`` is the (shaped) score the learner saw, ``true_return`` gymnasium's reward.
        early_stop: end the episode (truncated, ``info["early_stop"]``) at the first frame where the mean of the
            last 100 frames' shaped rewards (zeros before the episode's 100th frame) is <= -0.1: about 100 frames
            without a new tile.
        grass_penalty: subtracted from every frame whose 96x96 view is mostly grass (its green channel's mean
            above 185, :meth:`FastCarRacing.green_mean`; this draws every frame).
        end_bonus: added on the frame where gymnasium's own rules end the episode: a finished lap, leaving the
            playfield (its -100 then nets 0) or the ``max_frames`` time limit (gym 0.10's ``TimeLimit`` reported it
            as the end, and the reference added the bonus to it as well).
        **kwargs: :class:`FastCarRacing`'s and gymnasium's arguments (``lap_complete_percent=1.0`` needs every
            tile, as gym 0.10's CarRacing-v0 did; gymnasium's default 0.95).

    The last three are the reference protocol (xtma/pytorch_car_caring ``train.py``, ``Env.step``, which the paper's
    network follows); all off by default (gymnasium's protocol). Rewards are shaped per frame in the reference's
    order: bonus, grass penalty, then the early-stop test on the shaped reward. ``info["true_reward"]`` is always
    gymnasium's reward of the step, summed over its frames.
    """

    def __init__(
        self,
        render_mode: str | None = None,
        *,
        action_repeat: int = 1,
        frame_stack: int = 4,
        max_frames: int = MAX_FRAMES,
        flatten: bool = True,
        episode_log: str | None = None,
        early_stop: bool = False,
        grass_penalty: float = 0.0,
        end_bonus: float = 0.0,
        **kwargs: Any,
    ) -> None:
        kwargs.setdefault("grey", True)
        if not kwargs["grey"]:
            raise ConfigError("the carracing task observes greyscale frames")
        for name, value in (("action_repeat", action_repeat), ("frame_stack", frame_stack), ("max_frames", max_frames)):
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        for name, value in (("grass_penalty", grass_penalty), ("end_bonus", end_bonus)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"{name} must be a finite number, got {value!r}")
        if not isinstance(early_stop, bool):
            raise ConfigError(f"early_stop must be true or false, got {early_stop!r}")
        super().__init__(render_mode=render_mode, **kwargs)
        EzPickle.__init__(self, render_mode=render_mode, action_repeat=action_repeat, frame_stack=frame_stack,
                          max_frames=max_frames, flatten=flatten, episode_log=episode_log, early_stop=early_stop,
                          grass_penalty=grass_penalty, end_bonus=end_bonus, **kwargs)  # fmt: skip
        self.action_repeat, self.max_frames, self.episode_log = action_repeat, max_frames, episode_log
        self.early_stop, self.grass_penalty, self.end_bonus = early_stop, float(grass_penalty), float(end_bonus)
        self._recent = np.zeros(NO_PROGRESS_WINDOW)  # the last frames' shaped rewards (early_stop), a ring
        self.frame_shape = (frame_stack, FRAME, FRAME)
        self._stack = np.zeros(self.frame_shape, np.uint8)
        shape = (int(np.prod(self.frame_shape)),) if flatten else self.frame_shape
        self.observation_space = gym.spaces.Box(0, 255, shape, np.uint8)
        self._flatten = flatten
        self.frames, self.episode_return, self.true_return, self._reset_seed = 0, 0.0, 0.0, -1

    def _observation(self) -> np.ndarray:
        return self._stack.reshape(-1).copy() if self._flatten else self._stack.copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self._skip_frame = True  # gymnasium's reset steps once without an action: its frame is drawn below
        try:
            super().reset(seed=seed, options=options)
        finally:
            self._skip_frame = False
        self._stack[:] = self.draw_frame()
        self.frames, self.episode_return, self.true_return = 0, 0.0, 0.0
        self._recent[:] = 0.0
        self._reset_seed = -1 if seed is None else int(seed)
        return self._observation(), {}

    def step(self, action: np.ndarray | None) -> tuple[np.ndarray, float, bool, bool, dict]:
        if action is None:  # gymnasium's reset() takes this step itself
            return super().step(None)
        action = np.asarray(action, dtype=np.float32)
        total, true_total, terminated, stopped, info = 0.0, 0.0, False, False, {}
        self._skip_frame = True
        try:
            for _ in range(self.action_repeat):
                _, reward, terminated, _, info = super().step(action)
                self.frames += 1
                true_total += float(reward)
                ended = terminated or self.frames >= self.max_frames
                shaped = float(reward) + (self.end_bonus if ended else 0.0)
                if self.grass_penalty and self.green_mean() > GRASS_GREEN:
                    shaped -= self.grass_penalty
                total += shaped
                if self.early_stop:
                    self._recent[(self.frames - 1) % NO_PROGRESS_WINDOW] = shaped
                    stopped = float(self._recent.mean()) <= NO_PROGRESS_MEAN
                if ended or stopped:
                    break
        finally:
            self._skip_frame = False
        truncated = self.frames >= self.max_frames or (stopped and not terminated)
        self._stack[:-1] = self._stack[1:]
        self._stack[-1] = self.draw_frame()
        self.episode_return += total
        self.true_return += true_total
        info = dict(info, frames=self.frames, true_reward=true_total)
        if stopped and not terminated:
            info["early_stop"] = True
        if terminated or truncated:
            self._log_episode(bool(info.get("lap_finished", False)), bool(info.get("early_stop", False)))
        return self._observation(), total, bool(terminated), bool(truncated), info

    def _log_episode(self, lap_finished: bool, early_stop: bool) -> None:
        if not self.episode_log:
            return
        fields = (f"{time.time():.3f}", os.getpid(), self._reset_seed, f"{self.episode_return:.4f}", self.frames,
                  int(lap_finished), f"{self.true_return:.4f}", int(early_stop))  # fmt: skip
        line = ",".join(str(f) for f in fields) + "\n"
        fd = os.open(self.episode_log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line.encode())  # one write of a short line under O_APPEND: atomic across processes
        finally:
            os.close(fd)


@dataclass(frozen=True)
class TrackFollowRule:
    """The hand-written reference over carracing's five static intents (:mod:`hrtc.references`): steer along the
    centre line, and gas on straights up to a speed that falls with the bend ahead. Privileged: it reads the track's
    centre line (``track_*`` of :meth:`FastCarRacing.skill_state`), which the learners see only as pixels.

    Steering (a Stanley controller, Thrun et al. 2006): ``u = gain * (heading_error - atan2(offset_gain * offset,
    speed + 1) - yaw_damping * yaw_rate)``; ``turn_left`` weighs ``clip(u, 0, 1)``, ``turn_right`` ``clip(-u, 0, 1)``.
    Speed: the target is ``top_speed / (1 + bend_slowdown * track_turn_ahead)``; ``accelerate`` is 1 below it while
    ``|u| < gas_steer_limit`` (gas in a turn spins the rear-driven car out), ``decelerate`` 1 above it by more than
    ``brake_margin``. ``hold`` stays 0. Defaults: tuned on tracks of seeds 1000-1005, by a random search over
    ~135 settings (``benchmarks/results/carracing/track_rule/``)."""

    gain: float = 0.65
    offset_gain: float = 1.2
    yaw_damping: float = 0.05
    top_speed: float = 100.0
    bend_slowdown: float = 0.9
    gas_steer_limit: float = 0.15
    brake_margin: float = 10.0

    def __call__(self, state: Mapping[str, np.ndarray]) -> Mapping[str, float]:
        speed = float(state["speed"][0])
        u = self.gain * (float(state["track_heading_error"][0])
                         - math.atan2(self.offset_gain * float(state["track_offset"][0]), speed + 1.0)
                         - self.yaw_damping * float(state["yaw_rate"][0]))  # fmt: skip
        target = self.top_speed / (1.0 + self.bend_slowdown * float(state["track_turn_ahead"][0]))
        return {"turn_left": min(1.0, max(0.0, u)), "turn_right": min(1.0, max(0.0, -u)),
                "accelerate": float(speed < target and abs(u) < self.gas_steer_limit),
                "decelerate": float(speed > target + self.brake_margin), "hold": 0.0}  # fmt: skip


def pursuit_driver(env: cr.CarRacing, rng: np.random.Generator, mode: str = "road", noise: float = 0.3) -> np.ndarray:
    """A reference driver for tests and benchmarks (not a skill). ``road``: pure pursuit of the track's centre line 6
    tiles ahead, with ``noise`` on the steering; ``wild``: random actions that spin off onto the grass."""
    if mode == "wild":
        brake = rng.uniform(0, 0.3) * (rng.random() < 0.2)
        return np.array([rng.uniform(-1, 1), rng.uniform(0, 1), brake], np.float32)
    car = env.car
    pos, heading = np.array(car.hull.position), car.hull.angle
    centre = np.array([(t[2], t[3]) for t in env.track])
    target = centre[(int(np.argmin(((centre - pos) ** 2).sum(1))) + 6) % len(centre)]
    forward, to_target = np.array([-math.sin(heading), math.cos(heading)]), target - pos
    angle = math.atan2(forward[0] * to_target[1] - forward[1] * to_target[0], forward @ to_target)
    speed = math.hypot(*car.hull.linearVelocity)
    steer = float(np.clip(-2.0 * angle + noise * rng.normal(), -1, 1))
    return np.array([steer, 0.6 if speed < 60 else 0.0, 0.0 if speed < 70 else 0.5], np.float32)


# The reference protocol (xtma/pytorch_car_caring train.py, Env.step) on gymnasium's CarRacing: the early stop on
# no progress, -0.05 a grass frame, +100 at gym's own end, and every tile for a lap (gym 0.10's CarRacing-v0).
REFERENCE_PROTOCOL: dict[str, Any] = {"early_stop": True, "grass_penalty": 0.05, "end_bonus": 100.0,
                                      "lap_complete_percent": 1.0}  # fmt: skip


@register("carracing")
def carracing(**kwargs: Any) -> CarRacingTask:
    """gymnasium's CarRacing-v3 (continuous) with fast greyscale frames, a 4-frame stack and action repeat."""
    return CarRacingTask(**kwargs)


@register("carracing_paper")
def carracing_paper(**kwargs: Any) -> CarRacingTask:
    """``carracing`` under the reference protocol (:data:`REFERENCE_PROTOCOL`; each setting may be overridden)."""
    return CarRacingTask(**{**REFERENCE_PROTOCOL, **kwargs})
