"""A constant action: "hold" (zeros) for the cart-pole, the static driving intents for CarRacing."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hrtc.errors import ConfigError
from hrtc.skill import SkillOutput


class StaticIntent:
    """Always propose ``action`` (action_dim,), in the task's action units; reads no state."""

    state_keys: tuple[str, ...] = ()

    def __init__(self, action: Sequence[float]) -> None:
        array = np.array(action, dtype=np.float64)
        if array.ndim != 1 or array.size == 0:
            raise ConfigError(f"action must be a non-empty 1-D sequence, got shape {array.shape}")
        if not np.all(np.isfinite(array)):
            raise ConfigError(f"action must be finite, got {array}")
        array.setflags(write=False)
        self.action = array

    def reset(self, rng: np.random.Generator) -> None:
        """Stateless: nothing to forget."""

    def act(self, state: np.ndarray) -> SkillOutput:
        """Return a copy of the constant action, whatever ``state`` is (normally an empty array)."""
        return SkillOutput(self.action.copy(), {"status": 0.0})
