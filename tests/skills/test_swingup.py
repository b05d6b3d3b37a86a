"""EnergySwingUp on the real dm_control cart-pole: it pumps the energy to the upright level but does not balance."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import envs
from hrtc.errors import ConfigError, ShapeError
from hrtc.skill import Skill
from skills.cartpole_model import CartpoleParams
from skills.swingup import STATUS_NONFINITE_STATE, EnergySwingUp
from tests.skills.conftest import filtered_state, set_cartpole_state

DT = 0.01  # s per env step
STEPS = 1000  # one episode
RAIL = 1.8  # m
UPRIGHT_BAND = 0.2  # rad
REACH_BUDGET = 6.0  # s, time allowed to bring the energy to the upright level


@pytest.fixture(scope="module")
def skill() -> EnergySwingUp:
    return EnergySwingUp()


@pytest.fixture(scope="module")
def params() -> CartpoleParams:
    return CartpoleParams.from_mj_model(envs.mj_model("cartpole_swingup"))


def swing_energy(p: CartpoleParams) -> float:
    """2 m g l, J: the energy between hanging and upright at rest."""
    return 2.0 * p.pole_mass * p.gravity * p.com_length


def rollout(env: Any, skill: EnergySwingUp, seed: int, perturbed: bool) -> dict[str, np.ndarray]:
    """One episode from the task's own hanging start (or one perturbed further); the skill alone drives the cart."""
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    if perturbed:  # cart off centre, pole up to 0.5 rad from hanging, moving
        qpos = (rng.uniform(-0.5, 0.5), np.pi + rng.uniform(-0.5, 0.5))
        set_cartpole_state(env, qpos, (rng.uniform(-0.5, 0.5), rng.uniform(-1.0, 1.0)))
    skill.reset(rng)
    energy, angle, cart, action = (np.empty(STEPS) for _ in range(4))
    for t in range(STEPS):
        out = skill.act(filtered_state(env, skill.state_keys))
        env.step(out.action)
        s = env.unwrapped.skill_state()
        energy[t], action[t] = out.info["energy"], out.action[0]
        angle[t], cart[t] = s["pole_angle"][0], s["cart_position"][0]
    return {"energy": energy, "angle": angle, "cart": cart, "action": action}


def longest_run(mask: np.ndarray) -> int:
    best = run = 0
    for m in mask:
        run = run + 1 if m else 0
        best = max(best, run)
    return best


def test_is_a_skill(skill: EnergySwingUp) -> None:
    assert isinstance(skill, Skill)
    assert skill.state_keys == ("pole_angle", "pole_angular_velocity", "cart_position", "cart_velocity")


@pytest.mark.parametrize("perturbed", [False, True], ids=["task_start", "perturbed_start"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pumps_energy_to_upright_level_but_does_not_balance(
    cartpole: Any, skill: EnergySwingUp, params: CartpoleParams, seed: int, perturbed: bool
) -> None:
    r = rollout(cartpole, skill, seed, perturbed)
    tolerance = 0.05 * swing_energy(params)  # J
    assert r["energy"][0] < -0.5 * swing_energy(params), "the episode should start near hanging"
    reached = np.flatnonzero(np.abs(r["energy"] - skill.energy_target) < tolerance)
    assert reached.size, f"energy never came within {tolerance:.3f} J of the upright level"
    reach_s = (reached[0] + 1) * DT
    assert reach_s < REACH_BUDGET
    # ... and it stays there: the last 3 s all within the tolerance.
    assert np.all(np.abs(r["energy"][-300:] - skill.energy_target) < tolerance)
    assert np.max(np.abs(r["cart"])) < RAIL
    assert np.all(np.abs(r["action"]) <= 1.0)
    # Partial: the pole passes by upright (or turns back short of it) but is never held there.
    near_upright = np.abs(r["angle"]) < UPRIGHT_BAND
    upright_fraction = near_upright.mean()
    assert upright_fraction < 0.2
    assert longest_run(near_upright) * DT < 1.0
    print(
        f"\nswing-up seed {seed}{' perturbed' if perturbed else ''}: "
        f"|E - E*| < {tolerance:.3f} J after {reach_s:.2f} s; "
        f"max |x| {np.max(np.abs(r['cart'])):.2f} m; within {UPRIGHT_BAND} rad of upright "
        f"{100 * upright_fraction:.1f}% of the episode, longest {longest_run(near_upright) * DT:.2f} s"
    )


def test_each_action_raises_energy_more_than_its_opposite(
    cartpole: Any, skill: EnergySwingUp, params: CartpoleParams
) -> None:
    """The pumping sign, checked on the simulator: the skill's push beats the opposite push over a few steps."""
    cartpole.reset(seed=0)  # dm_control resets (to hanging) on the first step after construction otherwise
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(40):
        theta = rng.uniform(-np.pi, np.pi)
        theta_dot = rng.uniform(-3.0, 3.0)
        if params.energy(theta, theta_dot) > -0.2 * swing_energy(params) or abs(theta_dot * np.cos(theta)) < 0.5:
            continue
        set_cartpole_state(cartpole, (0.0, theta), (0.0, theta_dot))
        u = skill.act(filtered_state(cartpole, skill.state_keys)).action
        assert abs(u[0]) > 0.1
        energies = []
        for action in (u, -u):
            set_cartpole_state(cartpole, (0.0, theta), (0.0, theta_dot))
            for _ in range(3):
                cartpole.step(action)
            s = cartpole.unwrapped.skill_state()
            energies.append(params.energy(s["pole_angle"][0], s["pole_angular_velocity"][0]))
        assert energies[0] > energies[1]
        checked += 1
    assert checked >= 10


def test_output_is_small_near_upright_with_the_right_energy(skill: EnergySwingUp, params: CartpoleParams) -> None:
    np.testing.assert_array_equal(skill.act(np.zeros(4)).action, [0.0])
    for theta in np.linspace(-0.3, 0.3, 7):
        # the angular velocity that puts the energy exactly at the upright level
        theta_dot = np.sqrt(2.0 * params.pole_mass * params.gravity * params.com_length * (1 - np.cos(theta)))
        theta_dot /= np.sqrt(params.hinge_inertia)
        for sign in (-1.0, 1.0):
            out = skill.act(np.array([theta, sign * theta_dot, 0.05, -0.05]))
            assert abs(out.info["energy"]) < 1e-12
            assert abs(out.action[0]) < 0.05


def test_output_within_control_range(skill: EnergySwingUp) -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        state = rng.uniform([-np.pi, -15.0, -3.0, -10.0], [np.pi, 15.0, 3.0, 10.0])
        out = skill.act(state)
        assert out.action.shape == (1,) and out.action.dtype == np.float64
        assert -1.0 <= out.action[0] <= 1.0


def test_non_finite_state_gives_a_finite_action(skill: EnergySwingUp) -> None:
    out = skill.act(np.array([np.nan, 0.0, 0.0, 0.0]))
    assert np.all(np.isfinite(out.action))
    assert out.info["status"] == STATUS_NONFINITE_STATE


def test_rejects_a_wrongly_shaped_state(skill: EnergySwingUp) -> None:
    with pytest.raises(ShapeError):
        skill.act(np.zeros(3))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"gain": 0.0},
        {"gain": np.nan},
        {"max_pump": 1.5},
        {"max_pump": -0.1},
        {"velocity_scale": 0.0},
        {"centring_gain": -1.0},
        {"centring_damping": np.inf},
        {"energy_target": 5.0},
        {"energy_target": -1.0},
    ],
)
def test_rejects_bad_arguments(kwargs: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        EnergySwingUp(**kwargs)
