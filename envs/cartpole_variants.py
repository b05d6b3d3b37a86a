"""Cart-pole variants: tasks with a reward of their own (to train one skill alone) and tasks with changed physics (to
test transfer and fine-tuning).

Own-reward tasks (the paper's "each skill can have its own reward function"):
- ``cartpole_energy``: starts hanging; rewarded for the pole's mechanical energy reaching the upright level,
  ``r = clip(1 - |E| / (2 m g l), 0, 1) * centred``; ``E`` is 0 upright at rest and ``-2 m g l`` hanging at rest, J.
  It rewards swinging up, not balancing: a pole that swings through upright with the right energy scores fully.
- ``cartpole_upright``: starts anywhere within 0.6 rad of upright, with up to 1 rad/s of pole velocity; rewarded for
  keeping the pole near upright, ``r = exp(-theta^2 / (2 * 0.25^2)) * centred``, theta in rad.

Changed physics (dm_control's swing-up reward and start, the model edited before compiling):
- ``cartpole_swingup_heavy``: the pole's mass times ``pole_mass_scale`` (default 3: 0.3 kg instead of 0.1 kg).
- ``cartpole_swingup_long``: the pole's length times ``pole_length_scale`` (default 1.5: 1.5 m), same mass.

``centred = (1 + tolerance(x, margin=2)) / 2`` is dm_control's cart-centring factor (x the cart position, m). Every
variant keeps the cart-pole's observation, action and named state, so skills and checkpoints move between them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
from dm_control.rl import control
from dm_control.suite import cartpole
from dm_control.utils import rewards

from envs.cartpole import cartpole_state
from envs.dm_control_env import DMControlEnv
from envs.registry import register
from hrtc.errors import ConfigError

UPRIGHT_WIDTH = 0.25  # rad: the std of cartpole_upright's Gaussian reward in the pole angle
UPRIGHT_START_ANGLE = 0.6  # rad: cartpole_upright starts uniformly within this of upright
UPRIGHT_START_SPEED = 1.0  # rad/s: ... and with a pole angular velocity uniformly within this


def _centred(physics: Any) -> float:
    return float((1.0 + rewards.tolerance(physics.cart_position(), margin=2)) / 2.0)


def _pole_energy(physics: Any) -> tuple[float, float]:
    """The pole's mechanical energy relative to resting upright and the swing ``2 m g l`` (both J), read off the
    compiled model (so an edited pole is measured with its own mass and length)."""
    model, data = physics.model, physics.data
    pole = physics.model.name2id("pole_1", "body")
    mass, com = float(model.body_mass[pole]), float(model.body_ipos[pole][2])
    inertia = float(model.body_inertia[pole][1]) + mass * com**2  # about the hinge
    gravity = float(-model.opt.gravity[2])
    theta, theta_dot = float(data.qpos[1]), float(data.qvel[1])
    energy = 0.5 * inertia * theta_dot**2 + mass * gravity * com * (np.cos(theta) - 1.0)
    return energy, 2.0 * mass * gravity * com


class EnergyTask(cartpole.Balance):
    """Swing-up start; reward for the pole's energy at the upright level (see the module doc)."""

    def __init__(self, random: Any = None) -> None:
        super().__init__(swing_up=True, sparse=False, random=random)

    def get_reward(self, physics: Any) -> float:
        energy, swing = _pole_energy(physics)
        return float(np.clip(1.0 - abs(energy) / swing, 0.0, 1.0)) * _centred(physics)


class UprightTask(cartpole.Balance):
    """Start within ``UPRIGHT_START_ANGLE`` of upright; reward for staying near upright (see the module doc)."""

    def __init__(self, random: Any = None) -> None:
        super().__init__(swing_up=False, sparse=False, random=random)

    def initialize_episode(self, physics: Any) -> None:
        physics.named.data.qpos["slider"] = self.random.uniform(-0.25, 0.25)
        physics.named.data.qpos["hinge_1"] = self.random.uniform(-UPRIGHT_START_ANGLE, UPRIGHT_START_ANGLE)
        physics.named.data.qvel["slider"] = 0.0
        physics.named.data.qvel["hinge_1"] = self.random.uniform(-UPRIGHT_START_SPEED, UPRIGHT_START_SPEED)
        # base.Task's hook (Balance's would overwrite this start): after_reset bookkeeping only.
        super(cartpole.Balance, self).initialize_episode(physics)

    def get_reward(self, physics: Any) -> float:
        qpos = physics.data.qpos
        angle = float(np.arctan2(np.sin(qpos[1]), np.cos(qpos[1])))
        return float(np.exp(-0.5 * (angle / UPRIGHT_WIDTH) ** 2)) * _centred(physics)


def cartpole_xml(pole_mass_scale: float = 1.0, pole_length_scale: float = 1.0) -> tuple[str, dict]:
    """dm_control's cart-pole model with the pole's mass and length scaled; returns (xml, assets) for
    ``Physics.from_xml_string``. The pole is a capsule of 0.1 kg from the hinge to 1 m above it."""
    for name, value in (("pole_mass_scale", pole_mass_scale), ("pole_length_scale", pole_length_scale)):
        if not (np.isfinite(value) and 0.1 <= value <= 10.0):
            raise ConfigError(f"{name} must lie in [0.1, 10], got {value}")
    xml, assets = cartpole.get_model_and_assets()
    root = ET.fromstring(xml)
    geom = root.find("./default/default[@class='pole']/geom")
    if geom is None:  # dm_control's file changed shape: refuse rather than silently leave the pole as it was
        raise ConfigError("dm_control's cartpole.xml has no pole geom default to edit")
    geom.set("mass", repr(float(geom.get("mass", "0.1")) * pole_mass_scale))
    x0, y0, z0, x1, y1, z1 = (float(v) for v in geom.get("fromto", "0 0 0 0 0 1").split())
    geom.set("fromto", f"{x0} {y0} {z0} {x1} {y1} {z0 + (z1 - z0) * pole_length_scale}")
    return ET.tostring(root, encoding="unicode"), assets


class CartpoleVariantEnv(DMControlEnv):
    """A :class:`DMControlEnv` on an edited cart-pole model with a given dm_control task.

    Args:
        task_factory: builds the dm_control task from a seed (``random``).
        pole_mass_scale, pole_length_scale: see :func:`cartpole_xml`.
        time_limit: episode length, s (20 s, 1000 steps of 0.01 s, by default).
        environment_kwargs, render_mode, render_size, camera_id: as for :class:`DMControlEnv`.
    """

    def __init__(
        self,
        task_factory: Any,
        *,
        pole_mass_scale: float = 1.0,
        pole_length_scale: float = 1.0,
        time_limit: float | None = None,
        environment_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            "cartpole", "swingup", named_state=cartpole_state, time_limit=time_limit,
            environment_kwargs=environment_kwargs, **kwargs,
        )  # fmt: skip
        # The base class loaded the stock swing-up (spaces, dt); swap in the edited physics and our task. The
        # observation and action specs are those of every cart-pole, so the spaces it set still hold.
        physics = cartpole.Physics.from_xml_string(*cartpole_xml(pole_mass_scale, pole_length_scale))
        limit = cartpole._DEFAULT_TIME_LIMIT if time_limit is None else float(time_limit)
        self._env.close()
        self._env = control.Environment(
            physics, task_factory(random=0), time_limit=limit, **dict(environment_kwargs or {})
        )


def _swingup_task(random: Any = None) -> cartpole.Balance:
    return cartpole.Balance(swing_up=True, sparse=False, random=random)


@register("cartpole_energy")
def cartpole_energy(**kwargs: Any) -> CartpoleVariantEnv:
    """Swing-up start, reward for pole energy at the upright level; 1000 steps of 0.01 s; reward in [0, 1]."""
    return CartpoleVariantEnv(EnergyTask, **kwargs)


@register("cartpole_upright")
def cartpole_upright(**kwargs: Any) -> CartpoleVariantEnv:
    """Start within 0.6 rad of upright, reward for staying near upright; 1000 steps of 0.01 s; reward in [0, 1]."""
    return CartpoleVariantEnv(UprightTask, **kwargs)


@register("cartpole_swingup_heavy")
def cartpole_swingup_heavy(pole_mass_scale: float = 3.0, **kwargs: Any) -> CartpoleVariantEnv:
    """dm_control's swing-up with the pole ``pole_mass_scale`` times heavier (0.3 kg by default)."""
    return CartpoleVariantEnv(_swingup_task, pole_mass_scale=pole_mass_scale, **kwargs)


@register("cartpole_swingup_long")
def cartpole_swingup_long(pole_length_scale: float = 1.5, **kwargs: Any) -> CartpoleVariantEnv:
    """dm_control's swing-up with the pole ``pole_length_scale`` times longer (1.5 m by default), same mass."""
    return CartpoleVariantEnv(_swingup_task, pole_length_scale=pole_length_scale, **kwargs)
