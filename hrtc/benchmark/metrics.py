"""Metric plug-ins: what a benchmark measures beyond the evaluation curve, per run and per reference rule.

A benchmark config names one (``metric: {name: ..., ...}``); the run's worker calls :func:`after_training` once the
run is trained, and the driver evaluates the reference rules with :func:`evaluate_references`. Every episode runs
through :func:`hrtc.trainer.run_episodes`.

- ``returns`` (the default): the evaluation curve, the final policy's returns over ``final_episodes`` (and the best
  evaluated policy's with ``final_best``: LunarLander's 100-episode means on seeds disjoint from the evaluations).
- ``success``: success on unseen targets (panda_reach): each checkpoint in ``checkpoints`` (``best``, ``last``) and
  each reference acts on ``episodes`` episodes of seeds ``seed_base + k``, the same for every method; the env's
  ``info`` says ``success``, ``collision`` and ``distance`` at every env step, its reset ``info`` the target's
  ``family`` (named by ``families``). An episode ends at its first success. Learned policies act at their decision
  rate, held in between; references decide at every env step.
- ``episodes``: the training episodes themselves (CarRacing): every finished episode logged by the env
  (``episode_log``), the solve rules over ``windows`` consecutive episodes, frames per second, and the projection
  to the paper's episodes-to-solve (``paper_episodes``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

METRICS = ("returns", "success", "episodes")
# The keys each metric's arguments may hold, with their defaults.
METRIC_ARGS: dict[str, dict[str, Any]] = {
    "returns": {},
    "success": {"episodes": 1000, "seed_base": 2_000_000, "checkpoints": ["best"], "families": []},
    "episodes": {"windows": [10, 100], "paper_episodes": {}, "cutoff": 10_000},
}
EPISODE_LOG = ["wall_time", "pid", "reset_seed", "return", "frames", "lap_finished", "true_return", "early_stop"]


def after_training(spec: Any, started: float) -> dict[str, Any]:
    """The metric's measurements of a trained run (``spec``: its :class:`~hrtc.benchmark.runs.RunSpec`;
    ``started``: the training's start, epoch seconds)."""
    args = {**METRIC_ARGS[spec.metric], **dict(spec.metric_args)}
    run_dir = Path(spec.run_dir)
    if spec.metric == "success":
        seeds = [int(args["seed_base"]) + k for k in range(int(args["episodes"]))]
        out = {}
        for which in args["checkpoints"]:
            rows = checkpoint_success(run_dir / "checkpoints" / f"{which}.pt", seeds)
            out[which] = {"summary": summarise_success(rows, args["families"]), "episodes": rows}
        return {"success": out}
    if spec.metric == "episodes":
        return {"episodes_log": training_episodes(run_dir, spec.seed, started, args)}
    return {}


# --------------------------------------------------------------------------------------------------- policies
def checkpoint_env(meta: Mapping[str, Any], decision_every: int | None = None) -> gym.Env:
    """The env a checkpoint's policy acts in (its task, skills and env_kwargs), deciding every ``decision_every``
    env steps (default: the checkpoint's own rate)."""
    from hrtc.environments import evaluation_env_kwargs, make_env

    every = int(meta["decision_every"]) if decision_every is None else decision_every
    kwargs = evaluation_env_kwargs(meta["env_kwargs"])  # never the training run's episode log
    return make_env(meta["task"], meta["algo"], meta["skills_cfg"], meta["action_filter"], kwargs, every,
                    weight_margin=float(meta.get("weight_margin", 0.0)))  # fmt: skip


def checkpoint_returns(path: str | Path, seeds: Sequence[int]) -> np.ndarray:
    """Deterministic returns of a trainer checkpoint (HRTC or PPO) on ``seeds``."""
    import torch

    from hrtc.checkpoint import load_policy
    from hrtc.episodes import evaluate

    torch.set_num_threads(1)
    loaded = load_policy(path)
    env = checkpoint_env(loaded.meta)
    try:
        return evaluate(loaded.policy, loaded.normalizer, env, seeds, loaded.meta["dist"])
    finally:
        env.close()


# --------------------------------------------------------------------------------------------------- success
class SuccessWatch(gym.Wrapper):
    """Per episode: success (and the time to it), collisions, the closest distance, the target's family; an episode
    ends at its first success. ``steps`` counts the env steps of the current episode."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rows: list[dict[str, Any]] = []
        self.steps = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        family = info.get("family", getattr(self.env.unwrapped, "family", -1))
        self.rows.append({"seed": int(kwargs.get("seed", -1)), "family": int(family), "success": False,
                          "time_to_reach": math.nan, "collision": False, "closest": math.inf})  # fmt: skip
        self.steps = 0
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        row = self.rows[-1]
        row["collision"] = row["collision"] or bool(info["collision"])
        row["closest"] = min(row["closest"], float(info["distance"]))
        if info["success"]:
            row["success"], row["time_to_reach"] = True, self.steps * float(getattr(self.env.unwrapped, "dt", 1.0))
            terminated = True
        return obs, reward, terminated, truncated, info


def success_rows(env: gym.Env, decide: Callable[[np.ndarray], Any], seeds: Sequence[int], every: int = 1) -> list:
    """One row per episode of ``decide`` on ``env`` (stepping one env step at a time), re-deciding every ``every``
    env steps and holding the decision in between."""
    from hrtc.episodes import run_episodes

    watch = SuccessWatch(env)
    held: list[Any] = []

    def hold(obs: np.ndarray) -> Any:
        if watch.steps % every == 0 or not held:
            held[:] = [decide(obs)]
        return held[0]

    run_episodes(watch, hold, seeds)
    return watch.rows


def checkpoint_success(path: Path, seeds: Sequence[int]) -> list[dict[str, Any]]:
    import torch

    from hrtc.checkpoint import load_policy
    from hrtc.episodes import mode_decider

    torch.set_num_threads(1)
    loaded = load_policy(path)
    # One env step at a time (the decision held by success_rows), so success and collisions count at every step.
    env = checkpoint_env(loaded.meta, decision_every=1)
    try:
        decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])
        return success_rows(env, decide, seeds, int(loaded.meta["decision_every"]))
    finally:
        env.close()


def summarise_success(rows: list[dict[str, Any]], families: Sequence[str] = ()) -> dict[str, Any]:
    """Success, collisions, success without collision, mean time to reach (successes), median closest distance
    (mm): over all episodes and per family."""

    def stats(part: list[dict[str, Any]]) -> dict[str, float]:
        if not part:
            return {"targets": 0}
        ok = np.array([r["success"] for r in part])
        hit = np.array([r["collision"] for r in part])
        times = [r["time_to_reach"] for r in part if r["success"]]
        return {"targets": len(part), "success": float(ok.mean()), "collision": float(hit.mean()),
                "success_without_collision": float((ok & ~hit).mean()),
                "mean_time_to_reach_s": float(np.mean(times)) if times else math.nan,
                "median_closest_mm": float(np.median([r["closest"] for r in part]) * 1e3)}  # fmt: skip

    out = {"all": stats(rows)}
    for i, name in enumerate(families):
        out[name] = stats([r for r in rows if r["family"] == i])
    return out


# --------------------------------------------------------------------------------------------------- references
def evaluate_references(task: Mapping[str, Any], rules: Mapping[str, Any], seeds: Sequence[int], metric: str,
                        args: Mapping[str, Any], decision_every: int) -> dict[str, Any]:  # fmt: skip
    """Every reference rule on ``seeds`` (returns) or on the success metric's targets (success rows and summary).
    A rule with ``acts_on_env`` (a controller of the raw task, e.g. gymnasium's own heuristic) acts on the task
    itself; the others weigh the task's skills on the composed env."""
    from hrtc.environments import make_env
    from hrtc.episodes import Decision, run_episodes
    from hrtc.references import FixedWeights, rule_decider

    args = {**METRIC_ARGS[metric], **dict(args)}
    out: dict[str, Any] = {}
    for name, rule in rules.items():
        skills = dict(task["skills"])
        if metric == "success" and isinstance(rule, FixedWeights) and rule.default == 0:
            # Only the skills with a weight: the others add exactly nothing to the blend, at their cost.
            skills = {k: v for k, v in skills.items() if rule.weights.get(k, 0)}
        raw = getattr(rule, "acts_on_env", False)
        every = 1 if metric == "success" else decision_every
        env = make_env(task["name"], "ppo" if raw else "hrtc", skills, env_kwargs=task.get("env_kwargs"),
                       decision_every=every)  # fmt: skip
        if raw:

            def decide(obs: np.ndarray, env: gym.Env = env, rule: Any = rule) -> Decision:
                action = np.asarray(rule.act(env, obs), np.float32)
                return Decision(np.asarray(obs, np.float32), action, action)

        else:
            decide = rule_decider(env, rule)
        tic = time.perf_counter()
        if metric == "success":
            targets = [int(args["seed_base"]) + k for k in range(int(args["episodes"]))]
            rows = success_rows(env, decide, targets)
            out[name] = {"summary": summarise_success(rows, args["families"]), "episodes": rows}
        else:
            out[name] = run_episodes(env, decide, seeds).tolist()
        env.close()
        print(f"reference {name}: {time.perf_counter() - tic:.0f} s", flush=True)
    return out


# --------------------------------------------------------------------------------------------------- episodes
def solved_at(returns: np.ndarray, window: int, threshold: float) -> int | None:
    """The 1-based episode at which the mean of the last ``window`` returns first reaches ``threshold``."""
    if len(returns) < window:
        return None
    means = np.convolve(returns, np.ones(window) / window, mode="valid")
    hit = np.flatnonzero(means >= threshold)
    return int(hit[0]) + window if len(hit) else None


def best_window_mean(returns: np.ndarray, window: int) -> float | None:
    if len(returns) < window:
        return None
    return float(np.convolve(returns, np.ones(window) / window, mode="valid").max())


def running_scores(returns: np.ndarray, decay: float = 0.99) -> np.ndarray:
    """The reference CarRacing implementation's running score after each episode: ``running <- decay running +
    (1 - decay) score``, from 0 (xtma/pytorch_car_caring's ``train.py``; it calls the task solved above 900)."""
    out, running = np.empty(len(returns)), 0.0
    for i, score in enumerate(np.asarray(returns, float)):
        running = decay * running + (1.0 - decay) * score
        out[i] = running
    return out


def running_solved_at(returns: np.ndarray, threshold: float, decay: float = 0.99) -> int | None:
    """The 1-based episode after which the running score (:func:`running_scores`) first exceeds ``threshold``."""
    hit = np.flatnonzero(running_scores(returns, decay) > threshold)
    return int(hit[0]) + 1 if len(hit) else None


def training_episodes(run_dir: Path, seed: int, started: float, args: Mapping[str, Any]) -> dict[str, Any]:
    """The run's training episodes from its ``episodes.csv`` (the trainer's evaluation episodes, told apart by their
    reset seed, left out), in the order they finished; frames per second over training and evaluation."""
    import pandas as pd

    from hrtc.episodes import eval_seeds

    path = run_dir / "episodes.csv"
    log = pd.read_csv(path, names=EPISODE_LOG) if path.exists() and path.stat().st_size else pd.DataFrame(
        columns=EPISODE_LOG)  # fmt: skip
    train = log[~log["reset_seed"].isin(eval_seeds(seed, 10_000))].sort_values("wall_time")
    returns = train["return"].to_numpy(float)
    wall = float(log["wall_time"].max() - started) if len(log) else 0.0
    frames = int(log["frames"].sum())
    return {"returns": returns.tolist(), "true_returns": train["true_return"].to_numpy(float).tolist(),
            "train_frames": train["frames"].to_numpy(int).tolist(), "frames": frames, "wall_seconds": wall,
            "frames_per_second": frames / wall if wall > 0 else math.nan}  # fmt: skip
