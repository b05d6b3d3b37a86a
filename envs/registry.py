"""The task registry: ``make(name)`` returns a ``gymnasium.Env``; ``names()`` lists what ``make`` accepts."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym

from hrtc.errors import UnknownNameError

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


def mj_model(name: str) -> Any:
    """The ``mujoco.MjModel`` of task ``name`` (a copy, for skills that build a model of the plant)."""
    import copy

    env = make(name)
    try:
        return copy.copy(env.unwrapped.physics.model.ptr)
    finally:
        env.close()
