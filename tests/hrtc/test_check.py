"""check_skill: every shipped skill passes it, and each kind of broken skill is caught with a message saying why."""

import gymnasium as gym
import numpy as np
import pytest

from hrtc.check import SkillCheckError, check_skill, check_task_skills, task_states
from hrtc.cli import task_config
from hrtc.skill import SkillOutput

SPACE = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)


@pytest.fixture(scope="module")
def states():
    return task_states("cartpole_swingup", n=60, seed=3)


class Proportional:
    """A well-behaved skill: u = clip(-k x)."""

    state_keys = ("cart_position",)

    def reset(self, rng):
        pass

    def act(self, state):
        return SkillOutput(np.clip(-0.5 * state, -1, 1), {"gain": 0.5})


class WrongShape(Proportional):
    def act(self, state):
        return SkillOutput(np.zeros(2), {})


class NonFinite(Proportional):
    def act(self, state):
        return SkillOutput(np.array([np.nan]), {})


class OutOfBounds(Proportional):
    def act(self, state):
        return SkillOutput(np.array([3.0]), {})


class NonFiniteInfo(Proportional):
    def act(self, state):
        return SkillOutput(np.zeros(1), {"cost": float("inf")})


class IgnoresItsRng(Proportional):
    """Draws from a generator of its own instead of the injected one: two seeded passes differ."""

    def __init__(self):
        self.noise = np.random.default_rng()

    def act(self, state):
        return SkillOutput(np.clip(self.noise.normal(size=1), -1, 1), {})


class ForgetsNothing(Proportional):
    """An integrator that reset does not clear."""

    def __init__(self):
        self.total = 0.0

    def act(self, state):
        self.total += float(state[0])
        return SkillOutput(np.clip([self.total], -1, 1), {})


class UnknownKey(Proportional):
    state_keys = ("cart_acceleration",)


def test_a_good_skill_passes_with_statistics(states):
    stats = check_skill(Proportional(), states, SPACE)
    assert stats["steps"] == 60 and -1 <= stats["min"] <= stats["max"] <= 1


@pytest.mark.parametrize(
    "skill,match",
    [
        (WrongShape(), r"action shape \(2,\), the task's is \(1,\)"),
        (NonFinite(), "non-finite action"),
        (OutOfBounds(), "outside the bounds"),
        (NonFiniteInfo(), "non-finite diagnostics"),
        (IgnoresItsRng(), "not deterministic under seed"),
        (ForgetsNothing(), "reset does not forget the past"),
        (UnknownKey(), r"state_keys \['cart_acceleration'\] are not in the task's state"),
    ],
)
def test_broken_skills_are_caught(states, skill, match):
    with pytest.raises(SkillCheckError, match=match):
        check_skill(skill, states, SPACE)


@pytest.mark.parametrize("task", ["cartpole_swingup"])
def test_every_skill_of_the_task_passes(task):
    results = check_task_skills(task_config(task), n=150, seed=1)
    assert set(results) == set(task_config(task)["skills"])
