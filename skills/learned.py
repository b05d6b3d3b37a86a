"""Learned skills: a saved checkpoint (our PPO, or an HRTC meta-policy) acting as a skill of another task.

A PPO checkpoint proposes the mode of its action distribution (the Beta mean mapped onto its action bounds, or the
clipped Normal mean). An HRTC checkpoint is a meta-policy *as a skill* (the paper's recursion): it rebuilds its own
skill library from ``meta["skills_cfg"]``, chooses its weights as the Beta mean every ``meta["decision_every"]`` calls
(its own rate), and proposes the blend of its children's proposals. Trees of any depth follow, because a child may
itself be a :class:`PolicySkill`.

Either way the policy sees what it saw in training: its observation (by default the task's flat ``observation``)
normalised with the saved running statistics, as float32. Shapes are checked when the skill is built, against a
real state of the task it will act in, so a checkpoint that does not fit fails at start with one line.

Config::

    balance: {skill: {_target_: skills.learned.PolicySkill, path: runs/.../best.pt, task: cartpole_swingup}}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hrtc.checkpoint import load_policy, resolve_checkpoint
from hrtc.composition import ActionFilter, Composition, KeysFilter, SkillLibrary, build_library
from hrtc.errors import CheckpointError, ConfigError, ShapeError
from hrtc.policy import to_action
from hrtc.skill import SkillOutput


class PolicySkill:
    """A checkpoint acting deterministically as a skill.

    Args:
        path: the checkpoint (``checkpoints/best.pt`` of a run); relative paths are also looked up from the
            repository root.
        observation_keys: the named quantities, concatenated, that form the policy's observation (its training
            observation: the task's flat ``observation`` by default).
        task: the task this skill will act in, used to check shapes at construction (default: the checkpoint's own
            task). Pass it whenever the skill is reused in another task, so that a misfit fails at start.
        env_kwargs: keyword arguments for ``task`` (default: the checkpoint's own when ``task`` is its task).

    ``state_keys`` is ``observation_keys`` for a PPO checkpoint; for an HRTC checkpoint it also lists every key its
    children read, and ``act`` splits the concatenated state back into them (sizes measured on a real state).
    ``act`` returns the action (action_dim,) in the task's units. Info of an HRTC node: ``weight/<child>`` (its
    weight in [0, 1]) and every child's diagnostics as ``<child>/<key>``, so nested weights read
    ``<child>/weight/<grandchild>`` (see :func:`hrtc.tree.effective_weights`).
    """

    def __init__(
        self,
        path: str | Path,
        observation_keys: Sequence[str] = ("observation",),
        task: str | None = None,
        env_kwargs: Mapping[str, Any] | None = None,
    ) -> None:
        import envs

        self.path = resolve_checkpoint(path)
        self.policy, self.normalizer, self.meta = load_policy(self.path)
        self.algo, self.dist = str(self.meta["algo"]), str(self.meta["dist"])
        self.obs_dim, self.out_dim = int(self.meta["obs_dim"]), int(self.meta["out_dim"])
        self.observation_keys = tuple(observation_keys)
        if not self.observation_keys:
            raise ConfigError(f"{self.path}: observation_keys must name at least one state quantity")
        self.task = task or str(self.meta["task"])
        if env_kwargs is None:
            env_kwargs = self.meta.get("env_kwargs", {}) if self.task == self.meta["task"] else {}
        self.decision_every = int(self.meta.get("decision_every", 1)) if self.algo == "hrtc" else 1
        self.weight_margin = float(self.meta.get("weight_margin", 0.0))
        self.library: SkillLibrary | None = None
        self.composition: Composition | None = None

        env = envs.make(self.task, **dict(env_kwargs))
        try:
            env.reset(seed=0)
            sample = {k: np.asarray(v, np.float64) for k, v in env.unwrapped.skill_state().items()}
            space = env.action_space
        finally:
            env.close()
        self.action_dim = int(space.shape[0])
        if self.algo == "hrtc":
            if "skills_cfg" not in self.meta or list(self.meta["skills_cfg"]) != list(self.meta.get("skills", [])):
                raise CheckpointError(f"{self.path} is an HRTC checkpoint without its skills config: cannot rebuild")
            if self.out_dim != len(self.meta["skills_cfg"]):
                raise CheckpointError(f"{self.path}: {self.out_dim} weights for {len(self.meta['skills_cfg'])} skills")
            self.library = build_library(self.meta["skills_cfg"])
            low, high = space.low.astype(np.float64), space.high.astype(np.float64)
            action_filter = ActionFilter(low, high, self.meta.get("action_filter", "sum"))
            self.composition = Composition(self.library, action_filter, self.decision_every)
            child_keys = [k for s in self.library.slots for k in _filter_keys(s.state_filter)]
        else:
            if self.out_dim != self.action_dim:
                raise ShapeError(
                    f"{self.path} acts in {self.out_dim} dimensions (trained on {self.meta['task']}); "
                    f"task {self.task} takes {self.action_dim}"
                )
            self.low = np.asarray(self.meta.get("action_low", space.low), np.float64)
            self.high = np.asarray(self.meta.get("action_high", space.high), np.float64)
            child_keys = []
        self.state_keys: tuple[str, ...] = tuple(dict.fromkeys([*self.observation_keys, *child_keys]))
        missing = [k for k in self.state_keys if k not in sample]
        if missing:
            raise ConfigError(f"{self.path}: task {self.task} has no state {missing}; it has {sorted(sample)}")
        self._sizes = [int(np.atleast_1d(sample[k]).size) for k in self.state_keys]
        n_obs = sum(self._sizes[: len(self.observation_keys)])
        if n_obs != self.obs_dim:
            raise ShapeError(
                f"{self.path} reads observations of {self.obs_dim} values (trained on {self.meta['task']}); "
                f"{list(self.observation_keys)} of task {self.task} give {n_obs}"
            )
        # A dry run on the real state: a child that does not fit this task fails now, not mid-training.
        self.reset(np.random.default_rng(0))
        self.act(KeysFilter(self.state_keys)(sample))
        self.reset(np.random.default_rng(0))

    def describe(self) -> str:
        """One line for the printed skill tree."""
        rate = f", decides every {self.decision_every} steps" if self.decision_every > 1 else ""
        return f"{self.algo}-{self.dist} policy from {self.meta['task']}{rate} ({self.path})"

    def reset(self, rng: np.random.Generator) -> None:
        if self.composition is not None:
            self.composition.reset(rng)

    @torch.inference_mode()
    def _mode(self, observation: np.ndarray) -> np.ndarray:
        """The distribution's mode for one observation (obs_dim,): float64 (out_dim,)."""
        obs = observation.astype(np.float32)[None]  # the dtype the policy saw in training
        if self.normalizer is not None:
            obs = self.normalizer(obs)
        return self.policy.distribution(torch.as_tensor(obs)).mode().numpy()[0].astype(np.float64)

    def _weights(self, observation: np.ndarray) -> np.ndarray:
        """The node's skill weights for one observation: its mode on the span it was trained on, [-m, 1 + m] (the
        composition clips them to [0, 1])."""
        return to_action(self._mode(observation), -self.weight_margin, 1.0 + self.weight_margin, self.dist)

    def act(self, state: np.ndarray) -> SkillOutput:
        """Propose an action (action_dim,) for ``state``, the concatenation of ``state_keys``."""
        state = np.asarray(state, dtype=np.float64).ravel()
        if state.size != sum(self._sizes):
            raise ShapeError(f"PolicySkill({self.path.name}) expects {sum(self._sizes)} state values "
                             f"{self.state_keys}, got {state.size}")  # fmt: skip
        parts = np.split(state, np.cumsum(self._sizes)[:-1])
        named = dict(zip(self.state_keys, parts, strict=True))
        observation = np.concatenate([named[k] for k in self.observation_keys])
        if self.composition is None:
            return SkillOutput(to_action(self._mode(observation), self.low, self.high, self.dist), {})
        # The node's own rate: the composition holds its weights between decisions.
        action, _, infos = self.composition.act(lambda: named, lambda: self._weights(observation))
        info: dict[str, float] = {}
        for name, weight, child in zip(self.composition.names, self.composition.weights, infos, strict=True):
            info[f"weight/{name}"] = float(weight)
            info.update({f"{name}/{k}": float(v) for k, v in child.items()})
        return SkillOutput(action, info)


def _filter_keys(state_filter: Any) -> tuple[str, ...]:
    keys = getattr(state_filter, "keys", None)
    if keys is None:
        raise ConfigError(f"a learned HRTC skill needs key-based state filters for its children, got {state_filter}")
    return tuple(keys)
