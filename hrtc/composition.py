"""State filters, the action filter and the composed environment: HRTC's glue between skills and the meta-policy.

The paper's action filter is a weighted sum, ``A = sum_k w_k * a_k`` with ``a_k = skill_k(state_filter_k(s))``, then
clipped to the action bounds. :class:`ComposedEnv` wraps a task so that its *action is the weight vector*: the
meta-policy is then PPO with a Beta head on that environment, and the skills compute inside the environment's own
process (so they run in parallel across vector-environment workers).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import gymnasium as gym
import numpy as np

from hrtc.errors import ConfigError, ShapeError, UnknownNameError, interrupt_within
from hrtc.skill import Skill, SkillOutput

log = logging.getLogger(__name__)

BlendMode = Literal["sum", "convex"]
BLEND_MODES: tuple[str, ...] = ("sum", "convex")
# Skill diagnostics whose key ends so are wall-clock timings (ms): not reproducible, so left out of a ComposedEnv's
# info unless it was built with diagnostics=True (nested skills' keys, ``<child>/solve_ms``, end so too).
TIMING_SUFFIX = "_ms"


# --------------------------------------------------------------------------------------------------- state filters
class StateFilter(Protocol):
    """Selects what one skill reads from the task's named state."""

    def __call__(self, state: Mapping[str, np.ndarray]) -> np.ndarray: ...


@dataclass(frozen=True)
class KeysFilter:
    """Concatenates the named quantities ``keys``, in order, into one float64 vector."""

    keys: tuple[str, ...]

    def __call__(self, state: Mapping[str, np.ndarray]) -> np.ndarray:
        if not self.keys:
            return np.zeros(0)
        try:
            return np.concatenate([np.atleast_1d(np.asarray(state[k], dtype=np.float64)).ravel() for k in self.keys])
        except KeyError as error:
            raise UnknownNameError("state key", str(error.args[0]), tuple(state)) from None


# --------------------------------------------------------------------------------------------------- action filter
def blend(weights: np.ndarray, proposals: np.ndarray, mode: BlendMode = "sum") -> np.ndarray:
    """Combine skill proposals. ``weights`` (K,), ``proposals`` (K, A) -> (A,).

    ``sum``: the paper's ``sum_k w_k a_k``. ``convex``: ``sum_k w_k a_k / sum_k w_k`` (zero when every weight is 0).
    Weights are clipped to [0, 1] first (Normal-weight meta-policies can sample outside it).
    """
    weights = np.clip(weights, 0.0, 1.0)
    combined = weights @ proposals
    if mode == "convex":
        total = weights.sum()
        combined = combined / total if total > 1e-8 else np.zeros_like(combined)
    return combined


@dataclass(frozen=True)
class ActionFilter:
    """``blend`` then clip to ``[low, high]``."""

    low: np.ndarray
    high: np.ndarray
    mode: BlendMode = "sum"

    def __post_init__(self) -> None:
        if self.mode not in BLEND_MODES:
            raise UnknownNameError("action filter mode", self.mode, BLEND_MODES)

    def __call__(self, weights: np.ndarray, proposals: np.ndarray) -> np.ndarray:
        return np.clip(blend(weights, proposals, self.mode), self.low, self.high)


# --------------------------------------------------------------------------------------------------- skill library
@dataclass
class SkillSlot:
    """One skill in a library: its name (config name = Rerun entity = registry key), state filter and rate.

    ``every``: the skill is asked for a new action every ``every`` env steps and its action is held in between.
    ``time_budget_ms``: a proposal that took longer is discarded as a fault (the call cannot be pre-empted, but its
    late action is not used), None for no budget.

    Fault isolation: a skill is third-party solver code. A proposal that raises, is not finite, has the wrong shape or
    is over budget is replaced by the skill's last good action (zero before it has one), counted in ``faults`` and
    flagged ``fault = 1`` in its diagnostics; the run goes on. The one exception is a wrong shape before the skill has
    ever proposed a good action: that is a configuration error (:class:`ShapeError`), raised at the first reset.
    ``faults`` and ``calls`` count over the slot's lifetime (all episodes).
    """

    name: str
    skill: Skill
    state_filter: StateFilter
    every: int = 1
    time_budget_ms: float | None = None
    faults: int = 0
    calls: int = 0
    last_fault: str = ""
    _held: np.ndarray | None = field(default=None, repr=False)
    _info: Mapping[str, float] = field(default_factory=dict, repr=False)
    _good: bool = field(default=False, repr=False)

    def reset(self, rng: np.random.Generator) -> None:
        self.skill.reset(rng)
        self._held, self._info = None, {}

    def propose(self, state: Mapping[str, np.ndarray], step: int, action_dim: int) -> SkillOutput:
        if self._held is not None and step % self.every != 0:
            return SkillOutput(self._held, self._info)
        self.calls += 1
        start = time.perf_counter()
        problem, action, info = "", None, {}
        filtered = self.state_filter(state)  # outside the isolation: a missing state key is a configuration error
        try:
            out = self.skill.act(filtered)
            action = np.asarray(out.action, dtype=np.float64)
            info = {k: float(v) for k, v in out.info.items()}
        except Exception as error:  # noqa: BLE001  (any failure of the skill's own code is isolated here)
            if (interrupt := interrupt_within(error)) is not None:
                raise interrupt from error  # but not Ctrl-C or SIGTERM that a library wrapped: the run stops
            problem = f"raised {type(error).__name__}: {error}"
        elapsed = (time.perf_counter() - start) * 1e3
        if not problem:
            if action.shape != (action_dim,):
                if not self._good:
                    raise ShapeError(f"skill {self.name!r} proposed an action of shape {action.shape}; the task's is "
                                     f"{(action_dim,)}")  # fmt: skip
                problem = f"proposed an action of shape {action.shape}, not {(action_dim,)}"
            elif not np.all(np.isfinite(action)):
                problem = f"proposed a non-finite action {action}"
            elif self.time_budget_ms is not None and elapsed > self.time_budget_ms:
                problem = f"took {elapsed:.1f} ms, over its {self.time_budget_ms:g} ms budget"
        if problem:
            self.faults += 1
            self.last_fault = problem
            if self.faults <= 3 or self.faults % 100 == 0:
                log.warning("skill %r %s; using its last good action (fault %d of %d calls)", self.name, problem,
                            self.faults, self.calls)  # fmt: skip
            action = self._held if self._held is not None else np.zeros(action_dim)
            info = {**self._info, **{k: v for k, v in info.items() if np.isfinite(v)}, "fault": 1.0}
        else:
            self._good = True
            info["fault"] = 0.0
        info["compute_ms"] = info.get("compute_ms", elapsed) if not problem else elapsed
        self._held, self._info = action, info
        return SkillOutput(action, info)


class SkillLibrary:
    """The task's skills, in a fixed order (the order of the weight vector)."""

    def __init__(self, slots: Sequence[SkillSlot]) -> None:
        if not slots:
            raise ConfigError("a skill library needs at least one skill")
        names = [s.name for s in slots]
        if len(set(names)) != len(names):
            raise ConfigError(f"skill names must be unique, got {names}")
        self.slots = list(slots)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.slots)

    def __len__(self) -> int:
        return len(self.slots)

    def reset(self, rng: np.random.Generator) -> None:
        for slot, child in zip(self.slots, rng.spawn(len(self.slots)), strict=True):
            slot.reset(child)

    def propose(self, state: Mapping[str, np.ndarray], step: int, action_dim: int) -> tuple[np.ndarray, list]:
        """Every skill's proposal for ``state``: (K, action_dim) actions and K diagnostics dicts."""
        outs = [slot.propose(state, step, action_dim) for slot in self.slots]
        return np.stack([o.action for o in outs]), [o.info for o in outs]


def build_library(skills_cfg: Mapping[str, Mapping[str, Any]]) -> SkillLibrary:
    """Build a library from a task config's ``skills`` mapping::

    name: {skill: {_target_: module.Class, ...kwargs}, state: [keys...], every: 1, time_budget_ms: 50}

    (all but ``skill`` optional).
    """
    from hydra.utils import instantiate

    slots = []
    for name, spec in skills_cfg.items():
        spec = dict(spec)
        unknown = set(spec) - {"skill", "state", "every", "time_budget_ms"}
        if unknown or "skill" not in spec:
            raise ConfigError(
                f"skill {name!r}: expected keys skill (required), state, every, time_budget_ms; got {sorted(spec)}"
            )
        try:
            skill = instantiate(spec["skill"], _convert_="all")
        except Exception as error:  # hydra wraps import and constructor errors: report them on one line
            lines = [line.strip() for line in str(error.__cause__ or error).splitlines() if line.strip()] or [""]
            detail = lines[0] + (f" {lines[-1]}" if len(lines) > 1 else "")  # hydra's first and hint lines
            raise ConfigError(f"skill {name!r} could not be built: {detail}") from error
        every = int(spec.get("every", 1))
        if every < 1:
            raise ConfigError(f"skill {name!r}: every must be >= 1, got {every}")
        budget = spec.get("time_budget_ms")
        if budget is not None and not float(budget) > 0:
            raise ConfigError(f"skill {name!r}: time_budget_ms must be > 0, got {budget}")
        keys = tuple(spec["state"]) if spec.get("state") is not None else tuple(skill.state_keys)
        slots.append(SkillSlot(name, skill, KeysFilter(keys), every, float(budget) if budget is not None else None))
    return SkillLibrary(slots)


# --------------------------------------------------------------------------------------------------- composition
class Composition:
    """HRTC's composition, written once: at every env step each skill proposes for the task's named state (through
    its state filter, at its own rate), and the action filter blends the proposals with the meta-policy's weights,
    which are held for ``decision_every`` env steps (a new decision at steps 0, k, 2k... of an episode).

    Used by :class:`ComposedEnv` (a task whose action is the weights) and by a learned meta-policy acting as a skill
    of another task (``skills.learned.PolicySkill``, the paper's recursion).
    """

    def __init__(self, library: SkillLibrary, action_filter: ActionFilter, decision_every: int = 1) -> None:
        if int(decision_every) < 1:
            raise ConfigError(f"decision_every must be >= 1, got {decision_every}")
        self.library, self.action_filter, self.decision_every = library, action_filter, int(decision_every)
        self.action_dim = int(np.asarray(action_filter.low).shape[0])
        self.step = 0  # env steps since the episode began
        self.weights = np.zeros(len(library))  # the held weights, clipped to [0, 1]
        self._proposed: tuple[int, np.ndarray, list] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return self.library.names

    def reset(self, rng: np.random.Generator) -> None:
        self.library.reset(rng)
        self.step, self.weights, self._proposed = 0, np.zeros(len(self.library)), None

    def propose(self, state: Callable[[], Mapping[str, np.ndarray]]) -> tuple[np.ndarray, list]:
        """Every skill's proposal (K, A) and diagnostics for this step's ``state()``, asked once per step."""
        if self._proposed is None or self._proposed[0] != self.step:
            self._proposed = (self.step, *self.library.propose(state(), self.step, self.action_dim))
        return self._proposed[1], self._proposed[2]

    def act(self, state: Callable[[], Mapping[str, np.ndarray]],
            decide: Callable[[], np.ndarray]) -> tuple[np.ndarray, np.ndarray, list]:  # fmt: skip
        """This step's action: new weights from ``decide()`` when a decision is due (else the held ones) blended
        with the skills' proposals for ``state()``. Returns (action (A,), proposals (K, A), diagnostics); the step
        advances."""
        if self.step % self.decision_every == 0:
            self.weights = np.clip(np.asarray(decide(), dtype=np.float64), 0.0, 1.0)
        proposals, infos = self.propose(state)
        action = self.action_filter(self.weights, proposals)
        self.step += 1
        return action, proposals, infos


# --------------------------------------------------------------------------------------------------- composed env
class ComposedEnv(gym.Wrapper):
    """A task whose action is the skill-weight vector ``w`` in [0, 1]^K.

    Each step: every skill proposes for the current state, the action filter blends the proposals with ``w``, the
    task steps with the blended action. ``info`` carries ``weights`` (K,), ``proposals`` (K, A), ``action`` (A,),
    ``env_steps`` and per-skill diagnostics under ``skills`` (those of the last env step, with ``fault`` 1 if the
    skill faulted at any step of the decision).

    ``diagnostics=False`` (the default) keeps ``info`` reproducible: the same seed and weights give the same ``info``,
    as gymnasium's and stable-baselines3's ``check_env`` require. ``diagnostics=True`` adds what is not reproducible:
    the skills' wall-clock timings (diagnostics keys ending in ``_ms``: ``compute_ms``, ``solve_ms``, ms) and the
    lifetime ``skill_faults`` and ``skill_calls`` (K,) (also in the reset info), which the trainer's fault health
    check and the recordings read.

    ``decision_every=k``: one meta-policy decision holds its weights for ``k`` env steps while the skills act at every
    step (the meta-policy and its skills run at distinct rates); the rewards of the ``k`` steps are summed.

    ``weight_margin=m``: the action space is [-m, 1 + m]^K and the weights are clipped to [0, 1], so that a policy
    whose samples are bounded (a Beta's, mapped affinely onto the space) can still choose exactly 0 or 1, as a
    switching rule does. ``m = 0`` is the paper's meta-policy.
    """

    def __init__(
        self,
        env: gym.Env,
        library: SkillLibrary,
        mode: BlendMode = "sum",
        decision_every: int = 1,
        diagnostics: bool = False,
        weight_margin: float = 0.0,
    ) -> None:
        super().__init__(env)
        if not (np.isfinite(weight_margin) and weight_margin >= 0.0):
            raise ConfigError(f"weight_margin must be >= 0 and finite, got {weight_margin}")
        self.diagnostics = bool(diagnostics)
        space = env.action_space
        if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
            raise ConfigError(f"HRTC composes 1-D Box actions; this task's action space is {space}")
        if not hasattr(env.unwrapped, "skill_state"):
            raise ConfigError(f"task {env.unwrapped} exposes no skill_state(): skills cannot read it")
        action_filter = ActionFilter(space.low.astype(np.float64), space.high.astype(np.float64), mode)
        self.composition = Composition(library, action_filter, decision_every)
        self.library, self.action_filter, self.decision_every = library, action_filter, self.composition.decision_every
        self.action_dim = int(space.shape[0])
        self.weight_margin = float(weight_margin)
        self.action_space = gym.spaces.Box(-self.weight_margin, 1.0 + self.weight_margin, (len(library),), np.float32)

    @property
    def skill_names(self) -> tuple[str, ...]:
        return self.library.names

    def fault_counts(self) -> dict[str, np.ndarray]:
        """Lifetime ``skill_faults`` and ``skill_calls`` per skill, (K,) each."""
        slots = self.library.slots
        return {"skill_faults": np.array([s.faults for s in slots], dtype=np.float64),
                "skill_calls": np.array([s.calls for s in slots], dtype=np.float64)}  # fmt: skip

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.composition.reset(np.random.default_rng(seed) if seed is not None else self.env.np_random)
        self.composition.propose(self.env.unwrapped.skill_state)  # now: a misfit skill fails at reset
        return obs, ({**info, **self.fault_counts()} if self.diagnostics else info)

    def step(self, weights: np.ndarray):
        weights = np.asarray(weights, dtype=np.float64).reshape(-1)
        if weights.shape != (len(self.library),):
            raise ShapeError(f"expected {len(self.library)} skill weights {self.library.names}, got {weights.shape}")
        total, state = 0.0, self.env.unwrapped.skill_state
        true_total = 0.0  # a shaping task's own reward (info["true_reward"]), summed too
        faulted = np.zeros(len(self.library))  # a skill's fault at any env step of this decision is reported
        for _ in range(self.decision_every):
            action, proposals, skill_info = self.composition.act(state, lambda: weights)
            faulted = np.maximum(faulted, [i.get("fault", 0.0) for i in skill_info])
            obs, reward, terminated, truncated, info = self.env.step(action.astype(np.float32))
            total += float(reward)
            true_total += float(info.get("true_reward", reward))
            if terminated or truncated:
                break
            self.composition.propose(state)  # the next step's proposals now: the fault counts below include them
        if "true_reward" in info:
            info["true_reward"] = true_total
        keep = (lambda key: True) if self.diagnostics else (lambda key: not key.endswith(TIMING_SUFFIX))
        info.update(
            weights=self.composition.weights.copy(),
            proposals=proposals,
            action=action,
            env_steps=self.composition.step,
            skills={
                name: {**{k: v for k, v in i.items() if keep(k)}, "fault": float(f)}
                for name, i, f in zip(self.library.names, skill_info, faulted, strict=True)
            },  # fmt: skip
        )
        if self.diagnostics:
            info.update(self.fault_counts())
        return obs, total, terminated, truncated, info
