"""The lunarlander task: gymnasium's LunarLander-v3 (continuous) unchanged, plus the named state skills read."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs
from envs.lunarlander import STATE_KEYS
from hrtc.errors import ConfigError, ShapeError


def random_actions(seed: int, n: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, 2)).astype(np.float32)


def test_registered_and_conforms_to_gymnasium() -> None:
    assert "lunarlander" in envs.names()
    env = envs.make("lunarlander")
    check_env(env, skip_render_check=True)
    assert env.action_space.shape == (2,) and env.observation_space.shape == (8,)
    assert env.observation_space.dtype == np.float32 and env.action_space.dtype == np.float32


def test_same_episodes_as_gymnasiums_own_lunarlander() -> None:
    """Same seed and actions: identical observations, rewards and ends as ``gym.make("LunarLander-v3",
    continuous=True)`` (ours adds methods, never changes the dynamics)."""
    ours, theirs = envs.make("lunarlander"), gym.make("LunarLander-v3", continuous=True)
    for seed in (0, 1):
        a, _ = ours.reset(seed=seed)
        b, _ = theirs.reset(seed=seed)
        np.testing.assert_array_equal(a, b)
        for action in random_actions(seed, 300):
            sa, sb = ours.step(action), theirs.step(action)
            np.testing.assert_array_equal(sa[0], sb[0])
            assert sa[1:4] == sb[1:4]
            if sa[2] or sa[3]:
                break


def test_skill_state_names_the_observation() -> None:
    env = envs.make("lunarlander")
    obs, _ = env.reset(seed=3)
    for action in random_actions(3, 200):
        state = env.unwrapped.skill_state()
        assert tuple(state) == STATE_KEYS
        assert all(v.shape == (1,) and v.dtype == np.float64 for v in state.values())
        named = np.concatenate([state[k] for k in STATE_KEYS])
        np.testing.assert_allclose(named, obs, rtol=1e-6, atol=1e-6)  # the observation is its float32 rounding
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break


def test_units_of_the_named_state() -> None:
    """Free fall over 0.5 s: vy falls by g t in its units (1 vy unit = 7.5 world units/s, g = 10 world units/s^2)
    and y integrates it (1 vy unit moves y by 1.125 per second: 7.5 world units over a half height of 6.67)."""
    env = envs.make("lunarlander")
    env.reset(seed=0)
    env.unwrapped.set_state(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    ys, vys = [], []
    for _ in range(25):
        obs = env.step(np.array([-1.0, 0.0], np.float32))[0]
        ys.append(obs[1])
        vys.append(obs[3])
    assert vys[-1] == pytest.approx(-10.0 * 0.5 / 7.5, rel=0.02)
    assert ys[-1] - ys[0] == pytest.approx(1.125 * 0.02 * sum(vys[1:]), rel=0.05)


def test_set_state_places_the_lander_and_keeps_its_legs_attached() -> None:
    env = envs.make("lunarlander")
    env.reset(seed=0)
    obs = env.unwrapped.set_state(0.3, 0.8, 0.1, -0.1, 0.5, 0.2)
    np.testing.assert_allclose(obs[:6], [0.3, 0.8, 0.1, -0.1, 0.5, 0.2], atol=1e-6)
    # One frame later the state has moved by about one frame of its own velocities: the legs were carried rigidly
    # (a leg left behind would yank the body through its joint).
    nxt, reward, *_ = env.step(np.array([-1.0, 0.0], np.float32))
    assert nxt[0] == pytest.approx(0.3 + 0.5 * 0.1 * 0.02, abs=1e-4)  # 1 vx unit moves x by 0.5 a second
    assert nxt[4] == pytest.approx(0.5 + 2.5 * 0.2 * 0.02, abs=1e-3)  # 1 angular-velocity unit is 2.5 rad/s
    assert reward == 0.0  # no shaping jump for the teleport, no fuel spent
    lander = env.unwrapped.lander
    for leg in env.unwrapped.legs:
        assert np.hypot(*(np.array(leg.position) - np.array(lander.position))) < 1.0


def test_set_state_refuses_non_finite_values_and_use_before_reset() -> None:
    env = envs.make("lunarlander")
    with pytest.raises(RuntimeError):
        env.unwrapped.skill_state()
    env.reset(seed=0)
    with pytest.raises(ShapeError):
        env.unwrapped.set_state(np.nan, 1.0)


def test_deterministic_under_a_seed_and_random_start() -> None:
    def rollout(seed: int) -> np.ndarray:
        env = envs.make("lunarlander")
        trace = [env.reset(seed=seed)[0]]
        trace += [env.step(a)[0] for a in random_actions(0, 40)]
        return np.stack(trace)

    np.testing.assert_array_equal(rollout(5), rollout(5))
    assert not np.array_equal(rollout(5)[0], rollout(6)[0])


def test_time_limit_is_truncation() -> None:
    env = envs.make("lunarlander", time_limit=0.1)  # 5 steps of 0.02 s
    env.reset(seed=0)
    flags = [env.step(np.array([0.3, 0.0], np.float32))[2:4] for _ in range(5)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])
    assert envs.make("lunarlander")._max_episode_steps == 1000


def test_discrete_variant_is_refused() -> None:
    with pytest.raises(ConfigError, match="continuous"):
        envs.make("lunarlander", continuous=False)


def test_train_py_runs_hrtc_on_lunarlander_with_the_task_defaults(tmp_path) -> None:
    """The user's command, 2,000 env steps long: the task's settings (its learner, SAC with critics 512 x 512 and two
    gradient steps per decision, the 10 s horizon, the weight span, the start search, 3-decision targets and the mirror
    augmentation; a decision every 5 env
    steps) and its six skills reach the trainer."""
    import subprocess
    import sys
    from pathlib import Path

    import pandas as pd
    import yaml

    from hrtc.checkpoint import load_checkpoint

    root = Path(__file__).resolve().parents[2]
    run_dir = tmp_path / "run"
    args = ["task=lunarlander", "steps=2000", "eval_every=1000", "eval_episodes=1", "progress=false",
            f"hydra.run.dir={run_dir}"]  # fmt: skip
    result = subprocess.run([sys.executable, str(root / "scripts" / "train.py"), *args], capture_output=True,
                            text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    rows = pd.read_csv(run_dir / "train.csv")  # SAC's: one row per 250 decisions (1,250 env steps with 2 envs)
    assert len(rows) == 1 and "losses/q_loss" in rows.columns  # (no update yet: learning starts at 500 decisions)
    sac = yaml.safe_load((run_dir / "config.yaml").read_text())["sac"]
    assert sac["q_hidden"] == [512, 512] and sac["updates_per_decision"] == 2 and sac["gamma"] == 0.998
    assert sac["start_search"] == 16 and sac["start_search_forget"] is True
    assert sac["n_step"] == 3 and sac["mirror_fraction"] == 0.5 and sac["mirror_index"] == [0, 1, 2, 3, 4, 5, 7, 6]
    checkpoint = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    search = checkpoint["optimizer"]["start_search"]  # 2,000 env steps: the search's 30 episodes are still playing
    assert len(search["candidates"]) == 16 and search["winner"] is None and sum(map(len, search["returns"])) >= 1
    meta = checkpoint["meta"]
    assert meta["algo"] == "hrtc" and meta["dist"] == "beta" and meta["decision_every"] == 5
    assert meta["weight_margin"] == 0.25
    assert meta["learner"] == "sac"
    assert meta["skills"] == ["attitude", "centring", "descent", "hover", "touchdown", "idle"]


def _declared_mirror() -> tuple[list[int], np.ndarray]:
    """The left-right mirror that ``conf/task/lunarlander.yaml`` declares for ``sac.mirror_fraction``."""
    from importlib import resources

    import yaml

    sac = yaml.safe_load((resources.files("hrtc.conf") / "task" / "lunarlander.yaml").read_text())["sac"]
    return list(sac["mirror_index"]), np.asarray(sac["mirror_sign"], float)


class _NoDispersion:
    """Stands in for the env's generator after reset: gymnasium's engine impulses then land without their random
    offset (a draw the mirrored run would need negated), so the physics alone is compared."""

    def uniform(self, low: float = 0.0, high: float = 1.0, size: Any = None) -> Any:
        return np.zeros(size) if size is not None else 0.0


def test_the_declared_mirror_is_a_symmetry_of_the_lander_and_of_every_skill() -> None:
    """The map mirror augmentation relies on (``sac.mirror_index``, ``sac.mirror_sign``): (1) gymnasium's lander,
    started at a state and at its mirror image and driven by random actions and their mirror images (lateral
    negated), stays each other's mirror image while airborne; (2) dropped tilted onto the pad, its legs touch in
    each other's order; (3) every skill of the task's library proposes, for a
    state's mirror image, the mirror image of its proposal, so the same weights blend the mirrored action."""
    from hrtc.cli import task_config
    from hrtc.composition import build_library

    index, sign = _declared_mirror()
    assert sorted(index) == list(range(8)) and len(sign) == 8
    flip = np.array([1.0, -1.0], np.float32)  # the action's mirror image: the main engine kept, the lateral negated
    start = np.array([0.3, 0.8, 0.4, -0.2, 0.1, 0.2, 0.0, 0.0])
    actions = random_actions(0, 40)
    runs = []
    for mirrored in (False, True):
        env = envs.make("lunarlander")
        env.reset(seed=3)
        state = start[index] * sign if mirrored else start
        env.unwrapped.set_state(*state[:6])
        env.unwrapped._np_random = _NoDispersion()
        runs.append(np.array([env.step(a * flip if mirrored else a)[0] for a in actions]))
    plain, mirror = runs
    assert np.abs(plain[:, 2]).max() > 0.05 and np.abs(plain[:, 4]).max() > 0.1  # the lander moved and turned
    np.testing.assert_allclose(plain[:, index] * sign, mirror, atol=1e-4)
    touchdowns = []  # (2) dropped tilted onto the flat pad, engines off: one leg touches first, the other's mirror
    for mirrored in (False, True):
        env = envs.make("lunarlander")
        env.reset(seed=3)
        drop = np.array([0.05, 0.15, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
        env.unwrapped.set_state(*(drop[index] * sign if mirrored else drop)[:6])
        touchdowns.append(np.array([env.step(np.array([-1.0, 0.0], np.float32))[0] for _ in range(30)]))
    legs = touchdowns[0][:, 6:]
    assert (legs.sum(1) == 1).any() and (legs.sum(1) == 2).any()  # one leg first, then both
    np.testing.assert_allclose(touchdowns[0][:, index] * sign, touchdowns[1], atol=1e-3)
    library = build_library(task_config("lunarlander")["skills"])
    rng = np.random.default_rng(1)
    for _ in range(200):
        obs = rng.uniform(-1, 1, 8) * np.array([1, 1.5, 1, 1, 0.6, 1, 0, 0])
        obs[6:] = rng.integers(0, 2, 2)
        named = {key: np.array([v]) for key, v in zip(STATE_KEYS, obs, strict=True)}
        named_mirror = {key: np.array([v]) for key, v in zip(STATE_KEYS, obs[index] * sign, strict=True)}
        proposals, _ = library.propose(named, 0, 2)
        proposals_mirror, _ = library.propose(named_mirror, 0, 2)
        np.testing.assert_allclose(proposals_mirror, proposals * flip, atol=1e-12)
