"""StaticIntent: the same action whatever the state, and only sane actions accepted."""

from __future__ import annotations

import numpy as np
import pytest

from hrtc.errors import ConfigError
from hrtc.skill import Skill
from skills.static import StaticIntent


def test_is_a_skill_that_reads_nothing() -> None:
    skill = StaticIntent([0.0])
    assert isinstance(skill, Skill)
    assert skill.state_keys == ()


@pytest.mark.parametrize("action", [[0.0], [1.0, -0.5, 0.25], [0.0, 0.0, 0.8, 0.0, 0.0]])
def test_returns_exactly_its_action_for_any_state(action: list[float]) -> None:
    skill = StaticIntent(action)
    skill.reset(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for state in (np.empty(0), rng.normal(size=4), np.full(3, np.nan)):
        out = skill.act(state)
        assert out.action.dtype == np.float64
        assert out.action.shape == (len(action),)
        np.testing.assert_array_equal(out.action, np.asarray(action))
        assert out.info["status"] == 0.0


def test_caller_cannot_change_the_intent() -> None:
    source = [0.3]
    skill = StaticIntent(source)
    first = skill.act(np.empty(0)).action
    first[0] = 99.0
    source[0] = -7.0
    np.testing.assert_array_equal(skill.act(np.empty(0)).action, [0.3])


@pytest.mark.parametrize("action", [[], [[0.0, 1.0]], 0.5, [np.nan], [0.0, np.inf]])
def test_rejects_non_1d_or_non_finite_actions(action: object) -> None:
    with pytest.raises(ConfigError):
        StaticIntent(action)  # type: ignore[arg-type]
    with pytest.raises(ValueError):  # ConfigError is a ValueError
        StaticIntent(action)  # type: ignore[arg-type]
