"""Constrained linear MPC on the linearisation of a MuJoCo model, solved with OSQP.

The plant is the task's own ``mujoco.MjModel``, linearised by finite differences of one ``mj_step`` about a
reference state and control. The state of the linear model is the deviation from the reference in MuJoCo's
tangent space, ``x = [dq, dv]`` with ``dq = qpos - qpos_ref`` (``mj_differentiatePos``, hinge angles wrapped to
(-pi, pi]) and ``dv = qvel - qvel_ref``; ``x`` is (2 nv,). The decision variables of the condensed QP are the
``horizon`` controls, (horizon * nu,); only the linear term of the QP changes between steps.

A linear controller with a bounded control: it balances about the reference from nearby states but cannot, for
instance, swing a cart-pole up from hanging. It is a partial skill.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, NamedTuple

import mujoco
import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp

from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import SkillOutput

# ``info["status"]`` codes, shared with the other skills (skills.nmpc).
STATUS_OK = 0  # the QP was solved; the action is its first control
STATUS_NOT_CONVERGED = 1  # OSQP stopped without solving (iteration limit, ...); the action is the clipped LQR law
STATUS_NONFINITE_SOLUTION = 2  # OSQP returned NaN / inf; the action is the clipped LQR law
STATUS_NONFINITE_STATE = 3  # the state had NaN / inf; the action is the clipped reference control


class Linearization(NamedTuple):
    """A discrete-time affine model of one ``mj_step`` about a reference, on tangent-space deviations.

    ``x_next = A x + B u + drift``, where ``u`` is the control's deviation from the reference control.
    A: (2 nv, 2 nv); B: (2 nv, nu); drift: (2 nv,), the deviation one step after the reference itself (zero when
    the reference is an equilibrium).
    """

    A: np.ndarray
    B: np.ndarray
    drift: np.ndarray


def hinge_dofs(model: Any) -> np.ndarray:
    """Indices (into qvel) of the hinge joints' degrees of freedom, whose position errors are wrapped."""
    hinges = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    return np.asarray(model.jnt_dofadr[hinges], dtype=int)


HINGE_ERRORS = ("wrap", "sin")


def state_error(
    model: Any,
    qpos_ref: np.ndarray,
    qvel_ref: np.ndarray,
    qpos: np.ndarray,
    qvel: np.ndarray,
    hinge_error: str = "wrap",
) -> np.ndarray:
    """Tangent-space deviation ``[dq, dv]`` (2 nv,) of ``(qpos, qvel)`` from the reference.

    Hinge angle errors are either wrapped to [-pi, pi) (``"wrap"``) or taken as ``sin`` of the wrapped error
    (``"sin"``): equal to first order near the reference, but continuous all round the circle and zero again at the
    opposite point, so the linear law gives no bang-bang flip as a hanging pole crosses +-pi.
    """
    dq = np.zeros(model.nv)
    mujoco.mj_differentiatePos(model, dq, 1.0, np.asarray(qpos_ref, float), np.asarray(qpos, float))
    dofs = hinge_dofs(model)
    wrapped = np.mod(dq[dofs] + np.pi, 2.0 * np.pi) - np.pi
    dq[dofs] = np.sin(wrapped) if hinge_error == "sin" else wrapped
    return np.concatenate([dq, np.asarray(qvel, float) - qvel_ref])


def _step(model: Any, data: Any, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray) -> tuple[np.ndarray, ...]:
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    mujoco.mj_step(model, data)
    return data.qpos.copy(), data.qvel.copy()


def finite_difference_transition(
    model: Any, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray, eps: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of ``mj_step`` with the model's own integrator (RK4 included).

    Same layout and meaning as ``mujoco.mjd_transitionFD`` with ``flg_centered=True`` for a model without
    activations: A (2 nv, 2 nv) maps a tangent-space deviation of ``[qpos, qvel]`` to the deviation of the next
    state from the nominal next state; B (2 nv, nu) does the same for ``ctrl``. ``mjd_transitionFD`` refuses RK4.
    """
    nv, nu = model.nv, model.nu
    data = mujoco.MjData(model)
    qpos_next, qvel_next = _step(model, data, qpos, qvel, ctrl)

    def next_deviation(dx: np.ndarray, du: np.ndarray) -> np.ndarray:
        q = np.array(qpos, dtype=float)
        mujoco.mj_integratePos(model, q, dx[:nv], 1.0)
        q1, v1 = _step(model, data, q, qvel + dx[nv:], ctrl + du)
        dq = np.zeros(nv)
        mujoco.mj_differentiatePos(model, dq, 1.0, qpos_next, q1)
        return np.concatenate([dq, v1 - qvel_next])

    A = np.zeros((2 * nv, 2 * nv))
    B = np.zeros((2 * nv, nu))
    for i in range(2 * nv):
        e = np.zeros(2 * nv)
        e[i] = eps
        A[:, i] = (next_deviation(e, np.zeros(nu)) - next_deviation(-e, np.zeros(nu))) / (2.0 * eps)
    for j in range(nu):
        e = np.zeros(nu)
        e[j] = eps
        B[:, j] = (next_deviation(np.zeros(2 * nv), e) - next_deviation(np.zeros(2 * nv), -e)) / (2.0 * eps)
    return A, B


def linearize(model: Any, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray, eps: float = 1e-6) -> Linearization:
    """Linearise one ``mj_step`` of ``model`` about ``(qpos, qvel, ctrl)``.

    Uses ``mujoco.mjd_transitionFD`` (centred) where MuJoCo supports the integrator, and the same central
    differences done here with ``mj_step`` for RK4 (which ``mjd_transitionFD`` rejects; dm_control's cart-pole
    uses RK4). ``eps`` is the perturbation size in the tangent space and in control units.
    """
    qpos, qvel, ctrl = (np.asarray(a, dtype=float) for a in (qpos, qvel, ctrl))
    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        A, B = finite_difference_transition(model, qpos, qvel, ctrl, eps)
    else:
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
        mujoco.mj_forward(model, data)
        A = np.zeros((2 * model.nv, 2 * model.nv))
        B = np.zeros((2 * model.nv, model.nu))
        mujoco.mjd_transitionFD(model, data, eps, True, A, B, None, None)
    qpos_next, qvel_next = _step(model, mujoco.MjData(model), qpos, qvel, ctrl)
    drift = np.zeros(model.nv)
    mujoco.mj_differentiatePos(model, drift, 1.0, qpos, qpos_next)
    return Linearization(A, B, np.concatenate([drift, qvel_next - qvel]))


def _vector(name: str, value: Any, size: int) -> np.ndarray:
    """``value`` as a finite (size,) float64 vector; a scalar is broadcast."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(size, float(array))
    if array.shape != (size,):
        raise ConfigError(f"{name} must be a scalar or have shape ({size},), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ConfigError(f"{name} must be finite, got {array}")
    return array


class LinearMPC:
    """Constrained LQR-MPC about a reference state of a MuJoCo model; OSQP on the condensed QP.

    Minimises ``sum_{k<N} (x_k' Q x_k + u_k' R u_k) + x_N' P x_N`` subject to the linearised dynamics and
    ``ctrlrange`` box bounds on every control, with ``P`` from the discrete algebraic Riccati equation (so the
    unconstrained solution is the infinite-horizon LQR). The action is ``ctrl_ref + u_0``, clipped to the bounds.

    Args:
        model: a task name for ``envs.mj_model`` or a ``mujoco.MjModel`` (any model without activations, nu >= 1).
            Its timestep is the control period: one action per ``mj_step``.
        qpos_ref: (nq,) reference positions; default ``model.qpos0`` (for the cart-pole: centred and upright).
        qvel_ref: (nv,) reference velocities, default zeros.
        ctrl_ref: (nu,) reference control, default zeros.
        horizon: N, steps of the prediction horizon.
        q_diag: (2 nv,) diagonal of Q on ``[dq, dv]`` (per unit^2 of each); default ones, which balances the
            cart-pole from 0.15 rad with velocities.
        r: diagonal of R, a scalar or (nu,), per control unit^2; > 0.
        eps: finite-difference step for the linearisation.
        max_iter, eps_abs, eps_rel: OSQP settings.
        hinge_error: ``"wrap"`` or ``"sin"``, how hinge angle errors enter the linear model (see ``state_error``).

    Info keys: ``solve_ms`` (wall time of the QP update and solve, ms), ``status`` (0 ok; 1 or 2 the solve failed
    and the clipped LQR action was used; 3 non-finite state), ``osqp_status`` (OSQP's status code, 1 = solved),
    ``iterations``, ``cost`` (predicted cost-to-go of the plan; of the LQR law on a fallback).
    """

    state_keys: tuple[str, ...] = ("qpos", "qvel")

    def __init__(
        self,
        model: str | Any = "cartpole_swingup",
        qpos_ref: Sequence[float] | None = None,
        qvel_ref: Sequence[float] | None = None,
        ctrl_ref: Sequence[float] | None = None,
        horizon: int = 25,
        q_diag: Sequence[float] | None = None,
        r: float | Sequence[float] = 0.1,
        eps: float = 1e-6,
        max_iter: int = 200,
        eps_abs: float = 1e-5,
        eps_rel: float = 1e-5,
        hinge_error: str = "wrap",
    ) -> None:
        import envs  # here: envs pulls in dm_control, needed only to read the model

        model = envs.mj_model(model)
        if model.nu < 1:
            raise ConfigError("the model has no actuators: nothing to control")
        if model.na > 0:
            raise ConfigError(f"the model has {model.na} actuator activations, which qpos/qvel do not observe")
        if isinstance(horizon, bool) or not isinstance(horizon, int | np.integer) or horizon < 1:
            raise ConfigError(f"horizon must be a positive integer, got {horizon!r}")
        if not (eps > 0 and np.isfinite(eps)):
            raise ConfigError(f"eps must be positive and finite, got {eps}")
        if max_iter < 1:
            raise ConfigError(f"max_iter must be >= 1, got {max_iter}")
        if hinge_error not in HINGE_ERRORS:
            raise ConfigError(f"hinge_error must be one of {HINGE_ERRORS}, got {hinge_error!r}")
        self.hinge_error = hinge_error
        self.model = model
        nq, nv, nu = model.nq, model.nv, model.nu
        self.qpos_ref = _vector("qpos_ref", model.qpos0 if qpos_ref is None else qpos_ref, nq)
        self.qvel_ref = _vector("qvel_ref", np.zeros(nv) if qvel_ref is None else qvel_ref, nv)
        self.ctrl_ref = _vector("ctrl_ref", np.zeros(nu) if ctrl_ref is None else ctrl_ref, nu)
        q = _vector("q_diag", np.ones(2 * nv) if q_diag is None else q_diag, 2 * nv)
        if np.any(q < 0):
            raise ConfigError(f"q_diag must be >= 0, got {q}")
        r_diag = _vector("r", r, nu)
        if np.any(r_diag <= 0):
            raise ConfigError(f"r must be > 0, got {r_diag}")
        limited = model.actuator_ctrllimited.astype(bool)
        self.ctrl_min = np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf)  # (nu,)
        self.ctrl_max = np.where(limited, model.actuator_ctrlrange[:, 1], np.inf)  # (nu,)
        if np.any(self.ctrl_ref < self.ctrl_min) or np.any(self.ctrl_ref > self.ctrl_max):
            raise ConfigError(
                f"ctrl_ref {self.ctrl_ref} is outside the control range [{self.ctrl_min}, {self.ctrl_max}]"
            )
        self.horizon = int(horizon)

        self.linearization = linearize(model, self.qpos_ref, self.qvel_ref, self.ctrl_ref, eps)
        A, B, c = self.linearization
        Q, R = np.diag(q), np.diag(r_diag)
        try:
            P = scipy.linalg.solve_discrete_are(A, B, Q, R)
        except (np.linalg.LinAlgError, ValueError) as error:
            raise ConfigError(
                f"no stabilising LQR solution about this reference (not stabilisable?): {error}"
            ) from None
        self.terminal_cost = P  # (2 nv, 2 nv)
        self.lqr_gain = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)  # (nu, 2 nv), u = -K x

        # Condensed prediction X = Sx x0 + Su U + Sc over x_1..x_N.
        n, N = 2 * nv, self.horizon
        powers = [np.eye(n)]
        for _ in range(N):
            powers.append(A @ powers[-1])
        Sx = np.vstack(powers[1:])  # (N n, n)
        Su = np.zeros((N * n, N * nu))  # (N n, N nu)
        Sc = np.zeros(N * n)  # (N n,)
        for k in range(N):
            Sc[k * n : (k + 1) * n] = (Sc[(k - 1) * n : k * n] if k else 0.0) + powers[k] @ c
            for j in range(k + 1):
                Su[k * n : (k + 1) * n, j * nu : (j + 1) * nu] = powers[k - j] @ B
        Qbar = scipy.linalg.block_diag(*([Q] * (N - 1) + [P]))  # (N n, N n)
        self._H = Su.T @ Qbar @ Su + np.kron(np.eye(N), R)  # (N nu, N nu)
        self._H = 0.5 * (self._H + self._H.T)
        self._F = Su.T @ Qbar @ Sx  # (N nu, n)
        self._g = Su.T @ Qbar @ Sc  # (N nu,)
        self._Sx, self._Sc, self._Qbar, self._Q = Sx, Sc, Qbar, Q

        lower = np.tile(self.ctrl_min - self.ctrl_ref, N)
        upper = np.tile(self.ctrl_max - self.ctrl_ref, N)
        self._bounds = (lower, upper)
        self._max_iter, self._eps = int(max_iter), (float(eps_abs), float(eps_rel))
        self._solver = self._make_solver()
        self._num_vars = N * nu

    def _make_solver(self) -> osqp.OSQP:
        """A fresh OSQP instance (its adaptive rho is solver state too: a reset must not inherit it)."""
        lower, upper = self._bounds
        solver = osqp.OSQP()
        solver.setup(
            sp.triu(sp.csc_matrix(self._H), format="csc"),
            self._g.copy(),
            sp.identity(self._H.shape[0], format="csc"),
            np.where(np.isfinite(lower), lower, -osqp.constant("OSQP_INFTY")),
            np.where(np.isfinite(upper), upper, osqp.constant("OSQP_INFTY")),
            verbose=False,
            warm_starting=True,
            polishing=False,  # polishing prints to stdout even with verbose=False
            max_iter=self._max_iter,
            eps_abs=self._eps[0],
            eps_rel=self._eps[1],
        )
        return solver

    def reset(self, rng: np.random.Generator) -> None:
        """A fresh solver, so an episode does not depend on the previous one (``rng`` is unused)."""
        self._solver = self._make_solver()

    def _cold_start(self) -> None:
        self._solver.warm_start(x=np.zeros(self._num_vars), y=np.zeros(self._num_vars))

    def error(self, state: np.ndarray) -> np.ndarray:
        """The linear model's state ``[dq, dv]`` (2 nv,) for ``state = [qpos, qvel]`` (nq + nv,)."""
        nq = self.model.nq
        return state_error(self.model, self.qpos_ref, self.qvel_ref, state[:nq], state[nq:], self.hinge_error)

    def _cost(self, x0: np.ndarray, U: np.ndarray) -> float:
        predicted = self._Sx @ x0 + self._Sc
        constant = predicted @ self._Qbar @ predicted + x0 @ self._Q @ x0
        return float(U @ self._H @ U + 2.0 * (self._F @ x0 + self._g) @ U + constant)

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose ``ctrl`` (nu,) for ``state = [qpos, qvel]`` (nq + nv,)."""
        state = np.asarray(state, dtype=float)
        expected = (self.model.nq + self.model.nv,)
        if state.shape != expected:
            raise ShapeError(f"LinearMPC expects a state of shape {expected} ([qpos, qvel]), got {state.shape}")
        if not np.all(np.isfinite(state)):
            action = np.clip(self.ctrl_ref, self.ctrl_min, self.ctrl_max)
            info = {"solve_ms": 0.0, "status": float(STATUS_NONFINITE_STATE), "osqp_status": 0.0, "iterations": 0.0}
            return SkillOutput(action, {**info, "cost": 0.0})
        x0 = self.error(state)
        start = time.perf_counter()
        self._solver.update(q=self._F @ x0 + self._g)
        result = self._solver.solve(raise_error=False)
        solve_ms = 1e3 * (time.perf_counter() - start)
        U = np.array(result.x, dtype=float)
        if not np.all(np.isfinite(U)):
            status = STATUS_NONFINITE_SOLUTION
        elif result.info.status_val != osqp.SolverStatus.OSQP_SOLVED:
            status = STATUS_NOT_CONVERGED
        else:
            status = STATUS_OK
        if status == STATUS_OK:
            u0, cost = U[: self.model.nu], self._cost(x0, U)
        else:
            self._cold_start()  # a failed solve leaves a useless warm start
            u0, cost = -self.lqr_gain @ x0, float(x0 @ self.terminal_cost @ x0)
        action = np.clip(self.ctrl_ref + u0, self.ctrl_min, self.ctrl_max)
        info = {
            "solve_ms": solve_ms,
            "status": float(status),
            "osqp_status": float(result.info.status_val),
            "iterations": float(result.info.iter),
            "cost": cost,
        }
        return SkillOutput(action, info)
