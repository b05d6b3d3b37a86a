"""``panda_reach``: a Franka Panda (gymnasium-robotics' MJCF and meshes, loaded offline) reaching random end-effector
pose targets on a table with a wall-shaped obstacle in front of it.

Control: the action is a joint-velocity command for the 7 arm joints, rad/s, in ``[-max_joint_velocity, +]``. The
environment integrates it into position targets ``q_cmd += action * control_dt`` (clipped to the joint ranges) that
the model's position servos track; gravity is compensated (``body_gravcomp = 1``, as the real arm's controller does)
so a zero action holds the arm still. The fingers stay closed. ``control_dt`` 0.02 s (50 Hz, 10 physics steps of
2 ms); an episode is ``time_limit`` s (3 s: 150 steps), always ended by truncation.

Targets are end-effector poses (position, m, world frame; orientation as a unit quaternion w, x, y, z) taken from the
forward kinematics of a sampled collision-free joint configuration, so every target is reachable. Three families:

- ``free``: joints near a comfortable configuration; the hand above the table in front of the wall.
- ``limit``: as ``free``, but one joint pushed to within ``limit_margin`` rad of one of its limits.
- ``behind``: the hand low behind the wall (x beyond the wall, below its top): reached by going over the wall.

Reward per step: ``-distance`` (m, end effector to target position) ``+ success_bonus`` while within
``success_radius`` ``- collision_penalty`` while an arm or finger geom touches the obstacle or the table.
``info`` carries ``distance`` (m), ``orientation_error`` (rad), ``success`` (within the radius at this step),
``collision`` (touching at any physics step of this env step), ``family`` (0 free, 1 limit, 2 behind) and
``action_fault`` (the action had NaN / inf and was replaced by zero velocity).
"""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from envs.registry import register
from hrtc.errors import ConfigError, ShapeError, UnknownNameError

log = logging.getLogger(__name__)

SCENE = Path(__file__).resolve().parent / "assets" / "panda_reach.xml"
ARM_JOINTS = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
EE_SITE = "end_effector"
OBSTACLES = ("obstacle", "table")
# A comfortable configuration: elbow bent, hand pointing down 0.31 m in front of the base at 0.49 m height.
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 0.0, 0.785])
FAMILIES = ("free", "limit", "behind")
# Half-widths (rad) of the box around HOME from which free and limit target configurations are drawn.
TARGET_SPREAD = np.array([1.2, 0.6, 0.6, 0.7, 0.8, 0.6, 1.2])
# Targets lie in front of the base (x >= 0.1 m) and no higher than 0.9 m: the table-top workspace.
WORKSPACE = (0.1, 0.9)
# The joints the limit family pushes to a limit: shoulder and elbow pitch, wrist pitch (0-based). The +-2.9 rad yaw
# joints are left out: a target with a yaw joint at its limit often lies on the far side of the joint's range from
# HOME, which no local controller reaches (the arm would have to turn the other way round).
LIMIT_JOINTS = np.array([1, 3, 5])
ARM_DAMPING = np.array([40.0, 40.0, 40.0, 40.0, 4.0, 4.0, 4.0])  # N m s/rad


def franka_assets() -> Path:
    """gymnasium-robotics' ``kitchen_franka/franka_assets`` folder, found without importing the package (its import
    prints warnings about unrelated environments)."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError("panda_reach needs gymnasium-robotics==1.4.2 (pip install gymnasium-robotics==1.4.2)")
    return Path(spec.submodule_search_locations[0]) / "envs" / "assets" / "kitchen_franka" / "franka_assets"


def load_model() -> mujoco.MjModel:
    """The scene's ``MjModel`` (9 DoF: 7 arm joints, 2 fingers), gravity compensated on every body."""
    xml = SCENE.read_text().replace("{franka}", str(franka_assets()))
    spec = mujoco.MjSpec.from_string(xml)
    # Set before compiling: the compiler counts the bodies with gravcomp, and a model edited afterwards skips them.
    for body in spec.bodies:
        body.gravcomp = 1.0
    model = spec.compile()
    # The kitchen model's joint damping (100 N m s/rad on joints 1-4) makes the position servos (kp 870) lag 0.17 rad
    # behind a 1.5 rad/s command; with this damping they track within about 0.02 rad.
    arm_dofs = [model.joint(name).dofadr[0] for name in ARM_JOINTS]
    model.dof_damping[arm_dofs] = ARM_DAMPING
    return model


def collision_geoms(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Ids of the robot's colliding geoms and of the obstacle geoms (wall, table)."""
    obstacle = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in OBSTACLES])
    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "panda0_link0")
    robot_bodies = {b for b in range(model.nbody) if _has_ancestor(model, b, root)}
    colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    robot = np.array([g for g in range(model.ngeom) if colliding[g] and model.geom_bodyid[g] in robot_bodies])
    return robot, obstacle


def _touching(data: mujoco.MjData, robot_mask: np.ndarray, obstacle_mask: np.ndarray) -> bool:
    """Whether a current contact pairs a geom of ``robot_mask`` with one of ``obstacle_mask`` ((ngeom,) bool)."""
    geoms = data.contact.geom[: data.ncon]  # (ncon, 2)
    g1, g2 = geoms[:, 0], geoms[:, 1]
    return bool(np.any((robot_mask[g1] & obstacle_mask[g2]) | (robot_mask[g2] & obstacle_mask[g1])))


def _has_ancestor(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return False


class PandaReachEnv(gym.Env[np.ndarray, np.ndarray]):
    """Reach end-effector pose targets with a 7-DoF Panda (see the module docstring).

    Args:
        time_limit: episode length, s.
        control_dt: seconds per env step (a multiple of the 2 ms physics step).
        max_joint_velocity: bound of the action, rad/s, the same for every arm joint.
        family_probs: probabilities of the target families ``free``, ``limit``, ``behind``.
        limit_margin: (low, high) rad, how far inside its limit the ``limit`` family puts one joint.
        start_noise: rad, half-width of the uniform noise on HOME at reset.
        success_radius: m; the step is a success when the end effector is this close to the target position.
        success_bonus, collision_penalty: reward terms per step (see the module docstring).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        time_limit: float = 3.0,
        control_dt: float = 0.02,
        max_joint_velocity: float = 1.5,
        family_probs: tuple[float, float, float] = (0.4, 0.3, 0.3),
        limit_margin: tuple[float, float] = (0.02, 0.15),
        start_noise: float = 0.05,
        success_radius: float = 0.01,
        success_bonus: float = 1.0,
        collision_penalty: float = 1.0,
        render_mode: str | None = None,
    ) -> None:
        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        substeps = control_dt / self.model.opt.timestep
        if time_limit <= 0 or substeps < 1 or abs(substeps - round(substeps)) > 1e-9:
            raise ConfigError(f"control_dt must be a multiple of {self.model.opt.timestep} s, got {control_dt}")
        probs = np.asarray(family_probs, dtype=np.float64)
        if probs.shape != (3,) or np.any(probs < 0) or probs.sum() <= 0:
            raise ConfigError(f"family_probs must be 3 non-negative numbers (free, limit, behind), got {family_probs}")
        self.family_probs = probs / probs.sum()
        self.substeps = int(round(substeps))
        self.dt = float(control_dt)
        self.max_steps = int(round(time_limit / control_dt))
        self.limit_margin = (float(limit_margin[0]), float(limit_margin[1]))
        self.start_noise = float(start_noise)
        self.success_radius = float(success_radius)
        self.success_bonus, self.collision_penalty = float(success_bonus), float(collision_penalty)
        self.render_mode = render_mode

        self.arm_qpos_adr = np.array([self.model.joint(n).qposadr[0] for n in ARM_JOINTS])
        self.arm_dof_adr = np.array([self.model.joint(n).dofadr[0] for n in ARM_JOINTS])
        self.arm_range = self.model.jnt_range[[self.model.joint(n).id for n in ARM_JOINTS]].copy()  # (7, 2)
        self.ee_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, EE_SITE)
        self.target_mocap = int(self.model.body("target").mocapid[0])
        self.robot_geoms, self.obstacle_geoms = collision_geoms(self.model)
        self._robot_mask = np.zeros(self.model.ngeom, dtype=bool)
        self._robot_mask[self.robot_geoms] = True
        self._obstacle_mask = np.zeros(self.model.ngeom, dtype=bool)
        self._obstacle_mask[self.obstacle_geoms] = True
        wall = self.model.geom("obstacle")
        self.wall_center, self.wall_half = self.model.body("obstacle").pos.copy(), wall.size.copy()

        vmax = float(max_joint_velocity)
        self.action_space = gym.spaces.Box(-vmax, vmax, (7,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (self._obs_dim(),), np.float32)
        # A scratch MjData for sampling targets, so sampling never disturbs the simulation.
        self._scratch = mujoco.MjData(self.model)
        self.q_cmd = HOME.copy()
        self.target_pos, self.target_quat = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        self.family = 0
        self._t = 0
        self._renderer: Any = None

    # ------------------------------------------------------------------ named state
    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """End-effector position (3,) m and unit quaternion (4,) w, x, y, z, world frame."""
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, self.data.site_xmat[self.ee_site])
        return self.data.site_xpos[self.ee_site].copy(), quat

    def orientation_error(self) -> float:
        """Angle (rad) of the rotation from the end effector's orientation to the target's."""
        _, quat = self.ee_pose()
        return float(2.0 * np.arccos(np.clip(abs(np.dot(quat, self.target_quat)), 0.0, 1.0)))

    def in_collision(self) -> bool:
        """Whether a robot geom touches the wall or the table now."""
        return _touching(self.data, self._robot_mask, self._obstacle_mask)

    def skill_state(self) -> dict[str, np.ndarray]:
        """Named quantities skills read: ``arm_qpos`` (7,) rad, ``arm_qvel`` (7,) rad/s, ``ee_pos`` (3,) m,
        ``ee_quat`` (4,), ``target_pos`` (3,) m, ``target_quat`` (4,), ``target_distance`` (1,) m from the end
        effector to the target, ``target_behind_wall`` (1,): 1.0 for a target behind the wall, else 0.0, ``qpos`` and
        ``qvel`` (9,)."""
        ee_pos, ee_quat = self.ee_pose()
        return {
            "qpos": self.data.qpos.copy(),
            "qvel": self.data.qvel.copy(),
            "arm_qpos": self.data.qpos[self.arm_qpos_adr].copy(),
            "arm_qvel": self.data.qvel[self.arm_dof_adr].copy(),
            "ee_pos": ee_pos,
            "ee_quat": ee_quat,
            "target_pos": self.target_pos.copy(),
            "target_quat": self.target_quat.copy(),
            "target_distance": np.array([np.linalg.norm(self.target_pos - ee_pos)]),
            "target_behind_wall": np.array([float(self._behind_wall(self.target_pos))]),
        }

    def _obs_dim(self) -> int:
        return 7 + 7 + 7 + 3 + 3 + 3 + 4 + 4 + 1

    def _observation(self) -> np.ndarray:
        """Joint positions scaled to [-1, 1] over their ranges (7), distance of each joint to its nearer limit in rad
        (7), joint velocities (7), ee position (3), target position (3), target - ee (3), ee and target quaternions
        (4 + 4), fraction of the episode elapsed (1)."""
        q = self.data.qpos[self.arm_qpos_adr]
        low, high = self.arm_range[:, 0], self.arm_range[:, 1]
        ee_pos, ee_quat = self.ee_pose()
        obs = np.concatenate([
            2.0 * (q - low) / (high - low) - 1.0,
            np.minimum(q - low, high - q),
            self.data.qvel[self.arm_dof_adr],
            ee_pos,
            self.target_pos,
            self.target_pos - ee_pos,
            ee_quat,
            self.target_quat,
            [self._t / self.max_steps],
        ])  # fmt: skip
        return obs.astype(np.float32)

    # ------------------------------------------------------------------ targets
    def _clear(self, q: np.ndarray) -> bool:
        """FK of arm configuration ``q`` into the scratch data; True when no robot geom touches an obstacle or
        another robot geom (self-collision) and the hand is at least 3 cm above the table."""
        data = self._scratch
        data.qpos[:] = 0.0
        data.qpos[self.arm_qpos_adr] = q
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_collision(self.model, data)
        if data.site_xpos[self.ee_site][2] < 0.03:
            return False
        geoms = data.contact.geom[: data.ncon]  # (ncon, 2)
        return not np.any(self._robot_mask[geoms])

    def _behind_wall(self, pos: np.ndarray) -> bool:
        """The position is past the wall (x), within its width (y) and below its top (z)."""
        c, h = self.wall_center, self.wall_half
        return bool(pos[0] > c[0] + h[0] + 0.03 and abs(pos[1]) < h[1] - 0.02 and pos[2] < c[2] + h[2] - 0.02)

    def _in_front(self, pos: np.ndarray) -> bool:
        """Not behind or above-and-near the wall: the straight approach from HOME does not cross it."""
        c, h = self.wall_center, self.wall_half
        return bool(pos[0] < c[0] - h[0] - 0.05 or abs(pos[1]) > h[1] + 0.05)

    def sample_target(self, family: int, rng: np.random.Generator, tries: int = 20_000) -> tuple[np.ndarray, ...]:
        """A reachable target of ``family``: (position (3,), quaternion (4,), configuration (7,)) from the FK of a
        sampled collision-free configuration. Raises ConfigError if none is found in ``tries`` draws."""
        low, high = self.arm_range[:, 0], self.arm_range[:, 1]
        for _ in range(tries):
            if family == 2:
                # Over the wall: shoulder forward, elbow opened, wrist pointing down behind the wall.
                q = HOME + rng.uniform(-1, 1, 7) * np.array([0.5, 0.3, 0.5, 0.5, 0.5, 0.5, 1.2])
                q[1] += rng.uniform(0.6, 1.2)
                q[3] += rng.uniform(0.3, 1.0)
                q[5] += rng.uniform(0.2, 1.0)
            else:
                q = HOME + rng.uniform(-1, 1, 7) * TARGET_SPREAD
            if family == 1:
                joint = rng.choice(LIMIT_JOINTS)
                margin = rng.uniform(*self.limit_margin)
                q[joint] = low[joint] + margin if rng.random() < 0.5 else high[joint] - margin
            q = np.clip(q, low + 0.01, high - 0.01)
            if not self._clear(q):
                continue
            pos = self._scratch.site_xpos[self.ee_site].copy()
            if not (WORKSPACE[0] <= pos[0] and pos[2] <= WORKSPACE[1]):
                continue
            if (family == 2) != self._behind_wall(pos) or (family != 2 and not self._in_front(pos)):
                continue
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, self._scratch.site_xmat[self.ee_site])
            return pos, quat, q
        raise ConfigError(f"no target of family {FAMILIES[family]!r} found in {tries} draws")

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """``options``: ``family`` (name or index) forces a target family; ``target`` ((3,) position, (4,)
        quaternion) forces a target pose."""
        super().reset(seed=seed)
        options = dict(options or {})
        rng = self.np_random
        mujoco.mj_resetData(self.model, self.data)
        q0 = np.clip(HOME + rng.uniform(-1, 1, 7) * self.start_noise, self.arm_range[:, 0], self.arm_range[:, 1])
        self.data.qpos[self.arm_qpos_adr] = q0
        self.q_cmd = q0.copy()
        self.data.ctrl[:7] = q0
        self.data.ctrl[7:] = 0.0
        family = options.get("family")
        if family is None:
            self.family = int(rng.choice(3, p=self.family_probs))
        elif isinstance(family, str):
            if family not in FAMILIES:
                raise UnknownNameError("target family", family, FAMILIES)
            self.family = FAMILIES.index(family)
        elif int(family) in range(len(FAMILIES)):
            self.family = int(family)
        else:
            raise ConfigError(f"target family index must be 0, 1 or 2 ({', '.join(FAMILIES)}), got {family}")
        if "target" in options:
            pos, quat = (np.asarray(x, dtype=np.float64) for x in options["target"])
            if pos.shape != (3,) or quat.shape != (4,) or not np.all(np.isfinite(pos)) or not np.any(quat):
                raise ShapeError(f"options['target'] must be a finite position (3,) and quaternion (4,), got "
                                 f"{pos.shape}, {quat.shape}")  # fmt: skip
            self.target_pos, self.target_quat = pos, quat / np.linalg.norm(quat)
        else:
            self.target_pos, self.target_quat, _ = self.sample_target(self.family, rng)
        self.data.mocap_pos[self.target_mocap] = self.target_pos
        self.data.mocap_quat[self.target_mocap] = self.target_quat
        mujoco.mj_forward(self.model, self.data)
        self._t = 0
        return self._observation(), {"family": self.family}

    def step(self, action: np.ndarray):
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (7,):
            raise ShapeError(f"panda_reach takes 7 joint velocities, got an action of shape {action.shape}")
        fault = not np.all(np.isfinite(action))
        if fault:  # hold still rather than poison the servo targets with NaN
            log.warning("panda_reach got a non-finite action %s; holding the arm still", action)
            action = np.zeros(7)
        vmax = float(self.action_space.high[0])
        action = np.clip(action, -vmax, vmax)
        self.q_cmd = np.clip(self.q_cmd + action * self.dt, self.arm_range[:, 0], self.arm_range[:, 1])
        self.data.ctrl[:7] = self.q_cmd
        collision = False
        for _ in range(self.substeps):
            mujoco.mj_step(self.model, self.data)
            collision = collision or self.in_collision()
        self._t += 1
        distance = float(np.linalg.norm(self.data.site_xpos[self.ee_site] - self.target_pos))
        success = distance < self.success_radius
        reward = -distance + self.success_bonus * success - self.collision_penalty * collision
        info = {
            "distance": distance,
            "orientation_error": self.orientation_error(),
            "success": success,
            "collision": collision,
            "family": self.family,
            "action_fault": fault,
        }
        return self._observation(), float(reward), False, self._t >= self.max_steps, info

    def render(self) -> np.ndarray:
        """An RGB frame (480, 640, 3) uint8 from the side camera."""
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, 480, 640)
        self._renderer.update_scene(self.data, camera="side")
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


@register("panda_reach")
def panda_reach(**kwargs: Any) -> PandaReachEnv:
    """Reach end-effector pose targets with a Franka Panda; 150 steps of 0.02 s; see :mod:`envs.panda_reach`."""
    return PandaReachEnv(**kwargs)


@dataclass(frozen=True)
class HandoverRule:
    """The hand-written reference over panda_reach's skills (:mod:`hrtc.references`): over the wall with ``avoid``
    until the hand is within ``radius`` (m, horizontally) above a target behind it, then ``reach``."""

    radius: float = 0.03

    def __call__(self, state: Mapping[str, np.ndarray]) -> Mapping[str, float]:
        above = np.linalg.norm(state["ee_pos"][:2] - state["target_pos"][:2]) < self.radius
        return {"avoid": 1.0} if state["target_behind_wall"][0] > 0.5 and not above else {"reach": 1.0}
