"""dm_control's acrobot swing-up, with the named quantities skills read.

Two 1 m links on hinges about +y: the shoulder is passive, the elbow is driven (gear 2: at most 2 N m). MuJoCo's
``qpos`` is zero with both links pointing up, so conventions here are: ``shoulder_angle`` the upper link's angle from
upright, ``elbow_angle`` the lower link's angle relative to the upper link, both wrapped to (-pi, pi], rad, positive
about +y; velocities in rad/s; ``tip_distance`` the distance (m) from the lower link's tip to the target 4 m up,
where the tip of the upright acrobot is. Episodes start at uniformly random angles at rest; 1000 steps of 0.01 s;
reward 1 while the tip is within 0.2 m of the target, falling off smoothly over the next metre.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from envs.dm_control_env import DMControlEnv
from envs.pendulum import wrap
from envs.registry import register


def acrobot_state(physics: Any) -> dict[str, np.ndarray]:
    qpos, qvel = physics.data.qpos, physics.data.qvel
    return {
        "shoulder_angle": np.array([wrap(qpos[0])]),
        "elbow_angle": np.array([wrap(qpos[1])]),
        "shoulder_velocity": np.array([qvel[0]]),
        "elbow_velocity": np.array([qvel[1]]),
        "tip_distance": np.array([float(physics.to_target())]),
    }


@register("acrobot_swingup")
def acrobot_swingup(**kwargs: Any) -> DMControlEnv:
    """Swing the acrobot up by its elbow alone and balance it; 1000 steps of 0.01 s; reward in [0, 1] per step."""
    return DMControlEnv("acrobot", "swingup", named_state=acrobot_state, **kwargs)
