"""Predictive sampling on the task's own MuJoCo model: a derivative-free MPC for the acrobot.

Predictive sampling (Howell et al., "Predictive Sampling: Real-time Behaviour Synthesis with MuJoCo", 2022, the
planner of MuJoCo MPC) keeps a nominal control trajectory as a spline with ``spline_points`` knots over the
horizon. Each call it shifts the nominal by the time elapsed since the last call, draws ``samples - 1`` Gaussian
perturbations of its knots (clipped to the control range), rolls every candidate out open-loop from the measured
state on a copy of the task's MuJoCo model (``mujoco.rollout``, the model's own integrator at the planner's step
``dt``), and keeps the cheapest candidate, the unperturbed nominal included, as the next nominal. It proposes the
nominal's control at the current time.

The cost is the one MuJoCo MPC's acrobot task uses (the same model, the tip on the target 4 m up), summed over the
horizon's steps of ``dt`` s:

    w_distance |tip - target|^2 + w_velocity |q_dot|^2 + w_control u^2   (m, rad/s, control units).

Measured on the task (README): from dm_control's random starts it brings the tip to the target in 2-7 s, but it
does not hold it there: the open-loop candidates of a 2 s horizon diverge from the unstable upright, so it keeps the
upper link up while the lower one loops round, and the tip passes the target again and again. From hanging exactly
at rest it finds only the local minimum of its cost with the lower link inverted on the hanging upper one (the tip
2 m from the target); no sampled 2 s plan pumps out of it. A partial skill, then: a swing-up towards the target.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import SkillOutput

STATUS_OK = 0
STATUS_NONFINITE_STATE = 3  # the state had NaN / inf; the action is zero (codes shared with skills.nmpc)


def _interpolation_matrix(knots: int, steps: int, horizon: float) -> np.ndarray:
    """(knots, steps): the controls at the ``steps`` step starts are ``knot_values @ B`` (linear interpolation
    between knots spaced evenly over ``[0, horizon]``, the last knot at the horizon's end)."""
    knot_times = np.linspace(0.0, horizon, knots)
    step_times = np.arange(steps) * (horizon / steps)
    basis = np.zeros((knots, steps))
    for j, t in enumerate(step_times):
        k = min(int(np.searchsorted(knot_times, t, side="right")) - 1, knots - 2)
        a = (t - knot_times[k]) / (knot_times[k + 1] - knot_times[k])
        basis[k, j], basis[k + 1, j] = 1.0 - a, a
    return basis


class AcrobotPredictiveSampling:
    """Predictive-sampling MPC for dm_control's acrobot on a copy of its MuJoCo model.

    Args:
        model: a task name for ``envs.mj_model`` or a ``mujoco.MjModel`` of dm_control's acrobot (joints
            ``shoulder`` and ``elbow``, sites ``tip`` and ``target``).
        horizon: s, the planning horizon.
        dt: s, the planner's model step (the model's own integrator; dm_control's is RK4 at 0.01 s).
        spline_points: knots of the control spline over the horizon (linear interpolation).
        samples: candidate trajectories per call, the nominal included.
        noise: standard deviation(s) of the knots' perturbations, control units; with several, the candidates take
            them in turn (small ones refine the plan, large ones find new swings).
        call_interval: s between calls (``every`` env steps of the task); the nominal is shifted by it.
        w_distance, w_velocity, w_control: cost weights (1/m^2, s^2/rad^2, per control unit^2).

    ``act`` takes ``[shoulder_angle, elbow_angle (rad), shoulder_velocity, elbow_velocity (rad/s)]`` (MuJoCo's
    ``qpos`` and ``qvel``) and returns u (1,) in the control range. Info: ``solve_ms`` (wall time of the call, ms),
    ``cost`` (the chosen candidate's), ``improvement`` (the nominal's cost minus the chosen one's, >= 0),
    ``status`` (0 ok, 3 non-finite state).
    """

    state_keys: tuple[str, ...] = ("shoulder_angle", "elbow_angle", "shoulder_velocity", "elbow_velocity")

    def __init__(
        self,
        model: str | Any = "acrobot_swingup",
        horizon: float = 2.0,
        dt: float = 0.05,
        spline_points: int = 10,
        samples: int = 64,
        noise: float | Sequence[float] = (0.05, 0.3),
        call_interval: float = 0.05,
        w_distance: float = 50.0,
        w_velocity: float = 0.1,
        w_control: float = 0.05,
    ) -> None:
        import envs

        scales = np.atleast_1d(np.asarray(noise, dtype=np.float64))
        if scales.ndim != 1 or not np.all(np.isfinite(scales) & (scales > 0)):
            raise ConfigError(f"noise must be a positive number or a list of them, got {noise!r}")
        for name, value in (("horizon", horizon), ("dt", dt), ("call_interval", call_interval)):
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be positive and finite, got {value!r}")
        for name, value in (("w_distance", w_distance), ("w_velocity", w_velocity), ("w_control", w_control)):
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be >= 0 and finite, got {value!r}")
        for name, value, least in (("spline_points", spline_points, 2), ("samples", samples, 1)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
                raise ConfigError(f"{name} must be an integer >= {least}, got {value!r}")
        steps = int(round(horizon / dt))
        if steps < 1 or abs(steps * dt - horizon) > 1e-9 * max(1.0, horizon):
            raise ConfigError(f"horizon {horizon} s must be a whole number of planner steps of {dt} s")
        mj_model = envs.mj_model(model)
        ids = {
            (kind, name): mujoco.mj_name2id(mj_model, obj, name)
            for kind, obj, names in (
                ("joint", mujoco.mjtObj.mjOBJ_JOINT, ("shoulder", "elbow")),
                ("site", mujoco.mjtObj.mjOBJ_SITE, ("tip", "target")),
                ("body", mujoco.mjtObj.mjOBJ_BODY, ("upper_arm", "lower_arm")),
            )
            for name in names
        }
        if min(ids.values()) < 0 or mj_model.nq != 2 or mj_model.nu != 1:
            raise ConfigError("model must be dm_control's acrobot (joints shoulder, elbow; sites tip, target)")
        self.model = copy.deepcopy(mj_model)  # the planner's own copy: its step may differ from the task's
        self.model.opt.timestep = float(dt)
        self.data = mujoco.MjData(self.model)
        # forward kinematics of the tip in the x-z plane (hinges about +y take +z towards +x)
        self._shoulder = np.asarray(mj_model.body_pos[ids["body", "upper_arm"]])[[0, 2]]
        self._l1 = float(mj_model.body_pos[ids["body", "lower_arm"]][2])
        self._l2 = float(mj_model.site_pos[ids["site", "tip"]][2])
        self._target = np.asarray(mj_model.site_pos[ids["site", "target"]])[[0, 2]]
        self.control_min, self.control_max = (float(v) for v in mj_model.actuator_ctrlrange[0])
        self.horizon, self.dt, self.steps = float(horizon), float(dt), steps
        self.samples, self.call_interval = int(samples), float(call_interval)
        # the perturbed candidates' noise scales, taken in turn: small ones refine a plan, large ones find new swings
        self._scales = np.resize(scales, self.samples - 1)[:, None]  # (S - 1, 1)
        self.weights = (float(w_distance), float(w_velocity), float(w_control))
        self._knot_times = np.linspace(0.0, horizon, int(spline_points))
        self._basis = _interpolation_matrix(int(spline_points), steps, horizon)  # (P, H)
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self._nstate = mujoco.mj_stateSize(self.model, self._spec)
        self._rng = np.random.default_rng(0)
        self._nominal: np.ndarray | None = None  # (P,) knot values

    def reset(self, rng: np.random.Generator) -> None:
        """Forget the nominal plan; perturbations are drawn from ``rng`` from now on."""
        self._rng, self._nominal = rng, None

    def tip(self, qpos: np.ndarray) -> np.ndarray:
        """Tip position(s) (x, z), m, for ``qpos`` (..., 2)."""
        q1, q12 = qpos[..., 0], qpos[..., 0] + qpos[..., 1]
        x = self._shoulder[0] + self._l1 * np.sin(q1) + self._l2 * np.sin(q12)
        z = self._shoulder[1] + self._l1 * np.cos(q1) + self._l2 * np.cos(q12)
        return np.stack([x, z], axis=-1)

    def rollout_costs(self, state: np.ndarray, knots: np.ndarray) -> np.ndarray:
        """Cost of each candidate (S,) for knot values ``knots`` (S, P) from ``state`` (4,)."""
        controls = knots @ self._basis  # (S, H)
        self.data.qpos[:], self.data.qvel[:] = state[:2], state[2:]
        self.data.time = 0.0
        initial = np.empty(self._nstate)
        mujoco.mj_getState(self.model, self.data, initial, self._spec)
        states, _ = mujoco.rollout.rollout(
            self.model, self.data, np.tile(initial, (len(knots), 1)), controls[:, :, None]
        )  # (S, H, nstate): time, qpos, qvel
        qpos, qvel = states[:, :, 1:3], states[:, :, 3:5]
        w_d, w_v, w_u = self.weights
        distance = np.sum((self.tip(qpos) - self._target) ** 2, axis=-1)  # (S, H), m^2
        return (w_d * distance + w_v * np.sum(qvel**2, axis=-1) + w_u * controls**2).sum(axis=1) * self.dt

    def act(self, state: np.ndarray) -> SkillOutput:
        """Plan from ``state`` (4,) ordered as ``state_keys``; propose the best plan's first control (1,)."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (4,):
            raise ShapeError(f"AcrobotPredictiveSampling expects a state of shape (4,) ordered {self.state_keys}, "
                             f"got {state.shape}")  # fmt: skip
        if not np.all(np.isfinite(state)):
            info = {"solve_ms": 0.0, "cost": 0.0, "improvement": 0.0, "status": float(STATUS_NONFINITE_STATE)}
            return SkillOutput(np.zeros(1), info)
        start = time.perf_counter()
        if self._nominal is None:
            nominal = np.zeros(len(self._knot_times))
        else:  # the old spline, evaluated call_interval later (held at its last knot past the horizon)
            nominal = np.interp(self._knot_times + self.call_interval, self._knot_times, self._nominal)
        candidates = np.tile(nominal, (self.samples, 1))
        candidates[1:] += self._scales * self._rng.standard_normal((self.samples - 1, len(nominal)))
        candidates = np.clip(candidates, self.control_min, self.control_max)
        costs = self.rollout_costs(state, candidates)
        best = int(np.argmin(costs))
        self._nominal = candidates[best]
        info = {"solve_ms": 1e3 * (time.perf_counter() - start), "cost": float(costs[best]),
                "improvement": float(costs[0] - costs[best]), "status": float(STATUS_OK)}  # fmt: skip
        return SkillOutput(np.array([self._nominal[0]]), info)
