"""A fast rasteriser for CarRacing's 96x96 state frames, drawing what gymnasium's ``state_pixels`` draws.

gymnasium draws every road polygon and grass patch of the whole track with pygame on a 1000x800 surface, flips
it, draws the indicator bar, then box-filters the surface down to 96x96 (``smoothscale``); 98% of a step's time
goes into the Python loop over polygons. This module draws the same scene straight at 96x96:

- the road area (output rows 0-83, source rows 0-700) by supersampling: every output pixel is the mean of
  ``samples x samples`` point samples, each the colour of the last polygon (in gymnasium's drawing order) that
  covers it. Polygons are transformed and culled in one compiled routine, so only the tiles in view cost anything;
- the indicator bar (rows 84-95, source rows 700-800) exactly: its rectangles are axis-aligned in the source, so the
  box filter's coverage of each output pixel is a product of two interval overlaps. pygame fills the pixels
  ``trunc(x0)..trunc(x1)`` inclusive; the model does the same;
- the reward counter with pygame's own font, rendered and box-filtered once per distinct text (cached).

Units: *world* coordinates are gymnasium's Box2D units; *source* coordinates are pixels of gymnasium's 1000x800
surface after its vertical flip (x right, y down); *output* coordinates are pixels of the 96x96 frame.
The difference to gymnasium's frames comes from pygame's own pixel rules (vertices truncated to integers, edges
filled inclusively, an anti-aliased outline): about a tenth of an output pixel along edges (bounds in the tests).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from typing import NamedTuple

import numba
import numpy as np
from gymnasium.envs.box2d import car_dynamics as cd

FRAME = 96  # output frame side, px
SOURCE_W, SOURCE_H = 1000, 800  # gymnasium's drawing surface (WINDOW_W, WINDOW_H), px
ROAD_ROWS = 84  # output rows above the indicator bar: source rows [0, 700) (700 = 800 - 5 * 800 / 40)
BAR_TOP = 700.0  # source row where the indicator bar starts
SCALE_X, SCALE_Y = FRAME / SOURCE_W, FRAME / SOURCE_H  # output px per source px
MAX_VERTS = 8  # the largest polygon (the car's hull) has 8 vertices
TEXT_COLS = 12  # the reward counter lies in source x [0, 125) = output columns 0-11 of the bar
GREY_WEIGHTS = np.array([0.299, 0.587, 0.114])  # ITU-R 601 luma, as PIL's "L" and OpenCV's RGB2GRAY
# The car's wheel stripes (gymnasium's car_dynamics): half width and radius of a wheel, world units; stripe colour.
WHEEL_W, WHEEL_R = cd.WHEEL_W * cd.SIZE, cd.WHEEL_R * cd.SIZE
WHEEL_WHITE = (float(cd.WHEEL_WHITE[0]), float(cd.WHEEL_WHITE[1]), float(cd.WHEEL_WHITE[2]))
# pygame's smoothscale truncates in both of its passes: a uniform area of value v comes out as v - 2 (v >= 2).
SMOOTHSCALE_BIAS = 2.0


class Polygons(NamedTuple):
    """Convex polygons in drawing order. ``vertices`` (P, MAX_VERTS, 2) world units, padded; ``counts`` (P,) number
    of vertices used; ``rgb`` (P, 3) colours 0-255 (may be a live table that the caller updates in place)."""

    vertices: np.ndarray
    counts: np.ndarray
    rgb: np.ndarray


def pack_polygons(polygons: Sequence[Sequence[Sequence[float]]], rgb: np.ndarray) -> Polygons:
    """Pack a list of polygons (each a list of (x, y) world points, 3 to ``MAX_VERTS`` of them) with their colours."""
    vertices = np.zeros((len(polygons), MAX_VERTS, 2))
    counts = np.zeros(len(polygons), np.int64)
    for i, poly in enumerate(polygons):
        points = np.asarray(poly, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2 or not 3 <= len(points) <= MAX_VERTS:
            raise ValueError(f"polygon {i} has shape {points.shape}; expected (3..{MAX_VERTS}, 2)")
        vertices[i, : len(points)] = points
        counts[i] = len(points)
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.shape != (len(polygons), 3):
        raise ValueError(f"rgb has shape {rgb.shape}; expected ({len(polygons)}, 3)")
    return Polygons(vertices, counts, rgb)


class Camera(NamedTuple):
    """gymnasium's view: ``source = zoom * R(angle) (world - (x, y)) + (500, 200)``, then flipped vertically.

    ``x, y`` world units (the car's position), ``angle`` rad (minus the car's heading), ``zoom`` source px per world
    unit (16.2 after the first second, smaller while gymnasium animates the zoom)."""

    x: float
    y: float
    angle: float
    zoom: float


# --------------------------------------------------------------------------------------------------- compiled core
@numba.njit(cache=True)
def _fill_convex(ids: np.ndarray, xs: np.ndarray, ys: np.ndarray, n: int, pid: int) -> None:
    """Write ``pid`` into every sample of ``ids`` (rows, cols) whose centre lies inside the convex polygon with
    vertices ``xs[:n], ys[:n]`` (in sample units). Half-open spans: samples on a shared edge belong to one side."""
    rows, cols = ids.shape
    y_lo, y_hi = ys[0], ys[0]
    for k in range(1, n):
        y_lo = min(y_lo, ys[k])
        y_hi = max(y_hi, ys[k])
    r0 = max(0, math.ceil(y_lo - 0.5))
    r1 = min(rows - 1, math.ceil(y_hi - 0.5) - 1)
    for r in range(r0, r1 + 1):
        yc = r + 0.5
        x_lo, x_hi = np.inf, -np.inf
        for k in range(n):
            xa, ya = xs[k], ys[k]
            xb, yb = xs[(k + 1) % n], ys[(k + 1) % n]
            if (ya <= yc < yb) or (yb <= yc < ya):
                x = xa + (yc - ya) * (xb - xa) / (yb - ya)
                x_lo = min(x_lo, x)
                x_hi = max(x_hi, x)
        if x_lo > x_hi:
            continue
        c0 = max(0, math.ceil(x_lo - 0.5))
        c1 = min(cols - 1, math.ceil(x_hi - 0.5) - 1)
        for c in range(c0, c1 + 1):
            ids[r, c] = pid


@numba.njit(cache=True)
def _draw_group(
    ids: np.ndarray,
    vertices: np.ndarray,
    counts: np.ndarray,
    first_id: int,
    cam: np.ndarray,
    samples: int,
    start: int = 0,
) -> None:
    """Transform polygons ``start..`` from world to sample units (gymnasium's camera and flip), cull those out of
    view, fill."""
    cx, cy, cos_a, sin_a, zoom = cam[0], cam[1], math.cos(cam[2]), math.sin(cam[2]), cam[3]
    sx, sy = SCALE_X * samples, SCALE_Y * samples
    rows, cols = ids.shape
    xs = np.empty(MAX_VERTS)
    ys = np.empty(MAX_VERTS)
    for p in range(start, vertices.shape[0]):
        n = counts[p]
        inside = False
        x_lo, x_hi, y_lo, y_hi = np.inf, -np.inf, np.inf, -np.inf
        for k in range(n):
            dx, dy = vertices[p, k, 0] - cx, vertices[p, k, 1] - cy
            src_x = zoom * (cos_a * dx - sin_a * dy) + SOURCE_W / 2
            src_y = zoom * (sin_a * dx + cos_a * dy) + SOURCE_H / 4
            xs[k] = src_x * sx
            ys[k] = (SOURCE_H - src_y) * sy  # gymnasium flips the surface vertically
            x_lo, x_hi = min(x_lo, xs[k]), max(x_hi, xs[k])
            y_lo, y_hi = min(y_lo, ys[k]), max(y_hi, ys[k])
        inside = x_hi > 0.0 and x_lo < cols and y_hi > 0.0 and y_lo < rows
        if inside:
            _fill_convex(ids, xs, ys, n, first_id + p)


@numba.njit(cache=True)
def _view_inside_square(cam: np.ndarray, half: float) -> bool:
    """Whether the road area of the view (source x 0-1000, flipped y 0-700) lies inside the world square
    ``|x|, |y| <= half`` (the playfield), by its four corners (the view and the square are both convex)."""
    cx, cy, cos_a, sin_a, zoom = cam[0], cam[1], math.cos(cam[2]), math.sin(cam[2]), cam[3]
    for src_x in (0.0, float(SOURCE_W)):
        for flipped_y in (0.0, BAR_TOP):
            dx, dy = (src_x - SOURCE_W / 2) / zoom, (SOURCE_H - flipped_y - SOURCE_H / 4) / zoom
            x = cx + cos_a * dx + sin_a * dy  # the inverse rotation R(-angle)
            y = cy - sin_a * dx + cos_a * dy
            if abs(x) > half or abs(y) > half:
                return False
    return True


@numba.njit(cache=True)
def _overlap(lo: float, hi: float, a: float, b: float) -> float:
    return max(0.0, min(hi, b) - max(lo, a))


@numba.njit(cache=True)
def _car_world(
    local: np.ndarray,
    counts: np.ndarray,
    body: np.ndarray,
    rgb: np.ndarray,
    poses: np.ndarray,
    phases: np.ndarray,
    out_vertices: np.ndarray,
    out_counts: np.ndarray,
    out_rgb: np.ndarray,
) -> int:
    """The car in world units, in ``Car.draw``'s order: each fixture of each body, a wheel's white stripe right
    after the wheel (gymnasium's rule on the wheel's phase). Returns the number of polygons written."""
    n = 0
    for q in range(local.shape[0]):
        b = body[q]
        c, s = math.cos(poses[b, 2]), math.sin(poses[b, 2])
        for k in range(counts[q]):
            x, y = local[q, k, 0], local[q, k, 1]
            out_vertices[n, k, 0] = c * x - s * y + poses[b, 0]
            out_vertices[n, k, 1] = s * x + c * y + poses[b, 1]
        out_counts[n] = counts[q]
        out_rgb[n, :] = rgb[q, :]
        n += 1
        if b >= phases.shape[0]:  # the hull: no stripe
            continue
        a1 = phases[b]
        a2 = a1 + 1.2
        s1, s2, c1, c2 = math.sin(a1), math.sin(a2), math.cos(a1), math.cos(a2)
        if s1 > 0 and s2 > 0:
            continue
        if s1 > 0:
            c1 = np.sign(c1)
        if s2 > 0:
            c2 = np.sign(c2)
        ys = (WHEEL_R * c1, WHEEL_R * c1, WHEEL_R * c2, WHEEL_R * c2)
        xs = (-WHEEL_W, WHEEL_W, WHEEL_W, -WHEEL_W)
        for k in range(4):
            out_vertices[n, k, 0] = c * xs[k] - s * ys[k] + poses[b, 0]
            out_vertices[n, k, 1] = s * xs[k] + c * ys[k] + poses[b, 1]
        out_counts[n] = 4
        out_rgb[n, 0], out_rgb[n, 1], out_rgb[n, 2] = WHEEL_WHITE
        n += 1
    return n


@numba.njit(cache=True)
def _indicator_rects(values: np.ndarray, rects: np.ndarray, rgb: np.ndarray) -> int:
    """gymnasium's ``_render_indicators`` as source pixel ranges ``x0, x1, y0, y1`` (inclusive; pygame truncates
    vertices to integers and fills edges inclusively). ``values``: true speed, the four wheels' omega, the front
    wheel's joint angle, the hull's angular velocity. Returns the number of rectangles (drawn when |value| > 1e-4)."""
    s, h, height = SOURCE_W / 40.0, SOURCE_H / 40.0, float(SOURCE_H)
    n = 0
    for k in range(7):
        value = values[k]
        if abs(value) <= 1e-4:
            continue
        if k < 5:  # vertical bars: speed, then the wheels' angular velocities
            place, val = (5.0, 0.02 * value) if k == 0 else (6.0 + k, 0.01 * value)
            xa, xb, ya, yb = place * s, (place + 1) * s, height - (h + h * val), height - h
        else:  # horizontal bars: steering, gyroscope
            place, val = (20.0, -10.0 * value) if k == 5 else (30.0, -0.8 * value)
            xa, xb, ya, yb = place * s, (place + val) * s, height - 4 * h, height - 2 * h
        xa, xb, ya, yb = float(int(xa)), float(int(xb)), float(int(ya)), float(int(yb))
        rects[n, 0], rects[n, 1] = min(xa, xb), max(xa, xb)
        rects[n, 2], rects[n, 3] = min(ya, yb), max(ya, yb)
        if k == 0:
            rgb[n, 0], rgb[n, 1], rgb[n, 2] = 255.0, 255.0, 255.0
        elif k < 3:
            rgb[n, 0], rgb[n, 1], rgb[n, 2] = 0.0, 0.0, 255.0
        elif k < 5:
            rgb[n, 0], rgb[n, 1], rgb[n, 2] = 51.0, 0.0, 255.0
        elif k == 5:
            rgb[n, 0], rgb[n, 1], rgb[n, 2] = 0.0, 255.0, 0.0
        else:
            rgb[n, 0], rgb[n, 1], rgb[n, 2] = 255.0, 0.0, 0.0
        n += 1
    return n


@numba.njit(cache=True)
def _frame(
    ids: np.ndarray,
    world_vertices: np.ndarray,
    world_counts: np.ndarray,
    world_rgb: np.ndarray,
    car_local: np.ndarray,
    car_counts: np.ndarray,
    car_body: np.ndarray,
    car_rgb: np.ndarray,
    poses: np.ndarray,
    phases: np.ndarray,
    cam: np.ndarray,
    indicators: np.ndarray,
    weights: np.ndarray,
    samples: int,
    field_half: float,
    text: np.ndarray,
    out: np.ndarray,
    acc: np.ndarray,
    lut: np.ndarray,
    car_vertices: np.ndarray,
    car_n: np.ndarray,
    car_world_rgb: np.ndarray,
) -> None:
    """Draw one frame into ``out`` (96, 96, C) uint8. ``weights`` (C, 3) maps RGB to the output channels, C = 1
    or 3. Work buffers (no allocation per frame): ``acc`` (96, 96, C) float, ``lut`` (>= 1 + P + 2Q, C), and the
    car's world polygons ``car_vertices`` (2Q, MAX_VERTS, 2), ``car_n`` (2Q,), ``car_world_rgb`` (2Q, 3)."""
    channels = weights.shape[0]
    n_world = world_vertices.shape[0]
    n_car = _car_world(car_local, car_counts, car_body, car_rgb, poses, phases, car_vertices, car_n, car_world_rgb)
    # Colour per polygon id (0: the surface's black); pygame truncates colour components to integers.
    lut[0, :] = 0.0
    for p in range(n_world + n_car):
        for ch in range(channels):
            value = 0.0
            for k in range(3):
                colour = world_rgb[p, k] if p < n_world else car_world_rgb[p - n_world, k]
                value += weights[ch, k] * float(int(colour))
            lut[1 + p, ch] = value
    # The first world polygon is the playfield, which usually fills the whole view: then it is a plain memset.
    start = 1 if field_half > 0 and _view_inside_square(cam, field_half) else 0
    ids[:, :] = start
    _draw_group(ids, world_vertices, world_counts, 1, cam, samples, start)
    _draw_group(ids, car_vertices[:n_car], car_n[:n_car], 1 + n_world, cam, samples)
    # Box filter: each output pixel is the mean of its samples' colours (each sample's id read once).
    acc[:, :, :] = 0.0
    inv = 1.0 / (samples * samples)
    for j in range(ROAD_ROWS):
        for i in range(FRAME):
            t0, t1, t2 = 0.0, 0.0, 0.0
            for sr in range(samples):
                row = j * samples + sr
                for sc in range(samples):
                    pid = ids[row, i * samples + sc]
                    t0 += lut[pid, 0]
                    if channels == 3:
                        t1 += lut[pid, 1]
                        t2 += lut[pid, 2]
            acc[j, i, 0] = t0 * inv
            if channels == 3:
                acc[j, i, 1] = t1 * inv
                acc[j, i, 2] = t2 * inv
    # The indicator bars, composited by exact box-filter coverage (they never overlap one another).
    rects = np.zeros((7, 4))
    rects_rgb = np.zeros((7, 3))
    n_rects = _indicator_rects(indicators, rects, rects_rgb)
    px_w, px_h = 1.0 / SCALE_X, 1.0 / SCALE_Y  # source px per output px
    for k in range(n_rects):
        x0, x1, y0, y1 = rects[k, 0], rects[k, 1] + 1.0, rects[k, 2], rects[k, 3] + 1.0
        j0, j1 = max(0, int(y0 * SCALE_Y)), min(FRAME - 1, int(y1 * SCALE_Y))
        i0, i1 = max(0, int(x0 * SCALE_X)), min(FRAME - 1, int(x1 * SCALE_X))
        for j in range(j0, j1 + 1):
            cover_y = _overlap(y0, y1, j * px_h, (j + 1) * px_h) / px_h
            if cover_y <= 0.0:
                continue
            for i in range(i0, i1 + 1):
                cover = cover_y * _overlap(x0, x1, i * px_w, (i + 1) * px_w) / px_w
                for ch in range(channels):
                    value = weights[ch, 0] * rects_rgb[k, 0] + weights[ch, 1] * rects_rgb[k, 1]
                    value += weights[ch, 2] * rects_rgb[k, 2]
                    acc[j, i, ch] += cover * (value - acc[j, i, ch])
    for j in range(ROAD_ROWS, FRAME):  # the reward counter, already box-filtered by pygame itself
        for i in range(text.shape[1]):
            for ch in range(channels):
                acc[j, i, ch] = text[j - ROAD_ROWS, i, ch] + SMOOTHSCALE_BIAS
    for j in range(FRAME):
        for i in range(FRAME):
            for ch in range(channels):
                value = acc[j, i, ch] - SMOOTHSCALE_BIAS + 0.5  # rounded half up below
                out[j, i, ch] = 0 if value < 1.0 else (255 if value >= 255.0 else np.uint8(value))


# --------------------------------------------------------------------------------------------------- the renderer
class CarShape(NamedTuple):
    """The car's polygons in its bodies' local frames, in ``Car.draw``'s order (wheels, then the hull's fixtures).

    ``vertices`` (Q, MAX_VERTS, 2) world units, ``counts`` (Q,), ``body`` (Q,) index into the per-frame body poses
    (the wheels are bodies ``0..W-1`` and get gymnasium's white stripe; higher indices get none), ``rgb`` (Q, 3)."""

    vertices: np.ndarray
    counts: np.ndarray
    body: np.ndarray
    rgb: np.ndarray


class CarRaster:
    """Draws CarRacing state frames. Give it the track with :meth:`set_world` and the car with :meth:`set_car` (once
    per episode), then call :meth:`render` every frame.

    Args:
        grey: draw one luma channel (``GREY_WEIGHTS``) instead of RGB; frames are then (96, 96, 1).
        channel: draw one channel of the RGB frame instead (0 red, 1 green, 2 blue; overrides ``grey``); frames
            are then (96, 96, 1) (the paper's grass test reads the green channel).
        samples: point samples per output pixel along each axis (``samples**2`` a pixel).
        text_cache: distinct reward texts kept.
    """

    def __init__(self, grey: bool = False, samples: int = 3, text_cache: int = 512, channel: int | None = None) -> None:
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        if channel is not None and channel not in (0, 1, 2):
            raise ValueError(f"channel must be 0, 1 or 2, got {channel}")
        self.grey, self.samples = bool(grey) or channel is not None, int(samples)
        self.channels = 1 if self.grey else 3
        if channel is not None:
            self.weights = np.eye(3)[channel : channel + 1].copy()  # (1, 3): one RGB component
        else:
            self.weights = GREY_WEIGHTS[None, :].copy() if grey else np.eye(3)  # (C, 3): RGB -> output channels
        self._ids = np.zeros((ROAD_ROWS * self.samples, FRAME * self.samples), np.int16)  # polygon id per sample
        self._world: Polygons | None = None
        self._car_max = 2 * 16  # room for 16 car polygons, each with its stripe (gymnasium's car has 8)
        self._acc = np.zeros((FRAME, FRAME, self.channels))
        self._car_vertices = np.zeros((self._car_max, MAX_VERTS, 2))
        self._car_n = np.zeros(self._car_max, np.int64)
        self._car_rgb = np.zeros((self._car_max, 3))
        self._field_half = 0.0
        self._car: CarShape | None = None
        self._text_cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._text_cache_size = int(text_cache)
        self._font = None

    @property
    def world(self) -> Polygons | None:
        """The static scene given to :meth:`set_world` (None before)."""
        return self._world

    @property
    def car(self) -> CarShape | None:
        """The car given to :meth:`set_car` (None before)."""
        return self._car

    def set_world(self, world: Polygons, field_half: float = 0.0) -> None:
        """The static scene (background, grass, road and kerbs, in drawing order). ``world.rgb`` may be a live table
        the caller updates in place (gymnasium recolours a road tile when the car touches it): it is read per frame.

        ``field_half`` > 0 declares the first polygon to be the square ``|x|, |y| <= field_half`` (gymnasium's
        playfield): while it covers the whole view it is filled as one memset instead of polygon spans."""
        self._world, self._field_half = world, float(field_half)
        self._lut = np.zeros((1 + len(world.counts) + 2 * self._car_max, self.channels))

    def set_car(self, car: CarShape) -> None:
        if 2 * len(car.counts) > self._car_max:
            raise ValueError(f"a car of {len(car.counts)} polygons; at most {self._car_max // 2}")
        self._car = car

    def render(
        self, cam: Camera, poses: np.ndarray, phases: np.ndarray, indicators: np.ndarray, text: str
    ) -> np.ndarray:
        """One frame, (96, 96, C) uint8 (C = 1 grey or 3 RGB).

        Args:
            cam: the view.
            poses: (B, 3) the car's bodies ``x, y, angle`` (world units, rad).
            phases: (W,) the wheels' rotation phases, rad (their white stripes).
            indicators: (7,) what the bar shows: true speed, the four wheels' omega, the front wheel's joint angle,
                the hull's angular velocity (gymnasium's units).
            text: the reward counter, as gymnasium formats it.
        """
        if self._world is None or self._car is None:
            raise RuntimeError("CarRaster.render before set_world and set_car")
        world, car = self._world, self._car
        out = np.empty((FRAME, FRAME, self.channels), np.uint8)
        _frame(
            self._ids, world.vertices, world.counts, world.rgb, car.vertices, car.counts, car.body, car.rgb,
            poses, phases, np.array([cam.x, cam.y, cam.angle, cam.zoom]), indicators, self.weights, self.samples,
            self._field_half, self._text(text), out, self._acc, self._lut, self._car_vertices, self._car_n,
            self._car_rgb,
        )  # fmt: skip
        return out

    def _text(self, text: str) -> np.ndarray:
        """The bar's left 12x12 output pixels with the reward counter, (12, 12, C) float, as gymnasium draws it: the
        default font at 42 px, white on black, centred at source (60, 750), box-filtered from its 125x100 source
        pixels (125 = 12 output columns exactly, so the filter's pixel boundaries are gymnasium's)."""
        patch = self._text_cache.get(text)
        if patch is not None:
            self._text_cache.move_to_end(text)
            return patch
        import pygame

        if self._font is None:
            pygame.font.init()
            self._font = pygame.font.Font(pygame.font.get_default_font(), 42)
        surface = pygame.Surface((125, 100))
        surface.fill((0, 0, 0))
        glyphs = self._font.render(text, True, (255, 255, 255), (0, 0, 0))
        rect = glyphs.get_rect()
        rect.center = (60, 750 - int(BAR_TOP))
        surface.blit(glyphs, rect)
        small = pygame.transform.smoothscale(surface, (TEXT_COLS, FRAME - ROAD_ROWS))
        rgb = np.transpose(pygame.surfarray.array3d(small), (1, 0, 2)).astype(np.float64)
        patch = rgb @ self.weights.T
        self._text_cache[text] = patch
        if len(self._text_cache) > self._text_cache_size:
            self._text_cache.popitem(last=False)
        return patch
