"""Shared by the skill tests: the real dm_control cart-pole and the default state filter."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
import pytest

import envs


def filtered_state(env: Any, keys: Sequence[str]) -> np.ndarray:
    """The default state filter: the named quantities ``keys`` of the env's current state, concatenated."""
    state = env.unwrapped.skill_state()
    return np.concatenate([np.atleast_1d(state[k]) for k in keys]).astype(np.float64)


def set_cartpole_state(env: Any, qpos: Sequence[float], qvel: Sequence[float]) -> None:
    """Put the cart-pole at ``qpos = (x m, theta rad)``, ``qvel = (x_dot m/s, theta_dot rad/s)``, theta 0 upright."""
    physics = env.unwrapped.physics
    with physics.reset_context():
        physics.data.qpos[:] = qpos
        physics.data.qvel[:] = qvel


@pytest.fixture
def cartpole() -> Iterator[Any]:
    """A fresh ``cartpole_swingup`` env (1000 steps of 0.01 s), closed after the test."""
    env = envs.make("cartpole_swingup")
    yield env
    env.close()


@pytest.fixture(name="filtered_state")
def filtered_state_fixture() -> Callable[[Any, Sequence[str]], np.ndarray]:
    return filtered_state


@pytest.fixture(name="set_cartpole_state")
def set_cartpole_state_fixture() -> Callable[[Any, Sequence[float], Sequence[float]], None]:
    return set_cartpole_state
