"""The task registry: ``make(name)`` returns a ``gymnasium.Env``; ``names()`` lists what ``make`` accepts."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym

from hrtc.errors import ConfigError, UnknownNameError

_REGISTRY: dict[str, Callable[..., gym.Env]] = {}


def register(name: str) -> Callable[[Callable[..., gym.Env]], Callable[..., gym.Env]]:
    def decorator(factory: Callable[..., gym.Env]) -> Callable[..., gym.Env]:
        if name in _REGISTRY:
            raise ValueError(f"task {name!r} is registered twice")
        _REGISTRY[name] = factory
        return factory

    return decorator


def names() -> tuple[str, ...]:
    return tuple(sorted(_REGISTRY))


def make(name: str, **kwargs: Any) -> gym.Env:
    """Build task ``name``; raises :class:`UnknownNameError` listing the valid names."""
    try:
        factory = _REGISTRY[name]
    except KeyError:
        raise UnknownNameError("task", name, names()) from None
    return factory(**kwargs)


def mj_model(task_or_model: Any) -> Any:
    """The ``mujoco.MjModel`` a skill models its plant with: a copy of task ``task_or_model``'s model if it is a
    task name, the model itself if it already is a ``mujoco.MjModel``."""
    import copy

    import mujoco

    if isinstance(task_or_model, mujoco.MjModel):
        return task_or_model
    if not isinstance(task_or_model, str):
        raise ConfigError(f"model must be a task name or a mujoco.MjModel, got {type(task_or_model).__name__}")
    env = make(task_or_model)
    try:
        return copy.copy(env.unwrapped.physics.model.ptr)
    finally:
        env.close()
