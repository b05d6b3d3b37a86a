"""A thin dm_control -> gymnasium adapter.

Observations are flattened to float32 in the order of the task's observation spec; the time limit is reported as
truncation (dm_control ends such episodes with discount 1); a termination is an episode end with discount 0.
Skills read named physical quantities through :meth:`DMControlEnv.skill_state`, never raw ``qpos`` indices.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")  # before dm_control is imported: headless rendering

import gymnasium as gym
import numpy as np
from dm_control import suite
from dm_control.rl import control

NamedState = Callable[[Any], dict[str, np.ndarray]]


def _flat(observation: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.concatenate([np.asarray(v, dtype=np.float32).ravel() for v in observation.values()])


class DMControlEnv(gym.Env[np.ndarray, np.ndarray]):
    """A dm_control suite task as a ``gymnasium.Env``.

    Args:
        domain, task: suite names, e.g. ``"cartpole"``, ``"swingup"``.
        named_state: maps the physics to the named quantities skills read (units in the task's docs).
        render_size: (height, width) of frames from :meth:`render`, pixels.
        camera_id: camera used by :meth:`render`.
        time_limit: episode length in seconds (the task's default when None).
        environment_kwargs: passed to ``suite.load``.
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(
        self,
        domain: str,
        task: str,
        *,
        named_state: NamedState | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (240, 320),
        camera_id: int = 0,
        time_limit: float | None = None,
        environment_kwargs: Mapping[str, Any] | None = None,
    ) -> None:
        task_kwargs: dict[str, Any] = {"random": 0}
        if time_limit is not None:
            task_kwargs["time_limit"] = float(time_limit)
        self._env: control.Environment = suite.load(
            domain, task, task_kwargs=task_kwargs, environment_kwargs=dict(environment_kwargs or {})
        )
        self._named_state = named_state
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.camera_id = camera_id
        obs_dim = sum(int(np.prod(s.shape)) for s in self._env.observation_spec().values())
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        spec = self._env.action_spec()
        self.action_space = gym.spaces.Box(
            spec.minimum.astype(np.float32), spec.maximum.astype(np.float32), spec.shape, np.float32
        )
        self.dt = float(self._env.control_timestep())  # seconds per env step

    @property
    def physics(self) -> Any:
        """The dm_control ``Physics`` (``physics.model.ptr`` is the ``mujoco.MjModel``)."""
        return self._env.physics

    def skill_state(self) -> dict[str, np.ndarray]:
        """Named physical quantities of the current state, plus ``observation``, ``qpos`` and ``qvel``."""
        physics = self._env.physics
        state = {
            "qpos": physics.data.qpos.copy(),
            "qvel": physics.data.qvel.copy(),
            "observation": _flat(self._env.task.get_observation(physics)).astype(np.float64),
        }
        if self._named_state is not None:
            state.update(self._named_state(physics))
        return state

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.task.random.seed(seed)
        timestep = self._env.reset()
        return _flat(timestep.observation), {}

    def step(self, action: np.ndarray):
        action = np.asarray(action, dtype=np.float64).reshape(self.action_space.shape)
        timestep = self._env.step(action)
        reward = float(timestep.reward or 0.0)
        last = timestep.last()
        terminated = bool(last and timestep.discount == 0.0)
        truncated = bool(last and not terminated)
        return _flat(timestep.observation), reward, terminated, truncated, {}

    def render(self) -> np.ndarray:
        """An RGB frame, (height, width, 3) uint8."""
        height, width = self.render_size
        return self._env.physics.render(height=height, width=width, camera_id=self.camera_id)

    def close(self) -> None:
        self._env.close()
