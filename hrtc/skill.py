"""The Skill protocol: one controller the meta-policy can compose.

A skill is numpy-only at its boundary. It receives the vector its state filter produced and returns the action it
proposes (in the task's action units) with diagnostics. Solver state (warm starts, plans) lives inside the skill.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np


class SkillOutput(NamedTuple):
    """What a skill proposes for one step.

    action: (action_dim,) float64, in the task's action units (not yet clipped).
    info: scalar diagnostics, e.g. ``solve_ms`` (solver wall time, ms), ``status`` (0 means success), ``cost``.
    """

    action: np.ndarray
    info: Mapping[str, float]


@runtime_checkable
class Skill(Protocol):
    """A sub-skill. ``state_keys`` names the quantities its default state filter selects, in order."""

    state_keys: tuple[str, ...]

    def reset(self, rng: np.random.Generator) -> None:
        """Forget episode state (warm starts, integrators). Randomness, if any, comes from ``rng``."""
        ...

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose an action for the filtered state ``state`` (the concatenation of ``state_keys``)."""
        ...
