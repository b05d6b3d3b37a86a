"""A nonlinear MPC skill for the cart-pole: keep the cart near a position reference.

:class:`CartTrackingMPC` solves, at every call, a finite-horizon optimal control problem on the nonlinear rigid-body
model of :mod:`skills.cartpole_model` (RK4 at the MPC's own step ``dt``, direct multiple shooting) with CasADi's SQP
method and the ``qrqp`` QP solver, warm-started from the previous solution shifted by one step.

It is a *partial* skill: the cost penalises the cart's distance to ``x_ref``, its velocity and the control, never the
pole. The pole is predicted (so the cart is held still against a swinging pole) but neither swung up nor balanced.

The skill is meant to be re-solved every ``dt`` seconds (every 5 env steps of 0.01 s for the default 0.05 s) with its
action held in between: the warm start shifts the plan by exactly one MPC step per call.
"""

from __future__ import annotations

import time
from typing import Any

import casadi
import numpy as np

from hrtc.errors import ConfigError, ShapeError, interrupt_within
from hrtc.skill import SkillOutput
from skills.cartpole_model import CartpoleParams, accelerations

# info["status"] values: 0 is a converged solve; anything else means the action is a fallback.
STATUS_OK = 0
STATUS_NOT_CONVERGED = 1  # the solver stopped without success (iteration limit, infeasible, ...)
STATUS_NONFINITE_SOLUTION = 2  # the solver raised or returned NaN / inf
STATUS_NONFINITE_STATE = 3  # the input state had NaN / inf; no solve was attempted

_NX, _NU = 4, 1  # state (x, theta, x_dot, theta_dot), control u


def cartpole_rk4(params: CartpoleParams, dt: float, substeps: int = 1) -> casadi.Function:
    """One ZOH step of the cart-pole: ``F(s, u) -> s_next`` as a CasADi function.

    s: (4,) ``[x (m), theta (rad, 0 upright), x_dot (m/s), theta_dot (rad/s)]``; u: (1,) unitless, held for ``dt``
    seconds and integrated with ``substeps`` classical RK4 steps.
    """
    s = casadi.MX.sym("s", _NX)
    u = casadi.MX.sym("u", _NU)

    def f(z: Any) -> Any:
        x_ddot, theta_ddot = accelerations(params, z[1], z[3], z[2], u, math=casadi)
        return casadi.vertcat(z[2], z[3], x_ddot, theta_ddot)

    h = dt / substeps
    z = s
    for _ in range(substeps):
        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        z = z + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return casadi.Function("cartpole_rk4", [s, u], [z], ["s", "u"], ["s_next"])


class CartTrackingMPC:
    """Nonlinear MPC that drives the cart to ``x_ref`` and holds it there, ignoring the pole's angle.

    Problem over the horizon ``k = 0..N-1`` (``N = horizon``), model step ``dt`` s:
        min  sum_k  w_position (x_k - x_ref)^2 + w_velocity x_dot_k^2 + w_control u_k^2
             + w_terminal_position (x_N - x_ref)^2 + w_terminal_velocity x_dot_N^2
        s.t. s_0 = state, s_{k+1} = RK4(s_k, u_k), u_k in ctrlrange, |x_k| <= rail - rail_margin (k >= 1).

    Args:
        model: task name for :func:`envs.mj_model`, whose MuJoCo model gives the physical parameters and limits.
        x_ref: cart position reference, m; change it later with :meth:`set_reference`.
        dt: MPC step, s; the returned action is meant to be held this long.
        horizon: number of MPC steps ``N``.
        w_position, w_velocity, w_control: stage weights on ``(x - x_ref)^2`` (1/m^2), ``x_dot^2`` (s^2/m^2), ``u^2``.
        w_terminal_position, w_terminal_velocity: terminal weights on ``(x_N - x_ref)^2`` and ``x_dot_N^2``.
        rail_margin: the predicted cart stays this far inside the slider's range, m.
        max_iter: SQP iteration limit per solve.
        substeps: RK4 substeps per MPC step.
    """

    state_keys: tuple[str, ...] = ("cart_position", "pole_angle", "cart_velocity", "pole_angular_velocity")

    def __init__(
        self,
        model: str = "cartpole_swingup",
        x_ref: float = 0.0,
        dt: float = 0.05,
        horizon: int = 20,
        w_position: float = 10.0,
        w_velocity: float = 1.0,
        w_control: float = 0.1,
        w_terminal_position: float = 50.0,
        w_terminal_velocity: float = 10.0,
        rail_margin: float = 0.1,
        max_iter: int = 15,
        substeps: int = 1,
    ) -> None:
        weights = dict(
            w_position=w_position,
            w_velocity=w_velocity,
            w_control=w_control,
            w_terminal_position=w_terminal_position,
            w_terminal_velocity=w_terminal_velocity,
        )
        _check_settings(dt, dict(horizon=horizon, max_iter=max_iter, substeps=substeps), weights)
        if w_control <= 0.0:
            raise ConfigError(f"w_control must be > 0 so the problem is strictly convex in u, got {w_control!r}")
        if w_position + w_terminal_position <= 0.0:
            raise ConfigError("w_position and w_terminal_position are both 0: nothing tracks the reference")
        if not (np.isfinite(rail_margin) and rail_margin >= 0.0):
            raise ConfigError(f"rail_margin must be a finite number >= 0 m, got {rail_margin!r}")

        import envs  # here: envs pulls in dm_control, needed only to read the parameters

        mj_model = envs.mj_model(model)
        self.params = CartpoleParams.from_mj_model(mj_model)
        slider_range = _slider_range(mj_model)
        self.position_min = float(slider_range[0] + rail_margin)  # m
        self.position_max = float(slider_range[1] - rail_margin)  # m
        if self.position_min >= self.position_max:
            raise ConfigError(f"rail_margin {rail_margin} m leaves no room on the rail {tuple(slider_range)}")
        self.model = model
        self.dt = float(dt)
        self.horizon = int(horizon)
        self.max_iter = int(max_iter)
        self.weights = {k: float(v) for k, v in weights.items()}
        self.x_ref = 0.0
        self.set_reference(x_ref)

        self.step = cartpole_rk4(self.params, self.dt, int(substeps))
        self._build_solver()
        self._warm: dict[str, np.ndarray] | None = None
        self._plan: np.ndarray | None = None  # (N,) controls of the last successful solve
        self._plan_index = 0  # index into _plan of the control to fall back on next

    # ------------------------------------------------------------------ problem
    def _build_solver(self) -> None:
        n, p, w = self.horizon, self.params, self.weights
        s0 = casadi.MX.sym("s0", _NX)
        x_ref = casadi.MX.sym("x_ref")
        states = casadi.MX.sym("S", _NX, n + 1)  # columns s_0..s_N
        controls = casadi.MX.sym("U", _NU, n)  # columns u_0..u_{N-1}
        propagated = self.step.map(n)(states[:, :n], controls)  # (4, N)

        err = states[0, :] - x_ref  # (1, N+1)
        cost = (
            w["w_position"] * casadi.sumsqr(err[:n])
            + w["w_velocity"] * casadi.sumsqr(states[2, :n])
            + w["w_control"] * casadi.sumsqr(controls)
            + w["w_terminal_position"] * err[n] ** 2
            + w["w_terminal_velocity"] * states[2, n] ** 2
        )
        gaps = casadi.vertcat(states[:, 0] - s0, casadi.vec(states[:, 1:] - propagated))  # (4 (N+1),)
        decision = casadi.vertcat(casadi.vec(states), casadi.vec(controls))
        self._n_states = _NX * (n + 1)
        self._n_decision = self._n_states + _NU * n

        lbx = np.full(self._n_decision, -np.inf)
        ubx = np.full(self._n_decision, np.inf)
        # the initial state is pinned by the equality constraint; bounding it too would make an out-of-range
        # measurement infeasible instead of something the plan recovers from
        lbx[_NX : self._n_states : _NX] = self.position_min
        ubx[_NX : self._n_states : _NX] = self.position_max
        lbx[self._n_states :] = p.control_min
        ubx[self._n_states :] = p.control_max
        self._lbx, self._ubx = lbx, ubx
        self._n_constraints = int(gaps.numel())

        options = {
            "qpsol": "qrqp",
            "convexify_strategy": "eigen-clip",
            "max_iter": self.max_iter,
            "expand": True,  # SX evaluation of the MX graph: several times faster for this small problem
            "print_time": False,
            # A failed evaluation (NaN in a derivative, e.g. at an infeasible start past the rails) is handled by the
            # fallback and reported in info["status"]; CasADi would also print a warning per evaluation.
            "show_eval_warnings": False,
            "print_header": False,
            "print_iteration": False,
            "print_status": False,
            "error_on_fail": False,
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False},
        }
        nlp = {"x": decision, "p": casadi.vertcat(s0, x_ref), "f": cost, "g": gaps}
        self._solver = casadi.nlpsol("cart_tracking_mpc", "sqpmethod", nlp, options)

    @property
    def plan(self) -> np.ndarray | None:
        """Controls of the last converged solve, (N,), one per ``dt``; None before the first one or after a reset."""
        return None if self._plan is None else self._plan.copy()

    # ------------------------------------------------------------------ skill protocol
    def set_reference(self, x_ref: float) -> None:
        """Track cart position ``x_ref`` (m) from the next call of :meth:`act` on; must lie inside the bounds."""
        x_ref = float(x_ref)
        if not (np.isfinite(x_ref) and self.position_min <= x_ref <= self.position_max):
            raise ConfigError(
                f"x_ref must be a finite position in [{self.position_min}, {self.position_max}] m, got {x_ref!r}"
            )
        self.x_ref = x_ref

    def reset(self, rng: np.random.Generator) -> None:
        """Forget the warm start and the fallback plan. ``rng`` is unused: the skill is deterministic."""
        del rng
        self._warm = None
        self._plan = None
        self._plan_index = 0

    def act(self, state: np.ndarray) -> SkillOutput:
        """Solve the MPC problem from ``state`` and propose its first control.

        state: (4,) ``[cart_position (m), pole_angle (rad), cart_velocity (m/s), pole_angular_velocity (rad/s)]``.
        Returns a (1,) action in the model's ctrlrange, always finite. ``info``: ``solve_ms`` (wall time of the solve,
        ms), ``status`` (0 converged; otherwise the action is a fallback, see the ``STATUS_*`` constants),
        ``iterations`` (SQP iterations), ``cost`` (optimal cost; NaN when no solution was usable).
        """
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (_NX,):
            raise ShapeError(
                f"CartTrackingMPC expects a state of shape ({_NX},) ordered as {self.state_keys}, got {state.shape}"
            )
        if not np.all(np.isfinite(state)):
            return self._fallback(state, STATUS_NONFINITE_STATE, solve_ms=0.0, iterations=0)

        x0, lam_x0, lam_g0 = self._initial_guess(state)
        start = time.perf_counter()
        try:
            result = self._solver(
                x0=x0,
                p=np.append(state, self.x_ref),
                lbx=self._lbx,
                ubx=self._ubx,
                lbg=0.0,
                ubg=0.0,
                lam_x0=lam_x0,
                lam_g0=lam_g0,
            )
        except RuntimeError as error:  # CasADi raises when a function evaluation fails (e.g. NaN in a derivative)
            if (interrupt := interrupt_within(error)) is not None:
                raise interrupt from error  # Ctrl-C or SIGTERM during the solve: not a solver failure
            solve_ms = 1e3 * (time.perf_counter() - start)
            self._warm = None
            return self._fallback(state, STATUS_NONFINITE_SOLUTION, solve_ms=solve_ms, iterations=0)
        solve_ms = 1e3 * (time.perf_counter() - start)
        stats = self._solver.stats()
        iterations = int(stats.get("iter_count", 0))

        w = np.asarray(result["x"]).ravel()
        lam_x = np.asarray(result["lam_x"]).ravel()
        lam_g = np.asarray(result["lam_g"]).ravel()
        cost = float(result["f"])
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(lam_x)) and np.all(np.isfinite(lam_g))):
            self._warm = None
            return self._fallback(state, STATUS_NONFINITE_SOLUTION, solve_ms=solve_ms, iterations=iterations)
        if not stats.get("success", False):
            # an unconverged iterate is still a reasonable warm start for the next call
            self._warm = {"x": w, "lam_x": lam_x, "lam_g": lam_g}
            return self._fallback(state, STATUS_NOT_CONVERGED, solve_ms=solve_ms, iterations=iterations)

        self._warm = {"x": w, "lam_x": lam_x, "lam_g": lam_g}
        controls = np.clip(w[self._n_states :], self.params.control_min, self.params.control_max)  # (N,)
        self._plan, self._plan_index = controls, 1
        info = {"solve_ms": solve_ms, "status": float(STATUS_OK), "iterations": float(iterations), "cost": cost}
        return SkillOutput(controls[:1].copy(), info)

    # ------------------------------------------------------------------ internals
    def _initial_guess(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Primal guess and multipliers: the previous solution shifted by one step, or a cold start."""
        n = self.horizon
        if self._warm is None:
            states = np.tile(state, (n + 1, 1))  # (N+1, 4): hold the current state
            # a tiny push towards the reference: from an exact equilibrium with a zero guess, the SQP's first step
            # can sit at a zero gradient
            controls = np.full(n, 1e-3 * np.sign(self.x_ref - state[0] or 1.0))
            x0 = np.concatenate([states.ravel(), controls])
            return x0, np.zeros(self._n_decision), np.zeros(self._n_constraints)

        w, lam_x, lam_g = self._warm["x"], self._warm["lam_x"], self._warm["lam_g"]
        x0 = np.concatenate([_shift(w[: self._n_states], _NX), _shift(w[self._n_states :], _NU)])
        # pole_angle is wrapped to (-pi, pi]: move the guessed angles by whole turns to agree with the measurement,
        # or a hanging pole crossing +-pi would open a 2 pi gap in the shooting constraints
        turns = np.round((state[1] - x0[1]) / (2.0 * np.pi))
        x0[1 : self._n_states : _NX] += 2.0 * np.pi * turns
        x0[:_NX] = state  # the pinned initial state is known exactly
        lam_x0 = np.concatenate([_shift(lam_x[: self._n_states], _NX), _shift(lam_x[self._n_states :], _NU)])
        lam_g0 = _shift(lam_g, _NX)
        return x0, lam_x0, lam_g0

    def _fallback(self, state: np.ndarray, status: int, *, solve_ms: float, iterations: int) -> SkillOutput:
        """A safe action when no fresh solution is usable: the previous plan's next control, else a PD on the cart."""
        p = self.params
        if self._plan is not None and self._plan_index < len(self._plan):
            u = float(self._plan[self._plan_index])
            self._plan_index += 1
        elif np.isfinite(state[0]) and np.isfinite(state[2]):
            # critically damped PD on the cart's mass alone (2 rad/s), converted from force to u
            u = (4.0 * (self.x_ref - state[0]) - 4.0 * state[2]) * (p.cart_mass + p.pole_mass) / p.gear
        else:
            u = 0.0
        action = np.array([float(np.clip(u, p.control_min, p.control_max))])
        info = {"solve_ms": solve_ms, "status": float(status), "iterations": float(iterations), "cost": float("nan")}
        return SkillOutput(action, info)


def _check_settings(dt: float, counts: dict[str, Any], weights: dict[str, float]) -> None:
    """The settings both NMPCs share: a positive step ``dt``, integer counts >= 1 (horizon, iterations...), finite
    cost weights >= 0."""
    if not (np.isfinite(dt) and dt > 0.0):
        raise ConfigError(f"dt must be a positive number of seconds, got {dt!r}")
    for name, value in counts.items():
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    for name, value in weights.items():
        if not (np.isfinite(value) and value >= 0.0):
            raise ConfigError(f"{name} must be a finite number >= 0, got {value!r}")


def _shift(block: np.ndarray, width: int) -> np.ndarray:
    """Drop the first ``width`` entries of a stacked trajectory and repeat its last ``width`` entries at the end."""
    return np.concatenate([block[width:], block[-width:]])


def _slider_range(mj_model: Any) -> np.ndarray:
    """The slider joint's (lower, upper) position limits, m; ValueError if it is not limited."""
    import mujoco

    slider = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, "slider")
    if slider < 0 or not mj_model.jnt_limited[slider]:
        raise ConfigError("the model's slider joint is missing or has no range: cannot bound the cart position")
    return np.asarray(mj_model.jnt_range[slider], dtype=np.float64)


class UprightMPC:
    """Nonlinear MPC towards upright for dm_control's pendulum or acrobot: direct multiple shooting.

    Problem over ``k = 0..N-1`` (``N = horizon``), model step ``dt`` s (RK4 of the rigid-body equations of
    ``skills.pendulum_model`` or ``skills.acrobot_model``, with the MuJoCo model's own masses, lengths, inertias and
    damping), ``a_i`` the links' absolute angles from upright (the pendulum's ``theta``; the acrobot's ``q1`` and
    ``q1 + q2``), ``v`` the joint velocities:
        min  sum_k  w_angle sum_i (1 - cos a_ik) + w_velocity |v_k|^2 + w_control u_k^2
             + w_terminal sum_i (1 - cos a_iN) + w_velocity |v_N|^2
        s.t. s_0 = state, s_{k+1} = RK4(s_k, u_k), u_k in ctrlrange.
    ``1 - cos`` makes the cost blind to whole turns, so the measured angles' wrapping at +-pi is harmless. CasADi's
    SQP method with the ``qrqp`` QP solver, warm-started from the previous plan shifted by one step.

    On the pendulum a 1.6 s horizon swings up and balances: a whole skill on its own. On the acrobot a short horizon
    is a catch near upright (the torque limit leaves the linear balance a tiny basin), not a swing-up.

    Meant to be re-solved every ``dt`` seconds with its action held in between (``every`` in the task config).
    Info: ``solve_ms`` (wall time of the solve, ms), ``status`` (0 converged, 1 stopped at ``max_iter``: its plan is
    still used), ``iterations``, ``cost``.
    """

    nlp_solver = "sqpmethod"  # CasADi's nlpsol plug-in

    def __init__(
        self,
        model: str | Any = "pendulum_swingup",
        dt: float = 0.04,
        horizon: int = 40,
        w_angle: float = 10.0,
        w_velocity: float = 0.1,
        w_control: float = 0.1,
        w_terminal: float = 50.0,
        max_iter: int = 10,
    ) -> None:
        weights = dict(w_angle=w_angle, w_velocity=w_velocity, w_control=w_control, w_terminal=w_terminal)
        _check_settings(dt, dict(horizon=horizon, max_iter=max_iter), weights)
        if w_control <= 0.0:
            raise ConfigError(f"w_control must be > 0, got {w_control!r}")
        if w_angle + w_terminal <= 0.0:
            raise ConfigError("w_angle and w_terminal are both 0: nothing asks for upright")
        import envs
        from skills.acrobot_model import AcrobotParams
        from skills.pendulum_model import PendulumParams

        mj_model = envs.mj_model(model)
        self.params: Any
        if mj_model.nv == 1:
            plant, self.state_keys = PendulumParams, ("pole_angle", "pole_angular_velocity")
        else:
            plant = AcrobotParams
            self.state_keys = ("shoulder_angle", "elbow_angle", "shoulder_velocity", "elbow_velocity")
        try:
            self.params = plant.from_mj_model(mj_model)
        except (ValueError, AttributeError, TypeError) as error:
            raise ConfigError(f"model must be dm_control's pendulum or acrobot: {error}") from None
        self._nq = len(self.state_keys) // 2
        self.dt, self.horizon, self.max_iter = float(dt), int(horizon), int(max_iter)
        self.weights = {k: float(v) for k, v in weights.items()}
        self.step = self._rk4()
        self._build_solver()
        self._warm: dict[str, np.ndarray] | None = None
        self._plan: np.ndarray | None = None
        self._plan_index = 0

    def _rk4(self) -> casadi.Function:
        """``F(s, u) -> s_next``: one ZOH step of ``dt`` s; s = ``[angles (rad), velocities (rad/s)]`` as ordered
        by ``state_keys``."""
        nq = self._nq
        s, u = casadi.MX.sym("s", 2 * nq), casadi.MX.sym("u")

        def f(z: Any) -> Any:
            if nq == 1:
                return casadi.vertcat(z[1], self.params.acceleration(z[0], z[1], u, math=casadi))
            return casadi.vertcat(z[2], z[3], *self.params.accelerations(z[0], z[1], z[2], z[3], u, math=casadi))

        h = self.dt
        k1 = f(s)
        k2 = f(s + 0.5 * h * k1)
        k3 = f(s + 0.5 * h * k2)
        k4 = f(s + h * k3)
        s_next = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        return casadi.Function("upright_rk4", [s, u], [s_next], ["s", "u"], ["s_next"])

    def _build_solver(self) -> None:
        n, w, p, nq = self.horizon, self.weights, self.params, self._nq
        nx = 2 * nq
        s0 = casadi.MX.sym("s0", nx)
        states = casadi.MX.sym("S", nx, n + 1)
        controls = casadi.MX.sym("U", 1, n)
        propagated = self.step.map(n)(states[:, :n], controls)
        # absolute link angles from upright, (nq, N+1)
        angles = states[:1, :] if nq == 1 else casadi.vertcat(states[0, :], states[0, :] + states[1, :])
        tilt = casadi.sum1(1.0 - casadi.cos(angles))  # (1, N+1)
        cost = (
            w["w_angle"] * casadi.sum2(tilt[:n])
            + w["w_velocity"] * casadi.sumsqr(states[nq:, :])
            + w["w_control"] * casadi.sumsqr(controls)
            + w["w_terminal"] * tilt[n]
        )
        gaps = casadi.vertcat(states[:, 0] - s0, casadi.vec(states[:, 1:] - propagated))
        self._n_states, self._n_decision = nx * (n + 1), nx * (n + 1) + n
        self._lbx = np.concatenate([np.full(self._n_states, -np.inf), np.full(n, p.control_min)])
        self._ubx = np.concatenate([np.full(self._n_states, np.inf), np.full(n, p.control_max)])
        self._n_constraints = int(gaps.numel())
        nlp = {"x": casadi.vertcat(casadi.vec(states), casadi.vec(controls)), "p": s0, "f": cost, "g": gaps}
        self._solver = casadi.nlpsol("upright_mpc", self.nlp_solver, nlp, self._solver_options())

    def _solver_options(self) -> dict[str, Any]:
        """CasADi ``nlpsol`` options for :attr:`nlp_solver`."""
        return {
            "qpsol": "qrqp",
            "convexify_strategy": "eigen-clip",  # the cosine cost is not convex: keep the QPs convex
            "max_iter": self.max_iter,
            "expand": True,
            "print_time": False,
            "show_eval_warnings": False,
            "print_header": False,
            "print_iteration": False,
            "print_status": False,
            "error_on_fail": False,
            "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False},
        }

    @property
    def plan(self) -> np.ndarray | None:
        """Controls of the last converged solve, (N,); None before the first one or after a reset."""
        return None if self._plan is None else self._plan.copy()

    def reset(self, rng: np.random.Generator) -> None:
        """Forget the warm start and the fallback plan. ``rng`` is unused: the skill is deterministic."""
        self._warm, self._plan, self._plan_index = None, None, 0

    def _initial_guess(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.horizon
        if self._warm is None:
            # a pump-like guess: torque along the motion (away from hanging at rest, where every gradient is zero)
            velocity = state[-1]  # the driven joint's
            direction = np.sign(velocity) if velocity != 0.0 else 1.0
            controls = np.full(n, 0.5 * direction * self.params.control_max)
            states = np.tile(state, (n + 1, 1))
            return np.concatenate([states.ravel(), controls]), np.zeros(self._n_decision), np.zeros(self._n_constraints)
        nx = 2 * self._nq
        w, lam_x, lam_g = self._warm["x"], self._warm["lam_x"], self._warm["lam_g"]
        x0 = np.concatenate([_shift(w[: self._n_states], nx), _shift(w[self._n_states :], 1)])
        for i in range(self._nq):  # the measured angles are wrapped: move the guess by whole turns to agree
            x0[i : self._n_states : nx] += 2.0 * np.pi * np.round((state[i] - x0[i]) / (2.0 * np.pi))
        x0[:nx] = state
        lam_x0 = np.concatenate([_shift(lam_x[: self._n_states], nx), _shift(lam_x[self._n_states :], 1)])
        return x0, lam_x0, _shift(lam_g, nx)

    def act(self, state: np.ndarray) -> SkillOutput:
        """Solve from ``state`` (ordered as ``state_keys``: angles in rad, then velocities in rad/s); propose its
        first control (1,). A failed solve falls back on the previous plan's next control, else on zero."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (2 * self._nq,):
            raise ShapeError(f"UprightMPC expects a state of shape ({2 * self._nq},) ordered as {self.state_keys}, "
                             f"got {state.shape}")  # fmt: skip
        if not np.all(np.isfinite(state)):
            return self._fallback(STATUS_NONFINITE_STATE, 0.0, 0)
        x0, lam_x0, lam_g0 = self._initial_guess(state)
        start = time.perf_counter()
        try:
            result = self._solver(x0=x0, p=state, lbx=self._lbx, ubx=self._ubx, lbg=0.0, ubg=0.0, lam_x0=lam_x0,
                                  lam_g0=lam_g0)  # fmt: skip
        except RuntimeError as error:
            if (interrupt := interrupt_within(error)) is not None:
                raise interrupt from error  # Ctrl-C or SIGTERM during the solve: not a solver failure
            self._warm = None
            return self._fallback(STATUS_NONFINITE_SOLUTION, 1e3 * (time.perf_counter() - start), 0)
        solve_ms = 1e3 * (time.perf_counter() - start)
        try:
            stats = self._solver.stats()
        except RuntimeError:  # seen after a failed QP: CasADi cannot build its status string
            stats = {}
        iterations = int(stats.get("iter_count", 0))
        w, lam_x, lam_g = (np.asarray(result[k]).ravel() for k in ("x", "lam_x", "lam_g"))
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(lam_x)) and np.all(np.isfinite(lam_g))):
            self._warm = None
            return self._fallback(STATUS_NONFINITE_SOLUTION, solve_ms, iterations)
        self._warm = {"x": w, "lam_x": lam_x, "lam_g": lam_g}
        controls = np.clip(w[self._n_states :], self.params.control_min, self.params.control_max)
        # an SQP stopped at max_iter still holds a feasible, improving plan: use it, but report it
        status = STATUS_OK if stats.get("success", False) else STATUS_NOT_CONVERGED
        self._plan, self._plan_index = controls, 1
        info = {"solve_ms": solve_ms, "status": float(status), "iterations": float(iterations),
                "cost": float(result["f"])}  # fmt: skip
        return SkillOutput(controls[:1].copy(), info)

    def _fallback(self, status: int, solve_ms: float, iterations: int) -> SkillOutput:
        u = 0.0
        if self._plan is not None and self._plan_index < len(self._plan):
            u, self._plan_index = float(self._plan[self._plan_index]), self._plan_index + 1
        info = {"solve_ms": solve_ms, "status": float(status), "iterations": float(iterations), "cost": 0.0}
        return SkillOutput(np.array([u]), info)


class AcrobotUprightMPC(UprightMPC):
    """:class:`UprightMPC` on dm_control's acrobot as a catch near upright, solved by IPOPT.

    The same multiple-shooting problem (RK4 of ``skills.acrobot_model``'s equations per interval, cost on
    ``1 - cos`` of both links' absolute angles, the velocities and the elbow control, the actuator's ``gear x
    ctrlrange`` as the bound), with IPOPT (interior point, bounded iterations, warm-started) in place of the SQP:
    the convexified SQP stopped in local minima that let the acrobot fall. Defaults: ``dt`` 0.04 s, 75 steps (3 s);
    at 1.2 s the optimal plans fall slowly past the horizon's end and it held none of 8 perturbed starts.

    ``cold_guess``: IPOPT's starting point when there is no previous plan to shift (an episode's first solve, or
    after a failed one): ``hold`` the current state with zero torque, or ``swingup``: the energy swing-up's
    (:class:`skills.swingup.AcrobotEnergySwingUp`) own rollout on the model over the horizon, a pumping plan. From
    hanging, ``hold`` often ends in the local minimum with the lower link up and the upper one hanging; the pumping
    guess leads IPOPT to whole swing-ups (alone, 10 episodes: 478 against 388 on seed 1's, 478 against 396 on seed
    2's; the README's acrobot notes). ``reguess_every`` k > 0: every k-th solve is also made from that cold guess,
    and the cheaper plan kept (:meth:`act`; k = 25, once a second: 502 and 538 on the same episodes).
    """

    nlp_solver = "ipopt"

    def __init__(
        self,
        model: str | Any = "acrobot_swingup",
        dt: float = 0.04,
        horizon: int = 75,
        w_angle: float = 10.0,
        w_velocity: float = 0.1,
        w_control: float = 0.01,
        w_terminal: float = 100.0,
        max_iter: int = 50,
        cold_guess: str = "hold",
        reguess_every: int = 0,
    ) -> None:
        super().__init__(model, dt, horizon, w_angle, w_velocity, w_control, w_terminal, max_iter)
        if self._nq != 2:
            raise ConfigError(f"AcrobotUprightMPC needs the acrobot's model, got one with {self._nq} joint")
        if cold_guess not in ("hold", "swingup"):
            raise ConfigError(f"cold_guess must be hold or swingup, got {cold_guess!r}")
        if isinstance(reguess_every, bool) or not isinstance(reguess_every, int) or reguess_every < 0:
            raise ConfigError(f"reguess_every must be a non-negative integer, got {reguess_every!r}")
        self.cold_guess, self.reguess_every, self._solves = cold_guess, reguess_every, 0
        if cold_guess == "swingup":
            from skills.swingup import AcrobotEnergySwingUp

            self._pump = AcrobotEnergySwingUp(model)

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._solves = 0

    def act(self, state: np.ndarray) -> SkillOutput:
        """:meth:`UprightMPC.act`; with ``reguess_every`` k > 0, every k-th solve is made twice, from the shifted plan
        and from the cold guess, and the plan of lower cost is kept (``info["reguessed"]`` 1 when the cold one won):
        a warm-started IPOPT follows its plan into a local minimum, a fresh start can leave it."""
        first = super().act(state)
        self._solves += 1
        if self.reguess_every <= 0 or self._solves % self.reguess_every or self._warm is None:
            return SkillOutput(first.action, {**first.info, "reguessed": 0.0})
        kept = (self._warm, self._plan, self._plan_index)
        self._warm = None  # the next solve starts from the cold guess
        second = super().act(state)
        solve_ms = first.info["solve_ms"] + second.info["solve_ms"]
        if second.info["status"] == STATUS_OK and not second.info["cost"] >= first.info["cost"]:  # NaN: first failed
            return SkillOutput(second.action, {**second.info, "solve_ms": solve_ms, "reguessed": 1.0})
        self._warm, self._plan, self._plan_index = kept
        return SkillOutput(first.action, {**first.info, "solve_ms": solve_ms, "reguessed": 0.0})

    def _solver_options(self) -> dict[str, Any]:
        return {
            "expand": True,
            "print_time": False,
            "error_on_fail": False,
            "ipopt": {"max_iter": self.max_iter, "print_level": 0, "sb": "yes", "tol": 1e-6,
                      "warm_start_init_point": "yes", "mu_init": 1e-3},
        }  # fmt: skip

    def _initial_guess(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._warm is not None:
            return super()._initial_guess(state)
        # cold start: the state held with zero torque (near upright; the pendulum's pump-like constant torque led
        # IPOPT to plans that fall), or the energy swing-up's rollout (from far below)
        n = self.horizon
        if self.cold_guess == "hold":
            x0 = np.concatenate([np.tile(state, (n + 1, 1)).ravel(), np.zeros(n)])
            return x0, np.zeros(self._n_decision), np.zeros(self._n_constraints)
        # the energy swing-up's own rollout on the model (RK4 at dt, control held per interval)
        states, controls = [np.asarray(state, float)], []
        for _ in range(n):
            u = float(self._pump.act(states[-1]).action[0])
            controls.append(u)
            states.append(np.asarray(self.step(states[-1], u)).ravel())
        x0 = np.concatenate([np.stack(states).ravel(), np.asarray(controls)])
        return x0, np.zeros(self._n_decision), np.zeros(self._n_constraints)
