"""``check_skill``: validate any skill against the :class:`~hrtc.skill.Skill` protocol, in the spirit of SB3's
``check_env``.

A skill passes when, over a set of real task states:

- it declares ``state_keys`` (a tuple of names the task's ``skill_state()`` provides);
- ``act`` returns a :class:`~hrtc.skill.SkillOutput` whose action has the task's action shape, is finite and lies
  within the action bounds (a small tolerance), and whose diagnostics are finite scalar numbers;
- it is deterministic under a seed: two passes over the same states after ``reset`` with the same seed agree exactly;
- ``reset`` forgets the past: a pass after other states have been seen equals a pass from a fresh reset.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from hrtc.composition import KeysFilter, StateFilter
from hrtc.errors import HRTCError
from hrtc.skill import Skill, SkillOutput

NamedState = Mapping[str, np.ndarray]


class SkillCheckError(HRTCError, AssertionError):
    """A skill broke the protocol; the message lists every problem found."""


def task_states(
    task: str | gym.Env,
    n: int = 200,
    seed: int = 0,
    policy: Callable[[np.random.Generator, gym.spaces.Box], np.ndarray] | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
) -> list[dict[str, np.ndarray]]:
    """``n`` named states (``skill_state()`` dicts) of ``task`` visited under uniformly random actions (or
    ``policy(rng, action_space)``), across episodes started from seeds ``seed, seed + 1, ...``."""
    import envs

    env = envs.make(task, **dict(env_kwargs or {})) if isinstance(task, str) else task
    rng = np.random.default_rng(seed)
    states: list[dict[str, np.ndarray]] = []
    try:
        episode = 0
        env.reset(seed=seed)
        while len(states) < n:
            states.append({k: np.array(v, copy=True) for k, v in env.unwrapped.skill_state().items()})
            space = env.action_space
            action = policy(rng, space) if policy is not None else rng.uniform(space.low, space.high)
            _, _, terminated, truncated, _ = env.step(np.asarray(action, dtype=space.dtype))
            if terminated or truncated:
                episode += 1
                env.reset(seed=seed + episode)
    finally:
        if isinstance(task, str):
            env.close()
    return states


def _run(skill: Skill, inputs: Sequence[np.ndarray], seed: int) -> list[SkillOutput]:
    skill.reset(np.random.default_rng(seed))
    return [skill.act(x) for x in inputs]


def check_skill(
    skill: Skill,
    states: Sequence[NamedState],
    action_space: gym.spaces.Box,
    state_filter: StateFilter | None = None,
    seed: int = 0,
    atol: float = 1e-6,
) -> dict[str, float]:
    """Check ``skill`` on ``states`` (named task states, e.g. from :func:`task_states`) for a task with
    ``action_space``. Raises :class:`SkillCheckError` listing every problem; returns summary statistics
    (``steps``, action ``min``/``max``, ``median_ms`` per act)."""
    import time

    problems: list[str] = []
    keys = getattr(skill, "state_keys", None)
    if not isinstance(keys, tuple) or not all(isinstance(k, str) for k in keys):
        raise SkillCheckError(f"{type(skill).__name__}.state_keys must be a tuple of str, got {keys!r}")
    if not states:
        raise SkillCheckError("check_skill needs at least one state")
    missing = [k for k in keys if k not in states[0]]
    if state_filter is None and missing:
        raise SkillCheckError(f"state_keys {missing} are not in the task's state (it has {sorted(states[0])})")
    state_filter = state_filter or KeysFilter(keys)
    inputs = [state_filter(s) for s in states]
    shape = action_space.shape
    low, high = action_space.low.astype(np.float64), action_space.high.astype(np.float64)

    times = []
    skill.reset(np.random.default_rng(seed))
    first: list[SkillOutput] = []
    for i, x in enumerate(inputs):
        tic = time.perf_counter()
        out = skill.act(x)
        times.append(time.perf_counter() - tic)
        first.append(out)
        if not isinstance(out, SkillOutput):
            problems.append(f"step {i}: act returned {type(out).__name__}, not SkillOutput")
            break
        action = np.asarray(out.action, dtype=np.float64)
        if action.shape != shape:
            problems.append(f"step {i}: action shape {action.shape}, the task's is {shape}")
            break
        if not np.all(np.isfinite(action)):
            problems.append(f"step {i}: non-finite action {action}")
        elif np.any(action < low - atol) or np.any(action > high + atol):
            problems.append(f"step {i}: action {action} outside the bounds [{low}, {high}]")
        if not isinstance(out.info, Mapping):
            problems.append(f"step {i}: info is {type(out.info).__name__}, not a mapping")
        else:
            try:
                bad = {k: v for k, v in out.info.items() if not np.isfinite(float(v))}
            except (TypeError, ValueError):
                bad = {k: v for k, v in out.info.items() if np.ndim(v) != 0}
                problems.append(f"step {i}: diagnostics must be scalar numbers, got {bad}")
            else:
                if bad:
                    problems.append(f"step {i}: non-finite diagnostics {bad}")
        if len(problems) >= 10:
            break
    if problems:
        raise SkillCheckError(f"{type(skill).__name__} failed check_skill:\n  " + "\n  ".join(problems))

    second = _run(skill, inputs, seed)
    diff = _first_difference(first, second)
    if diff is not None:
        problems.append(f"not deterministic under seed {seed}: two passes differ first at step {diff}")
    # Reset behaviour: after seeing the states in reverse, a reset must give the first pass again.
    _run(skill, inputs[::-1], seed + 1)
    third = _run(skill, inputs, seed)
    diff = _first_difference(first, third)
    if diff is not None:
        problems.append(f"reset does not forget the past: a pass after reset differs first at step {diff}")
    if problems:
        raise SkillCheckError(f"{type(skill).__name__} failed check_skill:\n  " + "\n  ".join(problems))
    actions = np.stack([np.asarray(o.action, dtype=np.float64) for o in first])
    return {
        "steps": float(len(inputs)),
        "min": float(actions.min()),
        "max": float(actions.max()),
        "median_ms": float(np.median(times) * 1e3),
    }


def _first_difference(a: Sequence[SkillOutput], b: Sequence[SkillOutput]) -> int | None:
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        if not np.array_equal(np.asarray(x.action), np.asarray(y.action)):
            return i
    return None


def check_task_skills(task_cfg: Mapping[str, Any], n: int = 200, seed: int = 0) -> dict[str, dict[str, float]]:
    """``check_skill`` every skill a task config (``{name, skills, env_kwargs}``) declares, on states of that task.
    Returns per-skill summaries; raises :class:`SkillCheckError` naming the first skill that fails."""
    import envs
    from hrtc.composition import build_library

    env = envs.make(task_cfg["name"], **dict(task_cfg.get("env_kwargs") or {}))
    try:
        states = task_states(env, n, seed)
        library = build_library(task_cfg["skills"])
        results = {}
        for slot in library.slots:
            try:
                results[slot.name] = check_skill(slot.skill, states, env.action_space, slot.state_filter, seed)
            except SkillCheckError as error:
                raise SkillCheckError(f"skill {slot.name!r}: {error}") from None
        return results
    finally:
        env.close()
