"""dm_control's pendulum swing-up, with the named quantities skills read.

The pole hangs from a hinge about +y: a 1 kg point-like mass 0.5 m from the hinge, torque-limited to 1 N m (a fifth
of ``m g l``), so it must be pumped up. Conventions: ``pole_angle`` is 0 upright and wrapped to (-pi, pi], rad,
positive about +y (MuJoCo's ``qpos``, whose zero is upright); ``pole_angular_velocity`` in rad/s. Episodes start
at a uniformly random angle at rest; 1000 steps of 0.02 s; reward 1 while the pole is within 8 degrees of upright,
else 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from envs.dm_control_env import DMControlEnv
from envs.registry import register


def wrap(angle: Any) -> Any:
    """Angle(s) wrapped to (-pi, pi], rad."""
    return np.arctan2(np.sin(angle), np.cos(angle))


def pendulum_state(physics: Any) -> dict[str, np.ndarray]:
    qpos, qvel = physics.data.qpos, physics.data.qvel
    return {"pole_angle": np.array([wrap(qpos[0])]), "pole_angular_velocity": np.array([qvel[0]])}


@register("pendulum_swingup")
def pendulum_swingup(**kwargs: Any) -> DMControlEnv:
    """Swing the torque-limited pendulum up and hold it within 8 degrees of upright; 1000 steps of 0.02 s."""
    return DMControlEnv("pendulum", "swingup", named_state=pendulum_state, **kwargs)
