"""A training run's settings, validated: :class:`RunConfig`, built from the composed Hydra config tree."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from hrtc.composition import BLEND_MODES
from hrtc.encoders import check_encoder_spec
from hrtc.errors import ConfigError, UnknownNameError
from hrtc.logging.trace import RecordingConfig
from hrtc.policy import resolve_device
from hrtc.ppo import PPOConfig
from hrtc.sac import SACConfig

ROOT_CONF = Path(__file__).resolve().parent / "conf"  # the Hydra configs shipped with the package
log = logging.getLogger(__name__)

ALGOS = ("hrtc", "ppo")
DISTS = ("beta", "normal")
LEARNERS = ("ppo", "sac")


@dataclass(frozen=True)
class RunConfig:
    """Everything one training run needs, validated. Built from the Hydra config by :meth:`from_mapping`."""

    task: str
    skills: Mapping[str, Any]
    algo: str = "hrtc"
    dist: str = "beta"
    learner: str = "ppo"
    beta_init_bias: float = 0.0
    action_filter: str = "sum"
    decision_every: int = 1
    weight_margin: float = 0.0  # HRTC's weight samples span [-m, 1 + m], clipped to [0, 1] (ComposedEnv)
    init_weights: Mapping[str, float] | None = None  # HRTC: the untrained meta-policy's weights (hrtc.policy.start_at)
    seed: int = 1
    steps: int = 100_000
    num_envs: int = 2
    vector: str = "async"
    hidden: tuple[int, ...] = (64, 64)
    activation: str = "tanh"  # the actor and critic MLPs' (hrtc.policy.ACTIVATIONS)
    weight_init: str = "orthogonal"  # the MLPs' and heads' (hrtc.policy.WEIGHT_INITS)
    eval_every: int = 5_000
    eval_episodes: int = 3
    checkpoint_every: int = 10_000
    torch_threads: int = 1
    device: str = "auto"  # cpu | cuda | auto (cuda when torch sees a GPU): where the policy acts and learns
    progress: bool = True
    init_from: str | None = None
    max_skill_fault_rate: float = 0.05
    max_skipped_updates: int = 3
    max_worker_restarts: int = 5  # vector-env workers replaced when they die (hrtc.vector); the next death stops
    solve_threshold: float | None = None
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    sac: SACConfig = field(default_factory=SACConfig)
    logger: RecordingConfig = field(default_factory=lambda: RecordingConfig(mode="off"))
    encoder: Mapping[str, Any] | None = None  # an image encoder for pixel tasks (hrtc.encoders), e.g. {name: conv}

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise UnknownNameError("algo", self.algo, ALGOS)
        if self.dist not in DISTS:
            raise UnknownNameError("dist", self.dist, DISTS)
        if self.learner not in LEARNERS:
            raise UnknownNameError("learner", self.learner, LEARNERS)
        if self.action_filter not in BLEND_MODES:
            raise UnknownNameError("action filter mode", self.action_filter, BLEND_MODES)
        if not (isinstance(self.weight_margin, (int, float)) and 0.0 <= self.weight_margin < 10.0):
            raise ConfigError(f"algo.weight_margin must be a number in [0, 10), got {self.weight_margin!r}")
        if self.init_weights:
            if self.algo != "hrtc" or self.dist != "beta":
                raise ConfigError(f"algo.init_weights needs algo=hrtc dist=beta, got algo={self.algo} dist={self.dist}")
            if self.init_from:
                raise ConfigError("algo.init_weights and init_from both set the starting policy: give one")
            unknown = sorted(set(self.init_weights) - set(self.skills))
            if unknown:
                raise UnknownNameError("algo.init_weights skill", unknown[0], tuple(self.skills))
            for name, weight in self.init_weights.items():
                if not (isinstance(weight, (int, float)) and not isinstance(weight, bool) and 0.0 <= weight <= 1.0):
                    raise ConfigError(f"algo.init_weights.{name} must be a weight in [0, 1], got {weight!r}")
        if self.vector not in ("async", "sync"):
            raise UnknownNameError("vector mode", self.vector, ("async", "sync"))
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        positive = {"steps": self.steps, "num_envs": self.num_envs, "eval_every": self.eval_every,
                    "eval_episodes": self.eval_episodes, "checkpoint_every": self.checkpoint_every,
                    "ppo.num_steps": self.ppo.num_steps, "ppo.update_epochs": self.ppo.update_epochs,
                    "ppo.num_minibatches": self.ppo.num_minibatches, "torch_threads": self.torch_threads,
                    "algo.decision_every": self.decision_every,
                    "max_skipped_updates": self.max_skipped_updates}  # fmt: skip
        for name, value in positive.items():
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.max_worker_restarts, int) or isinstance(self.max_worker_restarts, bool) \
                or self.max_worker_restarts < 0:  # fmt: skip
            raise ConfigError(f"max_worker_restarts must be a non-negative integer, got {self.max_worker_restarts!r}")
        if not 0.0 <= self.max_skill_fault_rate <= 1.0:
            raise ConfigError(f"max_skill_fault_rate must be in [0, 1], got {self.max_skill_fault_rate}")
        if not 0.0 < self.ppo.learning_rate < 1.0:
            raise ConfigError(f"ppo.learning_rate must be in (0, 1), got {self.ppo.learning_rate}")
        for name in ("gamma", "gae_lambda"):
            if not 0.0 <= getattr(self.ppo, name) <= 1.0:
                raise ConfigError(f"ppo.{name} must be in [0, 1], got {getattr(self.ppo, name)}")
        if self.ppo.num_minibatches > self.ppo.num_steps * self.num_envs:
            raise ConfigError("ppo.num_minibatches exceeds the rollout size (ppo.num_steps * num_envs)")
        if self.algo == "hrtc" and not self.skills:
            raise ConfigError(f"algo=hrtc needs skills, and task {self.task!r} declares none")
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ConfigError(f"hidden must list positive layer widths, got {self.hidden}")
        if self.encoder is not None:
            check_encoder_spec(self.encoder)
        if self.learner == "sac" and resolve_device(self.policy_device).type != "cpu":
            raise ConfigError("learner=sac runs on the CPU; set device=cpu or device=auto")

    @property
    def policy_device(self) -> str:
        """Where the policy acts and learns: ``device``, except that ``auto`` is the CPU for SAC (CPU-only)."""
        return "cpu" if self.learner == "sac" and self.device == "auto" else self.device

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> RunConfig:
        """Build from the resolved config tree (plain dicts): ``task``, ``algo``, ``dist``, ``ppo``, top-level keys."""
        cfg = dict(cfg)
        task, algo, dist = dict(cfg.pop("task")), dict(cfg.pop("algo")), dict(cfg.pop("dist"))
        ppo_cfg = dict(cfg.pop("ppo", {}) or {})
        sac_cfg = dict(cfg.pop("sac", {}) or {})
        logger = RecordingConfig.from_mapping(cfg.pop("logger", None) or {"mode": "off"})
        for block, settings in (("ppo", ppo_cfg), ("sac", sac_cfg)):
            names = {f.name for f in fields(PPOConfig if block == "ppo" else SACConfig)}
            unknown = set(settings) - names
            if unknown:
                raise ConfigError(f"unknown {block} keys {sorted(unknown)}; valid: {sorted(names)}")
        if "q_hidden" in sac_cfg:
            sac_cfg["q_hidden"] = tuple(int(h) for h in sac_cfg["q_hidden"])
        for name in ("mirror_index", "mirror_sign"):
            if sac_cfg.get(name) is not None:
                sac_cfg[name] = tuple(sac_cfg[name])
        # learner=auto: HRTC learns with the task's declared learner (task.learner, PPO if none); flat RL with PPO.
        learner = str(cfg.pop("learner", "auto"))
        if learner == "auto":
            learner = str(task.get("learner", "ppo")) if algo.get("name") == "hrtc" else "ppo"
        search = sac_cfg.get("start_search")
        if learner == "sac" and isinstance(search, int) and search > 1:  # (bad values: SACConfig's error)
            _drop_start_search(sac_cfg, algo, str(dist.get("name")), cfg.get("init_from"))
        top = {f.name for f in fields(cls)} - {"task", "skills", "algo", "dist", "action_filter", "ppo", "sac",
                                                "learner", "solve_threshold", "env_kwargs", "logger"}  # fmt: skip
        unknown = set(cfg) - top - {"run_dir", "resume"}
        if unknown:
            raise ConfigError(f"unknown config keys {sorted(unknown)}; valid: {sorted(top)}")
        kwargs = {k: v for k, v in cfg.items() if k in top}
        if "hidden" in kwargs:
            kwargs["hidden"] = tuple(int(h) for h in kwargs["hidden"])
        return cls(
            task=str(task.get("name")),
            skills=task.get("skills") or {},
            solve_threshold=task.get("solve_threshold"),
            env_kwargs=task.get("env_kwargs") or {},
            algo=str(algo.get("name")),
            action_filter=str(algo.get("action_filter", "sum")),
            decision_every=algo.get("decision_every", 1),
            weight_margin=algo.get("weight_margin", 0.0),
            init_weights=dict(algo["init_weights"]) if algo.get("init_weights") else None,
            dist=str(dist.get("name")),
            beta_init_bias=float(dist.get("init_bias", 0.0)),
            learner=learner,
            ppo=PPOConfig(**ppo_cfg),
            sac=SACConfig(**sac_cfg),
            logger=logger,
            **kwargs,
        )

    @property
    def steps_per_decision(self) -> int:
        """Env steps one decision spans: ``decision_every`` for HRTC (the composed env holds its weights), else 1."""
        return self.decision_every if self.algo == "hrtc" else 1

    @property
    def learner_settings(self) -> PPOConfig | SACConfig:
        """The settings block of the run's learner."""
        return self.sac if self.learner == "sac" else self.ppo


def _drop_start_search(sac_cfg: dict[str, Any], algo: Mapping[str, Any], dist: str, init_from: Any) -> None:
    """A task's default start search (``sac.start_search``, lunarlander's) steps aside, logged, where the run gives the
    actor's start itself (``algo.init_weights``, ``init_from``) or the meta-policy has no Beta weights to start."""
    if algo.get("init_weights"):
        why = "algo.init_weights gives the actor's start"
    elif init_from:
        why = "init_from gives the actor's start"
    elif algo.get("name") != "hrtc" or dist != "beta":
        why = f"it needs algo=hrtc dist=beta, got algo={algo.get('name')} dist={dist}"
    else:
        return
    log.warning("sac.start_search=%s skipped: %s", sac_cfg["start_search"], why)
    sac_cfg.update(start_search=0, start_search_forget=False, start_search_reset=False, start_search_keep_winner=False)
