"""Reference rules over a task's own skills: what a learned composition is measured against.

A *rule* maps the task's named state (``env.unwrapped.skill_state()``) to skill weights by name (absent skills weigh
0). Every task gets, without declaring anything: each skill alone, and the untrained blend (every weight 0.5, where a
fresh Beta meta-policy starts). A task config may declare more under ``task.references`` (hand-written rules, fixed
blends), each built with ``_target_`` like a skill::

    references:
      switching rule: {_target_: hrtc.references.SwitchRule, key: pole_angle, threshold: 0.5,
                       above: {swingup: 1.0}, below: {balance: 1.0}}

Rules act at the meta-policy's decision rate, on the composed env, and are evaluated by the same episode loop as
the learners (:func:`hrtc.episodes.run_episodes`), on the same evaluation seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from hrtc.errors import ConfigError

UNTRAINED = "untrained blend (every weight 0.5)"


class WeightRule(Protocol):
    """Skill weights by name for the task's named state."""

    def __call__(self, state: Mapping[str, np.ndarray]) -> Mapping[str, float]: ...


@dataclass(frozen=True)
class FixedWeights:
    """The same weights in every state: ``weights`` by skill name, ``default`` for the skills it does not name."""

    weights: Mapping[str, float] = field(default_factory=dict)
    default: float = 0.0

    def __call__(self, state: Mapping[str, np.ndarray]) -> Mapping[str, float]:
        return self.weights

    def vector(self, names: Sequence[str]) -> np.ndarray:
        return np.array([float(self.weights.get(n, self.default)) for n in names])


@dataclass(frozen=True)
class SwitchRule:
    """``above`` while the named quantity ``key`` (its ``index``-th component; its magnitude if ``absolute``) exceeds
    ``threshold``, else ``below``: e.g. swing up while the pole is far from upright, balance near it."""

    key: str
    threshold: float
    above: Mapping[str, float]
    below: Mapping[str, float]
    absolute: bool = True
    index: int = 0

    def __call__(self, state: Mapping[str, np.ndarray]) -> Mapping[str, float]:
        value = float(np.atleast_1d(state[self.key])[self.index])
        return self.above if (abs(value) if self.absolute else value) > self.threshold else self.below


def reference_rules(skill_names: Sequence[str], declared: Mapping[str, Any] | None = None) -> dict[str, WeightRule]:
    """Each skill alone, the untrained blend, then the task's ``declared`` rules (``task.references``) built."""
    from hydra.utils import instantiate

    rules: dict[str, WeightRule] = {f"{name} alone": FixedWeights({name: 1.0}) for name in skill_names}
    rules[UNTRAINED] = FixedWeights(default=0.5)
    for name, spec in (declared or {}).items():
        try:
            rule = instantiate(dict(spec), _convert_="all")
        except Exception as error:  # hydra wraps import and constructor errors
            first = str(error.__cause__ or error).strip().splitlines()[0]
            raise ConfigError(f"reference {name!r} could not be built: {first}") from error
        unknown = set(getattr(rule, "above", {})) | set(getattr(rule, "below", {})) | set(getattr(rule, "weights", {}))
        if unknown - set(skill_names):
            raise ConfigError(f"reference {name!r} names skills {sorted(unknown - set(skill_names))}; the task's "
                              f"skills are {list(skill_names)}")  # fmt: skip
        rules[name] = rule
    return rules


def rule_decider(env: Any, rule: WeightRule) -> Callable[[np.ndarray], Any]:
    """A ``decide(obs)`` for :func:`hrtc.episodes.run_episodes` acting with ``rule`` on the composed ``env``."""
    from hrtc.episodes import Decision

    names = tuple(env.skill_names)
    base = env.unwrapped
    default = float(getattr(rule, "default", 0.0))  # the weight of skills a rule does not name

    def decide(obs: np.ndarray) -> Decision:
        chosen = rule(base.skill_state())
        weights = np.array([float(chosen.get(n, default)) for n in names])
        return Decision(np.asarray(obs, np.float32), weights, weights.astype(np.float32))

    return decide


def evaluate_rules(env: Any, rules: Mapping[str, WeightRule], seeds: Sequence[int]) -> dict[str, np.ndarray]:
    """Returns of one episode per seed for every rule, on the composed ``env``."""
    from hrtc.episodes import run_episodes

    return {name: run_episodes(env, rule_decider(env, rule), seeds) for name, rule in rules.items()}
