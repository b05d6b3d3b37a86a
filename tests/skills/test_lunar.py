"""The LunarLander heuristic skills on the real Box2D task: each does its one job, none lands alone, together they do.

Units are those of gymnasium's observation (``envs.lunarlander``): angle rad, angular velocity 2.5 rad/s, x and y in
half viewport widths and heights, vx 5 and vy 7.5 world units/s; one env step is 0.02 s.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import pytest

import envs
from hrtc.check import check_skill, check_task_skills, task_states
from hrtc.cli import task_config
from hrtc.composition import build_library
from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import Skill
from skills.lunar import STATUS_NONFINITE_STATE, AttitudeHold, DescentRate, LateralCentring, Touchdown
from tests.skills.conftest import filtered_state

DT = 0.02  # s per env step


@pytest.fixture
def lander() -> Iterator[Any]:
    env = envs.make("lunarlander")
    yield env
    env.close()


def fly(env: Any, skills: Sequence[Skill], steps: int, until_contact: bool = True) -> dict[str, np.ndarray]:
    """Step ``env`` with the sum of ``skills``' actions (the action filter with weight 1 each) for up to ``steps``
    steps, stopping at the episode's end or (``until_contact``) when a leg touches. Returns the traces and the
    first skill's diagnostics."""
    trace: dict[str, list] = {"x": [], "y": [], "vy": [], "angle": [], "info": [], "reward": []}
    terminated = False
    for _ in range(steps):
        outs = [s.act(filtered_state(env, s.state_keys)) for s in skills]
        action = np.clip(np.sum([o.action for o in outs], axis=0), -1.0, 1.0)
        obs, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
        for i, key in enumerate(("x", "y", "vy", "angle")):
            trace[key].append(obs[(0, 1, 3, 4)[i]])
        trace["info"].append(outs[0].info)
        trace["reward"].append(reward)
        if terminated or truncated or (until_contact and (obs[6] or obs[7])):
            break
    out = {k: np.asarray(v) for k, v in trace.items() if k != "info"}
    out["info"] = trace["info"]  # type: ignore[assignment]
    out["terminated"] = np.asarray(terminated)
    return out


def episode(env: Any, library: Any, weights: np.ndarray, seed: int) -> tuple[float, bool]:
    """One episode of the composed task under fixed ``weights``: (return, came to rest on the ground)."""
    from hrtc.composition import ComposedEnv

    composed = ComposedEnv(env, library)
    composed.reset(seed=seed)
    total, done, reward = 0.0, False, 0.0
    terminated = False
    while not done:
        _, reward, terminated, truncated, _ = composed.step(weights)
        total += reward
        done = terminated or truncated
    return total, bool(terminated and reward > 0)  # gymnasium's +100 for coming to rest is the last reward


# --------------------------------------------------------------------------------------------------- protocol
def test_every_skill_of_the_task_passes_check_skill() -> None:
    results = check_task_skills(task_config("lunarlander"), n=300, seed=0)
    assert set(results) == {"attitude", "centring", "descent", "hover", "touchdown", "idle"}
    for summary in results.values():
        assert -1.0 <= summary["min"] <= summary["max"] <= 1.0


@pytest.mark.parametrize("skill", [AttitudeHold(), LateralCentring(), DescentRate(), Touchdown()], ids=type)
def test_check_skill_on_states_near_the_ground(skill: Skill) -> None:
    """States of a real descent under the hand blend, down to touchdown (legs in contact), not only random flight."""
    library = build_library(task_config("lunarlander")["skills"])
    slots = {s.name: s.skill for s in library.slots}
    env = envs.make("lunarlander")
    states = []
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(400):
            states.append(env.unwrapped.skill_state())
            parts = [slots[n] for n in ("centring", "descent", "touchdown")]
            action = np.clip(sum(p.act(filtered_state(env, p.state_keys)).action for p in parts), -1, 1)
            if any(env.step(action.astype(np.float32))[2:4]):
                break
    assert any(s["left_leg_contact"][0] or s["right_leg_contact"][0] for s in states)
    check_skill(skill, states, env.action_space)


# --------------------------------------------------------------------------------------------------- properties
@pytest.mark.parametrize(("angle", "rate"), [(0.5, 0.0), (-0.5, 0.0), (0.5, 0.3), (-0.5, -0.3), (0.5, -0.3)])
@pytest.mark.parametrize("seed", [0, 1])
def test_attitude_hold_brings_the_angle_within_0_05_rad_within_1_5_s(lander: Any, angle, rate, seed) -> None:
    skill = AttitudeHold()
    lander.reset(seed=seed)
    lander.unwrapped.set_state(0.0, 1.4, 0.0, 0.2, angle, rate)  # high and rising: about 1.5 s of flight
    r = fly(lander, [skill], 200)
    inside = np.flatnonzero(np.abs(r["angle"]) <= 0.05)
    assert inside.size, f"never within 0.05 rad; closest {np.abs(r['angle']).min():.3f}"
    assert (inside[0] + 1) * DT <= 1.5
    assert np.all(np.abs(r["angle"][inside[0] :]) <= 0.05), "left the band again"
    assert skill.act(np.array([angle, rate])).action[0] == 0.0, "the main engine stays off"
    # Alone it only holds the attitude: with the main engine off the lander free-falls onto the ground.
    assert np.min(r["vy"]) < -0.5


def test_attitude_hold_holds_a_tilted_target(lander: Any) -> None:
    skill = AttitudeHold(target_angle=0.2)
    lander.reset(seed=0)
    lander.unwrapped.set_state(0.0, 1.4, 0.0, 0.2, -0.2, 0.0)
    r = fly(lander, [skill], 200)
    assert np.all(np.abs(r["angle"][-20:] - 0.2) <= 0.05)


def test_attitude_hold_is_zero_when_upright_and_still() -> None:
    np.testing.assert_array_equal(AttitudeHold().act(np.zeros(2)).action, [0.0, 0.0])


@pytest.mark.parametrize(
    "skill",
    [DescentRate(), DescentRate(min_speed=0.1, altitude_gain=0.0, max_speed=0.1)],
    ids=["altitude_schedule", "constant_0.1"],
)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_descent_rate_holds_its_target_speed(lander: Any, skill: DescentRate, seed: int) -> None:
    """After a 1 s transient the vertical speed stays within 0.08 (0.6 world units/s) of the target, 0.025 on average.
    The attitude skill keeps the lander upright meanwhile (the descent law acts on the main engine only)."""
    lander.reset(seed=seed)
    r = fly(lander, [skill, AttitudeHold()], 600)
    errors = np.array([i["speed_error"] for i in r["info"]])[50:]
    assert errors.size > 50
    assert np.max(np.abs(errors)) < 0.08
    assert np.mean(np.abs(errors)) < 0.025
    targets = np.array([i["target_speed"] for i in r["info"]])
    assert np.all(targets <= -skill.min_speed + 1e-12) and np.all(targets >= -skill.max_speed - 1e-12)


def test_descent_target_slows_with_altitude() -> None:
    skill = DescentRate(min_speed=0.05, altitude_gain=0.5, max_speed=0.6)
    assert skill.target_speed(0.0) == pytest.approx(-0.05)
    assert skill.target_speed(0.5) == pytest.approx(-0.3)
    assert skill.target_speed(3.0) == pytest.approx(-0.6)
    assert skill.target_speed(-0.1) == pytest.approx(-0.05)
    # Falling faster than the target fires the engine; slower (or rising) leaves it off.
    assert skill.act(np.array([0.5, -0.5])).action[0] > 0.5
    assert skill.act(np.array([0.5, 0.0])).action[0] <= 0.0
    assert skill.act(np.array([0.5, -0.5])).action[1] == 0.0


def test_hover_holds_its_altitude(lander: Any) -> None:
    hover = DescentRate(min_speed=0.0, altitude_gain=0.0)
    lander.reset(seed=0)
    lander.unwrapped.set_state(0.0, 1.0)
    r = fly(lander, [hover, AttitudeHold()], 250)  # 5 s
    assert len(r["y"]) == 250
    assert np.all(np.abs(r["y"] - 1.0) < 0.1)


@pytest.mark.parametrize("x0", [0.5, -0.5, 0.7])
def test_centring_with_a_hover_steers_over_the_pad(lander: Any, x0: float) -> None:
    """Centring tilts the thrust of another skill (here a hover) towards the pad: |x| < 0.1 within 10 s, and it stays
    there."""
    lander.reset(seed=0)
    lander.unwrapped.set_state(x0, 1.0)
    r = fly(lander, [LateralCentring(), DescentRate(min_speed=0.0, altitude_gain=0.0)], 500)
    inside = np.flatnonzero(np.abs(r["x"]) < 0.1)
    assert inside.size and (inside[0] + 1) * DT <= 10.0
    assert np.all(np.abs(r["x"][inside[0] :]) < 0.12)


def test_centring_tilts_towards_the_pad() -> None:
    skill = LateralCentring()
    # Right of the pad (x > 0): a positive angle points the thrust to -x, so the target is positive ...
    assert skill.target_angle(0.5, 0.0) > 0 and skill.target_angle(-0.5, 0.0) < 0
    # ... and the booster command turns the lander that way (left booster, lateral < -0.5: counter-clockwise).
    assert skill.act(np.array([0.5, 0.0, 0.0, 0.0])).action[1] < -0.5
    assert skill.act(np.array([-0.5, 0.0, 0.0, 0.0])).action[1] > 0.5
    assert skill.target_angle(5.0, 5.0) == pytest.approx(skill.max_tilt)
    assert skill.act(np.array([0.5, 0.0, 0.0, 0.0])).action[0] == 0.0


def test_touchdown_cuts_the_main_engine_only_on_contact(lander: Any) -> None:
    skill = Touchdown()
    np.testing.assert_array_equal(skill.act(np.array([0.0, 0.0])).action, [0.0, 0.0])
    for contact in ([1.0, 0.0], [0.0, 1.0], [1.0, 1.0]):
        np.testing.assert_array_equal(skill.act(np.array(contact)).action, [-1.0, 0.0])
    # On the real lander: under the hand blend its proposal switches exactly when a leg touches.
    lander.reset(seed=0)
    parts = [LateralCentring(), DescentRate()]
    switched = False
    for _ in range(600):
        state = lander.unwrapped.skill_state()
        out = skill.act(filtered_state(lander, skill.state_keys))
        contact = state["left_leg_contact"][0] or state["right_leg_contact"][0]
        assert out.info["contact"] == float(contact)
        switched |= bool(contact)
        action = np.clip(sum(p.act(filtered_state(lander, p.state_keys)).action for p in parts) + out.action, -1, 1)
        if any(lander.step(action.astype(np.float32))[2:4]):
            break
    assert switched


# --------------------------------------------------------------------------------------------------- composition
def test_no_skill_lands_alone_but_the_hand_blend_does(lander: Any) -> None:
    """The point of the library: every skill alone fails to land (0 of 6 episodes come to rest with a return of
    200), while centring + descent + touchdown at weight 1 lands all of them above 200."""
    library = build_library(task_config("lunarlander")["skills"])
    names = library.names
    seeds = range(100, 106)
    for i, name in enumerate(names):
        results = [episode(lander, library, np.eye(len(names))[i], seed) for seed in seeds]
        landed = sum(rest and ret >= 200 for ret, rest in results)
        assert landed == 0, f"{name} alone landed {landed} of {len(results)} episodes"
    hand = np.array([n in ("centring", "descent", "touchdown") for n in names], dtype=np.float64)
    results = [episode(lander, library, hand, seed) for seed in seeds]
    assert all(rest and ret >= 200 for ret, rest in results), results


# --------------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("skill", [AttitudeHold(), LateralCentring(), DescentRate(), Touchdown()], ids=type)
def test_non_finite_state_gives_zero_action_and_a_status(skill: Skill) -> None:
    state = np.zeros(len(skill.state_keys))
    state[0] = np.nan
    out = skill.act(state)
    np.testing.assert_array_equal(out.action, [0.0, 0.0])
    assert out.info["status"] == STATUS_NONFINITE_STATE


@pytest.mark.parametrize("skill", [AttitudeHold(), LateralCentring(), DescentRate(), Touchdown()], ids=type)
def test_rejects_a_wrongly_shaped_state(skill: Skill) -> None:
    with pytest.raises(ShapeError, match="expected shape"):
        skill.act(np.zeros(len(skill.state_keys) + 1))


@pytest.mark.parametrize(
    ("cls", "kwargs"),
    [
        (AttitudeHold, {"angle_gain": 0.0}),
        (AttitudeHold, {"rate_gain": -1.0}),
        (AttitudeHold, {"target_angle": 2.0}),
        (LateralCentring, {"max_tilt": np.nan}),
        (LateralCentring, {"position_gain": -0.5}),
        (DescentRate, {"min_speed": -0.1}),
        (DescentRate, {"max_speed": 0.01, "min_speed": 0.05}),
        (DescentRate, {"gain": 0.0}),
        (DescentRate, {"hover_throttle": np.inf}),
    ],
)
def test_rejects_bad_arguments(cls: type, kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        cls(**kwargs)


def test_task_states_cover_the_named_state() -> None:
    states = task_states("lunarlander", n=20, seed=0)
    assert set(states[0]) == {"x", "y", "vx", "vy", "angle", "angular_velocity", "left_leg_contact",
                              "right_leg_contact"}  # fmt: skip
