"""How soon can the acrobot's tip reach the target? The catch NMPC in closed loop against multi-start trajectory
optimisation on the same model, from the same evaluation starts.

    PYTHONPATH=. python benchmarks/results/acrobot_swingup/ceiling/swingup_time.py [--seed 1] [--episodes 10]
        [--guesses 40] [--horizon 6.0]

For each evaluation start of ``--seed`` (the benchmark's and ``eval_skill.py``'s episodes):
- the task's ``catch`` skill alone on the real env (weight 1, as ``eval_skill.py skill=catch``): its return and the
  first time its tip comes within 0.2 m of the target (dm_control's reward is 1 there);
- one open-loop plan over ``--horizon`` s, optimised by IPOPT on the catch's own model (RK4 of
  ``skills.acrobot_model``, 0.04 s steps, the elbow's 2 N m bound) for a cost that is the task's own reward turned
  into a loss, ``sum_k 1 - r(d_k)`` with ``r`` dm_control's tolerance (1 within 0.2 m, 0.1 at 1.2 m) plus
  ``0.01 d_k^2`` (a slope far from the target, where ``r`` is flat) and an upright-at-rest terminal term; started from
  the energy swing-up's rollout, its mirror for the first second, and ``--guesses`` random bang-bang torque sequences
  (segments of 0.15-0.8 s); the best plan's first time within 0.2 m and its return on the model (``4 r`` per 0.04 s
  step over 1000 env steps, the terminal reward held after the horizon: an optimistic bound, since the plan is not
  stabilised and the model is not MuJoCo's integrator).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import casadi
import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.cli import build_env, task_config  # noqa: E402
from hrtc.episodes import eval_seeds, run_episodes  # noqa: E402
from hrtc.references import FixedWeights, rule_decider  # noqa: E402
from skills.nmpc import AcrobotUprightMPC  # noqa: E402
from skills.swingup import AcrobotEnergySwingUp  # noqa: E402

DT, STEPS, RADIUS = 0.04, 1000, 0.2
LOG10 = float(np.log(10.0))  # dm_control's gaussian tolerance: 0.1 at one margin (1 m) past the radius
STATE_KEYS = ("shoulder_angle", "elbow_angle", "shoulder_velocity", "elbow_velocity")


def tip_distance(q1, q2, math=np):
    """m, from the tip to the target straight above the shoulder (both 1 m links upright)."""
    x, y = math.sin(q1) + math.sin(q1 + q2), math.cos(q1) + math.cos(q1 + q2)
    return math.sqrt(x**2 + (y - 2.0) ** 2 + 1e-12)


def reward(d, math=np):
    """dm_control's acrobot swing-up reward at tip distance ``d``."""
    gap = math.fmax(d - RADIUS, 0.0) if math is casadi else np.maximum(d - RADIUS, 0.0)
    return math.exp(-LOG10 * gap**2)


class TipWatch(gym.Wrapper):
    """Per episode: its start (the catch's state keys) and the first env step with the tip within the radius."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rows: list[dict] = []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        state = self.env.unwrapped.skill_state()
        self.rows.append({"start": np.array([state[k][0] for k in STATE_KEYS]), "first": None, "steps": 0})
        return obs, info

    def step(self, action):
        out = self.env.step(action)
        row = self.rows[-1]
        row["steps"] += 1
        if row["first"] is None and self.env.unwrapped.skill_state()["tip_distance"][0] < RADIUS:
            row["first"] = row["steps"]
        return out


class Planner:
    """IPOPT over one long open-loop plan from a given start (see the module's docstring)."""

    def __init__(self, horizon_s: float) -> None:
        model = AcrobotUprightMPC(dt=DT, horizon=2)  # its RK4 step on the MuJoCo model's parameters
        self.step, self.params, self.n = model.step, model.params, int(round(horizon_s / DT))
        n = self.n
        states, controls, start = casadi.MX.sym("S", 4, n + 1), casadi.MX.sym("U", 1, n), casadi.MX.sym("s0", 4)
        d = tip_distance(states[0, :], states[1, :], casadi)
        cost = (casadi.sum2(1.0 - reward(d[:n], casadi)) + 0.01 * casadi.sumsqr(d) + 1e-3 * casadi.sumsqr(controls)
                + 20.0 * (1.0 - reward(d[n], casadi)) + 0.1 * casadi.sumsqr(states[2:, n]))  # fmt: skip
        propagated = self.step.map(n)(states[:, :n], controls)
        gaps = casadi.vertcat(states[:, 0] - start, casadi.vec(states[:, 1:] - propagated))
        nlp = {"x": casadi.vertcat(casadi.vec(states), casadi.vec(controls)), "p": start, "f": cost, "g": gaps}
        options = {"ipopt": {"max_iter": 800, "print_level": 0, "sb": "yes", "tol": 1e-6}}
        self.solver = casadi.nlpsol("swingup_plan", "ipopt", nlp, {"expand": True, "print_time": False, **options})
        self.n_states = 4 * (n + 1)
        p = self.params
        self.lbx = np.r_[np.full(self.n_states, -np.inf), np.full(n, p.control_min)]
        self.ubx = np.r_[np.full(self.n_states, np.inf), np.full(n, p.control_max)]
        self.pump = AcrobotEnergySwingUp("acrobot_swingup")

    def rollout(self, start: np.ndarray, control) -> np.ndarray:
        states, controls = [np.asarray(start, float)], []
        for k in range(self.n):
            controls.append(float(control(states[-1], k)))
            states.append(np.asarray(self.step(states[-1], controls[-1])).ravel())
        return np.r_[np.stack(states).ravel(), controls]

    def guesses(self, start: np.ndarray, count: int, rng: np.random.Generator):
        pump = lambda s: float(self.pump.act(s).action[0])  # noqa: E731
        yield self.rollout(start, lambda s, k: pump(s))
        yield self.rollout(start, lambda s, k: -pump(s) if k * DT < 1.0 else pump(s))
        for _ in range(count):
            sequence, sign = [], rng.choice([-1.0, 1.0])
            while len(sequence) < self.n:
                sequence += [sign * rng.uniform(0.5, 1.0)] * int(rng.uniform(0.15, 0.8) / DT)
                sign = -sign
            yield self.rollout(start, lambda s, k, seq=sequence: seq[k])

    def best(self, start: np.ndarray, count: int, rng: np.random.Generator) -> tuple[float, float]:
        """(first time within the radius, s, or inf; the return on the model) of the cheapest plan."""
        kept = None
        for x0 in self.guesses(start, count, rng):
            result = self.solver(x0=x0, p=start, lbx=self.lbx, ubx=self.ubx, lbg=0.0, ubg=0.0)
            if kept is None or float(result["f"]) < kept[0]:
                kept = (float(result["f"]), np.asarray(result["x"]).ravel())
        plan = kept[1][: self.n_states].reshape(self.n + 1, 4)
        d = tip_distance(plan[:, 0], plan[:, 1])
        r = reward(d)
        first = float(np.argmax(d < RADIUS) * DT) if (d < RADIUS).any() else float("inf")
        per_step = round(DT / 0.01)  # env steps of 0.01 s per plan step
        ret = per_step * r[: self.n].sum() + max(STEPS - per_step * self.n, 0) * r[self.n]
        return first, float(ret)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--guesses", type=int, default=40)
    parser.add_argument("--horizon", type=float, default=6.0)
    args = parser.parse_args()
    task = task_config("acrobot_swingup")
    composed = build_env("acrobot_swingup", "hrtc", task["skills"])
    env, decide = TipWatch(composed), rule_decider(composed, FixedWeights({"catch": 1.0}))
    seeds = eval_seeds(args.seed, args.episodes)
    started = time.perf_counter()
    returns = run_episodes(env, decide, seeds)
    env.close()
    print(f"catch alone, {len(seeds)} episodes of seed {args.seed}: {returns.mean():.1f} "
          f"({time.perf_counter() - started:.0f} s)")  # fmt: skip
    planner, rng = Planner(args.horizon), np.random.default_rng(0)
    print(
        "| episode seed | start (q1, q2) rad | catch: return | catch: tip within 0.2 m at | "
        f"best of {args.guesses + 2} plans: within 0.2 m at | plan's return on the model |"
    )
    print("|---|---|---|---|---|---|")
    for seed, row, ret in zip(seeds, env.rows, returns, strict=True):
        first, plan_return = planner.best(row["start"], args.guesses, rng)
        catch_first = "never" if row["first"] is None else f"{row['first'] * 0.01:.2f} s"
        print(
            f"| {seed} | ({row['start'][0]:+.2f}, {row['start'][1]:+.2f}) | {ret:.0f} | {catch_first} | "
            f"{first:.2f} s | {plan_return:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
