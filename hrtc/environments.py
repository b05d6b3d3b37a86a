"""The environments a run acts in: the task (``ppo``) or the task composed with its skills (``hrtc``), one or many.

Tasks are looked up by name in the task registry (``envs.make``); the core imports no task module itself.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from hrtc.composition import ComposedEnv, build_library
from hrtc.vector import RestartingVectorEnv


def make_env(task: str, algo: str, skills: Mapping[str, Any], action_filter: str = "sum",
             env_kwargs: Mapping[str, Any] | None = None, decision_every: int = 1,
             diagnostics: bool = True, weight_margin: float = 0.0) -> gym.Env:  # fmt: skip
    """The environment the policy acts in: the task itself (``ppo``) or the task composed with its skills (``hrtc``).
    ``diagnostics``: the composed env's timings and fault counters in ``info``; ``weight_margin``: the span of its
    weights beyond [0, 1] (see :class:`ComposedEnv`)."""
    import envs  # the task registry (its package imports the shipped tasks so that they register)

    env = envs.make(task, **dict(env_kwargs or {}))
    if algo == "hrtc":
        library = build_library(skills)
        env = ComposedEnv(env, library, action_filter, decision_every, diagnostics, weight_margin)  # type: ignore[arg-type]
    return env


# env_kwargs that write into a training run's directory (carracing's log of every finished episode, which the
# benchmark's solve rules read): a saved run's settings without them for any later evaluation of its checkpoints.
RUN_LOG_KWARGS = ("episode_log",)


def evaluation_env_kwargs(env_kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
    """A saved run's ``env_kwargs`` for evaluating its policy: without :data:`RUN_LOG_KWARGS`, so the evaluation's
    episodes never land in the training run's logs."""
    return {k: v for k, v in dict(env_kwargs or {}).items() if k not in RUN_LOG_KWARGS}


def env_factory(cfg: Any) -> Callable[[], gym.Env]:
    """A picklable thunk building the env of run config ``cfg`` (a :class:`~hrtc.config.RunConfig`), so that
    vector-environment workers build their own env and skills."""
    return functools.partial(make_env, cfg.task, cfg.algo, cfg.skills, cfg.action_filter, cfg.env_kwargs,
                             cfg.decision_every, weight_margin=cfg.weight_margin)  # fmt: skip


def vector_env(make: Callable[[], gym.Env], num_envs: int, mode: str = "async",
               max_restarts: int = 5) -> gym.vector.VectorEnv:  # fmt: skip
    """``num_envs`` copies of ``make()`` stepped together, in worker processes (``async``, more than one env) or in
    this process (``sync``); an ended episode resets in the same step (its final observation in ``info``). A worker
    that dies is replaced, up to ``max_restarts`` times (:class:`~hrtc.vector.RestartingVectorEnv`)."""
    fns = [make for _ in range(num_envs)]
    autoreset = gym.vector.AutoresetMode.SAME_STEP
    if mode == "async" and num_envs > 1:
        return RestartingVectorEnv(fns, max_restarts, context="fork")
    return gym.vector.SyncVectorEnv(fns, autoreset_mode=autoreset)


def frame_source(env: gym.Env, size: Sequence[int]) -> Callable[[], np.ndarray | None] | None:
    """A function returning the task's current camera frame (RGB, (H, W, 3) uint8), or None if it cannot render.
    ``size`` (height, width) applies to tasks that choose their frame size (the MuJoCo tasks)."""
    base = env.unwrapped
    if hasattr(base, "render_size"):
        base.render_size = (int(size[0]), int(size[1]))
        return base.render
    if getattr(base, "render_mode", None) == "rgb_array":
        return base.render
    return None


def timed(work: Callable[[], Any]) -> tuple[Any, float]:
    """``work()`` and the seconds it took."""
    tic = time.perf_counter()
    return work(), time.perf_counter() - tic


def no_update() -> None:
    return None


def step_while(vec: gym.vector.VectorEnv, action: np.ndarray, work: Callable[[], Any]) -> tuple[tuple, tuple]:
    """Step ``vec`` with ``action`` and run ``work()`` meanwhile when the envs step in worker processes. Returns the
    step's results and ``(work(), its seconds)``."""
    if isinstance(vec, gym.vector.AsyncVectorEnv):
        vec.step_async(action)
        done = timed(work)
        return vec.step_wait(), done
    done = timed(work)
    return vec.step(action), done
