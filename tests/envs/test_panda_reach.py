"""panda_reach: the Panda scene loads offline, conforms to gymnasium, samples reachable targets of each family,
tracks joint-velocity commands, detects collisions with the wall and rewards reaching."""

from __future__ import annotations

from collections.abc import Iterator

import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from envs.panda_reach import FAMILIES, HOME, PandaReachEnv
from hrtc.errors import ConfigError, ShapeError, UnknownNameError
from skills.ik import IKReach


@pytest.fixture
def env() -> Iterator[PandaReachEnv]:
    task = envs.make("panda_reach")
    yield task.unwrapped
    task.close()


def test_registered_and_conforms_to_gymnasium(env: PandaReachEnv) -> None:
    assert "panda_reach" in envs.names()
    check_env(env, skip_render_check=True)
    assert env.action_space.shape == (7,) and env.action_space.dtype == np.float32
    assert env.observation_space.dtype == np.float32
    assert env.model.nq == 9 and env.model.nu == 9  # 7 arm joints and 2 fingers, from gymnasium-robotics' MJCF


def test_same_seed_same_episode_different_seed_different_target(env: PandaReachEnv) -> None:
    def rollout(seed: int) -> np.ndarray:
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for t in range(20):
            trace.append(env.step(np.full(7, 0.3 * np.sin(t / 4), np.float32))[0])
        return np.stack(trace)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3)[0], rollout(4)[0])


@pytest.mark.parametrize("family", FAMILIES)
def test_targets_are_reachable_collision_free_poses_of_their_family(env: PandaReachEnv, family: str) -> None:
    rng = np.random.default_rng(0)
    low, high = env.arm_range[:, 0], env.arm_range[:, 1]
    for _ in range(10):
        pos, quat, q = env.sample_target(FAMILIES.index(family), rng)
        data = mujoco.MjData(env.model)
        data.qpos[env.arm_qpos_adr] = q
        mujoco.mj_forward(env.model, data)
        np.testing.assert_allclose(data.site_xpos[env.ee_site], pos, atol=1e-12)  # the FK of q: reachable
        assert np.all(q > low) and np.all(q < high)
        assert not any(c.geom1 in env.robot_geoms or c.geom2 in env.robot_geoms for c in data.contact[: data.ncon])
        assert np.linalg.norm(quat) == pytest.approx(1.0)
        assert env._behind_wall(pos) == (family == "behind")
        margins = np.minimum(q - low, high - q)
        if family == "limit":
            assert margins.min() <= env.limit_margin[1] + 1e-9


def test_reset_starts_near_home_at_rest_with_the_target_marked(env: PandaReachEnv) -> None:
    for seed in range(5):
        env.reset(seed=seed)
        state = env.skill_state()
        assert np.max(np.abs(state["arm_qpos"] - HOME)) <= env.start_noise + 1e-12
        assert not np.any(state["arm_qvel"])
        np.testing.assert_array_equal(env.data.mocap_pos[env.target_mocap], state["target_pos"])


def test_zero_action_holds_the_arm_still(env: PandaReachEnv) -> None:
    """Gravity is compensated: 1 s of zero velocity moves the hand less than 2 mm."""
    env.reset(seed=0)
    start = env.skill_state()["ee_pos"]
    for _ in range(50):
        env.step(np.zeros(7, np.float32))
    assert np.linalg.norm(env.skill_state()["ee_pos"] - start) < 2e-3


def test_joint_velocity_commands_are_tracked(env: PandaReachEnv) -> None:
    """1 s at 0.5 rad/s on joint 1 turns it by about 0.5 rad; the others stay."""
    env.reset(seed=0)
    q0 = env.skill_state()["arm_qpos"]
    action = np.zeros(7, np.float32)
    action[0] = 0.5
    for _ in range(50):
        env.step(action)
    moved = env.skill_state()["arm_qpos"] - q0
    assert moved[0] == pytest.approx(0.5, abs=0.05)
    assert np.max(np.abs(moved[1:])) < 0.03


def test_commands_never_leave_the_joint_ranges(env: PandaReachEnv) -> None:
    env.reset(seed=0)
    for _ in range(100):
        env.step(env.action_space.high)
    assert np.all(env.q_cmd <= env.arm_range[:, 1]) and np.all(env.q_cmd >= env.arm_range[:, 0])
    # The simulated joints may overshoot by what the soft joint-limit constraint lets through at 1.5 rad/s.
    assert np.all(env.skill_state()["arm_qpos"] <= env.arm_range[:, 1] + 0.05)


def test_reaching_a_target_is_a_success_with_its_bonus(env: PandaReachEnv) -> None:
    env.reset(seed=0)
    pos, quat = env.ee_pose()
    env.reset(seed=0, options={"target": (pos + [0.0, 0.0, 0.004], quat)})
    _, reward, terminated, truncated, info = env.step(np.zeros(7, np.float32))
    assert info["success"] and not info["collision"] and not terminated and not truncated
    assert reward == pytest.approx(1.0 - info["distance"])
    env.reset(seed=0, options={"target": (pos + [0.0, 0.0, 0.05], quat)})
    _, reward, *_, info = env.step(np.zeros(7, np.float32))
    assert not info["success"] and reward == pytest.approx(-info["distance"])


def test_reaching_straight_for_a_target_behind_the_wall_collides_and_is_penalised(env: PandaReachEnv) -> None:
    """The IK reach alone heads straight for targets behind the wall and runs into it."""
    reach = IKReach(env.model)
    collided = 0
    for seed in range(3):
        env.reset(seed=seed, options={"family": "behind"})
        hit = False
        for _ in range(60):
            state = env.skill_state()
            action = reach.act(np.concatenate([state["arm_qpos"], state["target_pos"], state["target_quat"]])).action
            _, reward, *_, info = env.step(action.astype(np.float32))
            if info["collision"]:
                hit = True
                assert reward == pytest.approx(-info["distance"] + info["success"] - 1.0)
        collided += hit
    assert collided >= 2


def test_episode_is_a_fixed_time_ended_by_truncation() -> None:
    env = envs.make("panda_reach", time_limit=0.2)  # 10 steps of 0.02 s
    env.reset(seed=0)
    flags = [env.step(np.zeros(7, np.float32))[2:4] for _ in range(10)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])


def test_bad_input_is_refused_or_made_safe(env: PandaReachEnv) -> None:
    env.reset(seed=0)
    with pytest.raises(ShapeError):
        env.step(np.zeros(3, np.float32))
    before = env.q_cmd.copy()
    *_, info = env.step(np.full(7, np.nan, np.float32))
    assert info["action_fault"]
    np.testing.assert_array_equal(env.q_cmd, before)  # NaN held as zero velocity
    with pytest.raises(UnknownNameError, match="valid target familys: behind, free, limit"):
        env.reset(seed=0, options={"family": "floor"})
    with pytest.raises(ConfigError):
        envs.make("panda_reach", control_dt=0.003)
    with pytest.raises(ConfigError):
        envs.make("panda_reach", family_probs=(1.0, -1.0, 0.0))
