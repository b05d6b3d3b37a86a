"""The dm_control cartpole tasks, with the named quantities skills read.

Conventions: ``pole_angle`` is 0 upright and wrapped to (-pi, pi], rad, positive about +y (the hinge axis);
``cart_position`` m along the rail (limits +-1.8 m); velocities in m/s and rad/s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from envs.dm_control_env import DMControlEnv
from envs.registry import register


def cartpole_state(physics: Any) -> dict[str, np.ndarray]:
    qpos, qvel = physics.data.qpos, physics.data.qvel
    angle = float(np.arctan2(np.sin(qpos[1]), np.cos(qpos[1])))
    return {
        "cart_position": np.array([qpos[0]]),
        "cart_velocity": np.array([qvel[0]]),
        "pole_angle": np.array([angle]),
        "pole_angular_velocity": np.array([qvel[1]]),
    }


@register("cartpole_swingup")
def cartpole_swingup(**kwargs: Any) -> DMControlEnv:
    """Swing the pole up from hanging and balance it; 1000 steps of 0.01 s; reward in [0, 1] per step."""
    return DMControlEnv("cartpole", "swingup", named_state=cartpole_state, **kwargs)


@register("cartpole_balance")
def cartpole_balance(**kwargs: Any) -> DMControlEnv:
    """Keep the pole upright from a near-upright start; 1000 steps of 0.01 s."""
    return DMControlEnv("cartpole", "balance", named_state=cartpole_state, **kwargs)
