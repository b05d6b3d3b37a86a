"""A skill wrapper that fails on purpose: chaos testing of fault isolation (tests, and `eval_skill` drills).

    faulty:
      skill:
        _target_: skills.faulty.FaultInjector
        skill: {_target_: skills.swingup.EnergySwingUp, model: cartpole_swingup}
        rate: 0.01
        kinds: [raise, nan, inf, shape, slow]
        slow_ms: 30
      time_budget_ms: 20

At each call, with probability ``rate`` (drawn from the generator ``reset`` injects, so runs are reproducible), the
wrapper raises, returns NaN, inf or an action of the wrong shape, or sleeps ``slow_ms`` before answering (a timeout
when the slot's ``time_budget_ms`` is below it); otherwise it returns the wrapped skill's proposal.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from hrtc.errors import ConfigError
from hrtc.skill import Skill, SkillOutput

KINDS = ("raise", "nan", "inf", "shape", "slow")


class InjectedFault(RuntimeError):
    """The failure a :class:`FaultInjector` raises."""


class FaultInjector:
    """Wraps ``skill`` (a built skill) and injects faults at ``rate`` per call, of the given ``kinds``."""

    def __init__(self, skill: Skill, rate: float = 0.01, kinds: Sequence[str] = KINDS, slow_ms: float = 30.0) -> None:
        if not 0.0 <= float(rate) <= 1.0:
            raise ConfigError(f"FaultInjector rate must be in [0, 1], got {rate}")
        unknown = set(kinds) - set(KINDS)
        if unknown or not kinds:
            raise ConfigError(f"FaultInjector kinds must be a non-empty subset of {KINDS}, got {list(kinds)}")
        self.skill, self.rate, self.kinds, self.slow_ms = skill, float(rate), tuple(kinds), float(slow_ms)
        self.state_keys = tuple(skill.state_keys)
        self._rng = np.random.default_rng(0)
        self.injected = {kind: 0 for kind in self.kinds}

    def reset(self, rng: np.random.Generator) -> None:
        own, inner = rng.spawn(2)
        self._rng = own
        self.skill.reset(inner)

    def act(self, state: np.ndarray) -> SkillOutput:
        out = self.skill.act(state)
        if self._rng.random() >= self.rate:
            return out
        kind = self.kinds[int(self._rng.integers(len(self.kinds)))]
        self.injected[kind] += 1
        action = np.asarray(out.action, dtype=np.float64)
        if kind == "raise":
            raise InjectedFault("injected fault")
        if kind == "nan":
            return SkillOutput(np.full_like(action, np.nan), out.info)
        if kind == "inf":
            return SkillOutput(np.full_like(action, np.inf), out.info)
        if kind == "shape":
            return SkillOutput(np.zeros(action.size + 1), out.info)
        time.sleep(self.slow_ms / 1e3)
        return out
