"""The training loop: rollouts in vector environments, PPO updates, evaluation with the Beta mean, checkpoints.

HRTC and plain PPO share every line here. For HRTC the environment is a :class:`~hrtc.composition.ComposedEnv`
(its action is the skill-weight vector); for PPO it is the raw task. A sample ``u`` of the policy's distribution
becomes the environment's action by :func:`to_env_action`.
"""

from __future__ import annotations

import functools
import logging
import random
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch

from hrtc.checkpoint import load_checkpoint, resolve_checkpoint, save_checkpoint
from hrtc.composition import BLEND_MODES, ComposedEnv, build_library
from hrtc.distributions import BetaDistribution
from hrtc.encoders import build_encoder, check_encoder_spec
from hrtc.errors import CheckpointError, ConfigError, HRTCError, SkillError, UnknownNameError
from hrtc.learner import Learner, Step
from hrtc.logging import CsvSink, Sink
from hrtc.logging.trace import Recorder, RecordingConfig
from hrtc.normalize import ObsNormalizer, RewardScaler
from hrtc.policy import ActorCritic, resolve_device
from hrtc.ppo import PPOConfig, PPOLearner
from hrtc.sac import SACConfig, SACLearner
from hrtc.tree import describe

log = logging.getLogger(__name__)

ROOT_CONF = Path(__file__).resolve().parent / "conf"  # the Hydra configs shipped with the package

ALGOS = ("hrtc", "ppo")
DISTS = ("beta", "normal")
LEARNERS = ("ppo", "sac")
# train.csv: these, with the learner's own columns after the first two and each skill's fault count at the end.
# train/true_episode_reward: the task's own return where the env shapes its reward (info["true_reward"]).
TRAIN_COLUMNS = ("episodes", "train/episode_reward", "train/true_episode_reward", "charts/SPS", "charts/rollout_SPS",
                 "charts/update_seconds")  # fmt: skip
EVAL_COLUMNS = ("episode_reward", "episode_reward_std", "episodes", "train_episodes", "wall_seconds")


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
        if resolve_device(self.device).type != "cpu" and self.learner == "sac":
            raise ConfigError("learner=sac runs on the CPU; set device=cpu")

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
        # learner=auto: HRTC learns with the task's declared learner (task.learner, PPO if none); flat RL with PPO.
        learner = str(cfg.pop("learner", "auto"))
        if learner == "auto":
            learner = str(task.get("learner", "ppo")) if algo.get("name") == "hrtc" else "ppo"
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
            dist=str(dist.get("name")),
            beta_init_bias=float(dist.get("init_bias", 0.0)),
            learner=learner,
            ppo=PPOConfig(**ppo_cfg),
            sac=SACConfig(**sac_cfg),
            logger=logger,
            **kwargs,
        )


# --------------------------------------------------------------------------------------------------- environments
def make_env(task: str, algo: str, skills: Mapping[str, Any], action_filter: str = "sum",
             env_kwargs: Mapping[str, Any] | None = None, decision_every: int = 1,
             diagnostics: bool = True) -> gym.Env:  # fmt: skip
    """The environment the policy acts in: the task itself (``ppo``) or the task composed with its skills (``hrtc``).
    ``diagnostics``: the composed env's timings and fault counters in ``info`` (see :class:`ComposedEnv`)."""
    import envs

    env = envs.make(task, **dict(env_kwargs or {}))
    if algo == "hrtc":
        env = ComposedEnv(env, build_library(skills), action_filter, decision_every, diagnostics)  # type: ignore[arg-type]
    return env


def env_factory(cfg: RunConfig) -> Callable[[], gym.Env]:
    """A picklable thunk, so that vector-environment workers build their own env and skills."""
    return functools.partial(
        make_env, cfg.task, cfg.algo, cfg.skills, cfg.action_filter, cfg.env_kwargs, cfg.decision_every
    )


def to_env_action(u: np.ndarray, space: gym.spaces.Box, dist: str) -> np.ndarray:
    """Map a policy sample to the environment's action: Beta samples (0, 1) affinely onto ``[low, high]``;
    Normal samples clipped to ``[low, high]``. For HRTC the action space is [0, 1]^K, so weights are ``u``."""
    if dist == "beta":
        return (space.low + (space.high - space.low) * u).astype(np.float32)
    return np.clip(u, space.low, space.high).astype(np.float32)


def policy_for(cfg: RunConfig, obs_dim: int, space: gym.spaces.Box) -> ActorCritic:
    centre = float(np.mean((space.low + space.high) / 2))
    log_std = float(np.log(np.mean(space.high - space.low) / 4))  # std a quarter of the range
    encoder = build_encoder(cfg.encoder, obs_dim) if cfg.encoder is not None else None
    return ActorCritic(obs_dim, int(space.shape[0]), cfg.dist, cfg.hidden, centre, log_std, cfg.beta_init_bias,
                       encoder=encoder, activation=cfg.activation, weight_init=cfg.weight_init)  # fmt: skip


def learner_settings(cfg: RunConfig) -> PPOConfig | SACConfig:
    """The settings block of the run's learner."""
    return cfg.sac if cfg.learner == "sac" else cfg.ppo


def build_learner(cfg: RunConfig, policy: ActorCritic, steps_per_decision: int, generator: torch.Generator) -> Learner:
    """The run's learner for ``policy``; it discounts per decision (``gamma ** steps_per_decision``)."""
    settings = learner_settings(cfg)
    gamma = settings.gamma**steps_per_decision
    if cfg.learner == "sac":
        return SACLearner(policy, cfg.sac, gamma, generator)
    num_updates = -(-cfg.steps // (cfg.ppo.num_steps * cfg.num_envs * steps_per_decision))
    return PPOLearner(policy, cfg.ppo, cfg.num_envs, gamma, num_updates, generator)


def normalize_obs(normalizer: ObsNormalizer | None, obs: np.ndarray, update: bool = False) -> np.ndarray:
    """``obs`` (batch, obs_dim) as the policy sees it: normalised when the run normalises, else float32 (uint8 pixels
    stay uint8: the encoder converts them, and the rollout stores a quarter of the bytes)."""
    if normalizer is not None:
        return normalizer(obs, update)
    return obs if obs.dtype == np.uint8 else obs.astype(np.float32)


# --------------------------------------------------------------------------------------------------- evaluation
class Decision(NamedTuple):
    """One decision of a fixed policy: its input ``obs`` (as the policy saw it), output ``u``, the task action, and
    the Beta parameters when it has them."""

    obs: np.ndarray
    u: np.ndarray
    action: np.ndarray
    alpha: np.ndarray | None = None
    beta: np.ndarray | None = None


def run_episodes(
    env: gym.Env,
    decide: Callable[[np.ndarray], Decision],
    seeds: Sequence[int],
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
    values: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Returns of one episode per seed acting with ``decide``. With a ``recorder`` every decision is traced (weights,
    alpha/beta, proposals, action, reward, skill diagnostics, and frames from ``render`` when the recorder asks) and
    handed over when the episode ends, with ``values`` of the traced observations (one batch)."""
    returns = []
    for episode, seed in enumerate(seeds):
        obs, _ = env.reset(seed=int(seed))
        trace = recorder.begin(episode, int(seed), render) if recorder is not None else None
        total, done = 0.0, False
        while not done:
            decision = decide(obs)
            obs, reward, terminated, truncated, info = env.step(decision.action)
            total += float(reward)
            done = terminated or truncated
            if trace is not None:
                trace.add(decision.obs, decision.u, decision.alpha, decision.beta, decision.action, float(reward), info)
        returns.append(total)
        if trace is not None and recorder is not None:
            trace.episode_return = total
            if values is not None and trace.obs:
                trace.values = values(np.stack(trace.obs))
            recorder.end(trace)
    return np.asarray(returns)


@torch.no_grad()
def evaluate(
    policy: ActorCritic,
    normalizer: ObsNormalizer | None,
    env: gym.Env,
    seeds: Sequence[int],
    dist: str,
    recorder: Recorder | None = None,
    render: Callable[[], np.ndarray | None] | None = None,
) -> np.ndarray:
    """Returns of one deterministic episode per seed (the distribution's mode: the Beta mean for HRTC); recorded
    with the critic's values when a ``recorder`` is given (see :func:`run_episodes`)."""
    device = next(policy.parameters()).device

    def decide(obs: np.ndarray) -> Decision:
        nobs = normalize_obs(normalizer, obs[None])
        distribution = policy.distribution(torch.as_tensor(nobs, device=device))
        u = distribution.mode().cpu().numpy()[0]
        alpha, beta = _beta_parameters(distribution)
        return Decision(nobs[0], u, to_env_action(u, env.action_space, dist), alpha, beta)

    def values(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return policy.value(torch.as_tensor(obs, device=device)).cpu().numpy()

    return run_episodes(env, decide, seeds, recorder, render, values if recorder is not None else None)


def _beta_parameters(distribution: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    if isinstance(distribution, BetaDistribution):
        return distribution.alpha.cpu().numpy()[0], distribution.beta.cpu().numpy()[0]
    return None, None


def frame_source(env: gym.Env, size: Sequence[int]) -> Callable[[], np.ndarray | None] | None:
    """A function returning the task's current camera frame (RGB, (H, W, 3) uint8), or None if it cannot render.
    ``size`` (height, width) applies to tasks that choose their frame size (the MuJoCo tasks)."""
    base = env.unwrapped
    if hasattr(base, "render_size"):
        base.render_size = (int(size[0]), int(size[1]))
        return base.render
    if getattr(base, "render_mode", None) == "rgb_array":
        return base.render
    return None


class LoadedPolicy(NamedTuple):
    """A saved policy ready to act: the network, its observation normaliser (or None) and the checkpoint's meta."""

    policy: ActorCritic
    normalizer: ObsNormalizer | None
    meta: dict[str, Any]


def load_policy(path: str | Path, which: str = "policy") -> LoadedPolicy:
    """Rebuild the actor-critic saved in checkpoint ``path`` (weights only) in evaluation mode."""
    state = load_checkpoint(path)
    meta = dict(state["meta"])
    try:
        obs_dim = int(meta["obs_dim"])
        encoder = build_encoder(meta["encoder"], obs_dim) if meta.get("encoder") is not None else None
        policy = ActorCritic(obs_dim, int(meta["out_dim"]), str(meta["dist"]), tuple(int(h) for h in meta["hidden"]),
                             encoder=encoder, activation=str(meta.get("activation", "tanh")))  # fmt: skip
        policy.load_state_dict(state[which])
    except (KeyError, RuntimeError, ValueError) as error:
        raise CheckpointError(f"{path}: its weights do not fit its own meta ({_first(error)})") from error
    policy.eval()
    normalizer = None
    if state.get("obs_rms"):
        normalizer = ObsNormalizer((int(meta["obs_dim"]),))
        normalizer.rms.load_state_dict(state["obs_rms"])
    return LoadedPolicy(policy, normalizer, meta)


def _first(error: BaseException) -> str:
    return str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__


def load_policy_weights(trainer: Any, path: str | Path) -> dict[str, Any]:
    """Start ``trainer`` (a :class:`hrtc.trainer.Trainer`, before ``train()``; it needs ``cfg``, ``skill_names``,
    ``policy``, ``normalizer`` and ``reward_scaler``) from a checkpoint's policy, for fine-tuning on a changed task.

    Copies the actor-critic weights, the observation normaliser and the reward scaler's statistics (the critic's
    scale); the optimiser, counters and RNGs stay fresh. The checkpoint must have the same algorithm, distribution,
    network sizes and skill names, else :class:`CheckpointError`. Returns the checkpoint's meta."""
    path = resolve_checkpoint(path)
    state = load_checkpoint(path)
    meta = state["meta"]
    cfg = trainer.cfg
    mine = {"algo": cfg.algo, "dist": cfg.dist, "skills": list(trainer.skill_names), "hidden": list(cfg.hidden),
            "obs_dim": trainer.policy.obs_dim, "out_dim": trainer.policy.out_dim}  # fmt: skip
    for key, value in mine.items():
        theirs = meta.get(key)
        if (list(theirs) if isinstance(theirs, list | tuple) else theirs) != value:
            raise CheckpointError(f"cannot fine-tune from {path}: its {key} is {theirs!r}, this run's is {value!r}")
    trainer.policy.load_state_dict(state["policy"])
    if trainer.normalizer is not None and state["obs_rms"]:
        trainer.normalizer.rms.load_state_dict(state["obs_rms"])
    reward_rms = state.get("reward_rms") or (state.get("optimizer") or {}).get("reward_rms")  # older layout first
    if trainer.reward_scaler is not None and reward_rms:
        trainer.reward_scaler.rms.load_state_dict(reward_rms)
    return dict(meta)


def eval_seeds(seed: int, episodes: int) -> list[int]:
    """Evaluation episode seeds: the same at every evaluation, and disjoint from the training envs' reset seeds
    (``1000 * seed + ...``, below a million for any seed under 1000)."""
    return [1_000_000 + 1_000 * seed + k for k in range(episodes)]


# --------------------------------------------------------------------------------------------------- training
class Trainer:
    """One training run writing into ``run_dir``: ``train.csv``, ``eval.csv``, ``checkpoints/``.

    The loop (:meth:`train`) collects decisions in vector envs and hands them to the learner (:mod:`hrtc.learner`:
    PPO or SAC), evaluates with the distribution's mode on a schedule, checkpoints, checks health. ``sinks`` receive
    the same rows as the CSVs (e.g. a Rerun recording); ``resume`` continues from ``checkpoints/last.pt``.
    """

    def __init__(self, cfg: RunConfig, run_dir: str | Path, sinks: Sequence[Sink] = (), resume: bool = False) -> None:
        self.cfg, self.run_dir = cfg, Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.ckpt_dir = self.run_dir / "checkpoints"
        torch.set_num_threads(cfg.torch_threads)
        random.seed(cfg.seed)
        np.random.seed(cfg.seed)  # noqa: NPY002  (libraries that still draw from the legacy global RNG)
        torch.manual_seed(cfg.seed)
        self.generator = torch.Generator().manual_seed(cfg.seed)

        self.eval_env = env_factory(cfg)()  # built first: a bad task or skill config fails before workers start
        space = self.eval_env.action_space
        self.skill_names: tuple[str, ...] = getattr(self.eval_env, "skill_names", ())
        obs_dim = int(np.prod(self.eval_env.observation_space.shape))
        self.policy = policy_for(cfg, obs_dim, space).to(resolve_device(cfg.device))
        # One decision spans decision_every env steps: discount per decision accordingly.
        self.steps_per_decision = cfg.decision_every if cfg.algo == "hrtc" else 1
        self.learner = build_learner(cfg, self.policy, self.steps_per_decision, self.generator)
        self.normalizer = ObsNormalizer((obs_dim,)) if learner_settings(cfg).normalize_obs else None
        self.global_step, self.update, self.episodes = 0, 0, 0
        self.best_eval = -np.inf
        self.wall_offset = 0.0  # wall time of the run before a resume, s
        self._start = time.perf_counter()  # reset when train() starts
        if self.skill_names:  # the skills' first proposals: a wrong action size is an error now, not in a worker
            self.eval_env.reset(seed=cfg.seed)
        if cfg.init_from and not resume:  # fine-tune: start from a trained policy of the same shape
            load_policy_weights(self, cfg.init_from)
        if resume and not (self.ckpt_dir / "last.pt").exists():
            log.warning("resume: no checkpoint in %s yet; starting from scratch", self.ckpt_dir)
            resume = False
        if resume:
            self._restore(self.ckpt_dir / "last.pt")
        columns = {"train": (*TRAIN_COLUMNS[:3], *self.learner.columns, *TRAIN_COLUMNS[3:],
                             *(f"faults/{name}" for name in self.skill_names)), "eval": EVAL_COLUMNS}  # fmt: skip
        # A resumed run continues its CSVs from the checkpoint's step: rows written after it (the work the crash
        # lost, to be redone) are dropped, so no row is duplicated.
        csv_sink = CsvSink(self.run_dir, columns, append=resume, keep_until=self.global_step if resume else None)
        self.sinks: list[Sink] = [csv_sink, *sinks]
        self.recorder, self.render = None, None
        if cfg.logger.mode != "off":
            from hrtc.logging.rerun_sink import RerunSink

            task_action_dim = int(getattr(self.eval_env, "action_dim", space.shape[0]))
            names = self.skill_names or tuple(f"a{i}" for i in range(space.shape[0]))
            tree, paths = describe(self.eval_env, f"{cfg.task}: {cfg.algo}-{cfg.dist}")
            self.recorder = RerunSink(self.run_dir, cfg.logger, names, task_action_dim, tree, resume, tree_paths=paths,
                                      state_source=self.eval_env.unwrapped.skill_state,
                                      eval_episodes=cfg.eval_episodes)  # fmt: skip
            self.recorder.updates = self.update
            self.sinks.append(self.recorder)
            if cfg.logger.frames:
                self.render = frame_source(self.eval_env, cfg.logger.frame_size)

    @property
    def reward_scaler(self) -> RewardScaler | None:
        """PPO's reward scaler (None for SAC or when PPO does not scale)."""
        return getattr(self.learner, "reward_scaler", None)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "policy": self.policy.state_dict(),
            "optimizer": self.learner.state_dict(),  # the learner's whole training state (optimisers, buffers...)
            "obs_rms": self.normalizer.rms.state_dict() if self.normalizer else {},
            "global_step": self.global_step,
            "update": self.update,
            "episodes": self.episodes,
            "best_eval": float(self.best_eval),
            "wall_seconds": self.wall_offset + time.perf_counter() - self._start,
            "rng": {
                "torch": torch.get_rng_state(),
                "generator": self.generator.get_state(),
                "numpy": _numpy_rng_state(),
                "python": _python_rng_state(),
            },
            "meta": {
                "task": self.cfg.task,
                "algo": self.cfg.algo,
                "dist": self.cfg.dist,
                "learner": self.cfg.learner,
                "skills": list(self.skill_names),
                "obs_dim": self.policy.obs_dim,
                "out_dim": self.policy.out_dim,
                "hidden": list(self.cfg.hidden),
                "activation": self.cfg.activation,
                "action_filter": self.cfg.action_filter,
                # Enough to rebuild this policy as a skill of another task (skills.learned): plain containers only.
                "skills_cfg": _plain(self.cfg.skills),
                "env_kwargs": _plain(self.cfg.env_kwargs),
                "decision_every": self.steps_per_decision,
                "action_low": self.eval_env.action_space.low.tolist(),
                "action_high": self.eval_env.action_space.high.tolist(),
                "encoder": _plain(self.cfg.encoder),
            },
        }

    def save(self, name: str = "last.pt") -> Path:
        state = self.state_dict()
        if name != "last.pt":  # only last.pt resumes: others keep the policy, not the learner's buffers
            state["optimizer"] = {}
        return save_checkpoint(self.ckpt_dir / name, state)

    def _restore(self, path: Path) -> None:
        state = load_checkpoint(path)
        meta = state["meta"]
        mine = self.state_dict()["meta"]
        keys = ("skills", "obs_dim", "out_dim", "learner")
        if any(meta.get(k, "ppo" if k == "learner" else None) != mine[k] for k in keys):
            raise CheckpointError(
                f"{path} was trained with skills {meta['skills']} (obs {meta['obs_dim']}, out {meta['out_dim']}, "
                f"learner {meta.get('learner', 'ppo')}); this run has {mine['skills']} (obs {mine['obs_dim']}, out "
                f"{mine['out_dim']}, learner {mine['learner']})"
            )
        self.policy.load_state_dict(state["policy"])
        learner_state = state["optimizer"]
        if "param_groups" in learner_state:  # saved before the learner plug-in point: PPO's optimiser alone
            learner_state = {"optimizer": learner_state, "reward_rms": state.get("reward_rms", {})}
        self.learner.load_state_dict(learner_state)
        if self.normalizer and state["obs_rms"]:
            self.normalizer.rms.load_state_dict(state["obs_rms"])
        self.global_step, self.update = int(state["global_step"]), int(state["update"])
        self.episodes, self.best_eval = int(state["episodes"]), float(state["best_eval"])
        self.wall_offset = float(state.get("wall_seconds", 0.0))
        rng = state["rng"]
        torch.set_rng_state(rng["torch"])
        self.generator.set_state(rng["generator"])
        _set_numpy_rng_state(rng["numpy"])
        _set_python_rng_state(rng["python"])
        log.info("resumed from %s at step %d", path, self.global_step)

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, last: bool = False) -> float:
        if self.recorder is not None:
            self.recorder.start_evaluation(self.global_step, last)
        seeds = eval_seeds(self.cfg.seed, self.cfg.eval_episodes)
        policy, normalizer = self.policy, self.normalizer
        returns = evaluate(policy, normalizer, self.eval_env, seeds, self.cfg.dist, self.recorder, self.render)
        mean = float(returns.mean())
        self._write("eval", {"episode_reward": mean, "episode_reward_std": float(returns.std()),
                             "episodes": len(returns), "train_episodes": self.episodes,
                             "wall_seconds": self.wall_offset + time.perf_counter() - self._start})  # fmt: skip
        if mean > self.best_eval:
            self.best_eval = mean
            self.save("best.pt")
        return mean

    def _write(self, stream: str, metrics: Mapping[str, float]) -> None:
        for sink in self.sinks:
            sink.write(stream, self.global_step, metrics)

    def _check_health(self, faults: np.ndarray, calls: np.ndarray, skipped_in_a_row: int) -> None:
        """Stop the run (after saving it) when a skill faults too often or the loss stays non-finite."""
        for name, f, c in zip(self.skill_names, faults, calls, strict=True):
            if c >= 200 and f / c > self.cfg.max_skill_fault_rate:
                self.save()
                raise SkillError(f"skill {name!r} faulted in {f:.0f} of {c:.0f} calls ({f / c:.1%}, more than "
                                 f"max_skill_fault_rate {self.cfg.max_skill_fault_rate:.1%}); the run is saved at "
                                 f"step {self.global_step}, see the warnings above for the faults")  # fmt: skip
        if skipped_in_a_row >= self.cfg.max_skipped_updates:
            raise HRTCError(f"the PPO loss was not finite in {skipped_in_a_row} updates in a row (every minibatch "
                            f"skipped); stopping at step {self.global_step}, last checkpoint kept")  # fmt: skip

    # ------------------------------------------------------------------ the loop
    def _vector_env(self) -> gym.vector.VectorEnv:
        fns = [env_factory(self.cfg) for _ in range(self.cfg.num_envs)]
        mode = gym.vector.AutoresetMode.SAME_STEP
        if self.cfg.vector == "async" and self.cfg.num_envs > 1:
            return gym.vector.AsyncVectorEnv(fns, autoreset_mode=mode, context="fork")
        return gym.vector.SyncVectorEnv(fns, autoreset_mode=mode)

    def _normalize(self, obs: np.ndarray, update: bool = False) -> np.ndarray:
        return normalize_obs(self.normalizer, obs, update)

    def train(self) -> dict[str, float]:
        """Run until ``cfg.steps`` env steps; returns the final evaluation and throughput.

        Each vector step: the learner decides, the envs step (the learner updates meanwhile if it can), the learner
        observes and updates. At each point where the learner holds no pending data (after every PPO update; every
        step for SAC) the schedule runs: a ``train.csv`` row when the learner reports one, health checks,
        evaluation, checkpoint, progress."""
        cfg, learner, n = self.cfg, self.learner, self.cfg.num_envs
        env_steps_per_step = n * self.steps_per_decision
        vec = self._vector_env()
        space = self.eval_env.action_space
        ep_return, ep_true = np.zeros(n), np.zeros(n)
        recent_returns: list[float] = []
        recent_true: list[float] = []
        faults = np.zeros((n, len(self.skill_names)))  # lifetime faults and calls of each env's skills
        calls = np.zeros((n, len(self.skill_names)))
        skipped_in_a_row, decisions = 0, 0
        committed = (self.global_step, self.episodes)  # the state at the last point with nothing pending
        self._start = time.perf_counter()
        next_eval = (self.global_step // cfg.eval_every + 1) * cfg.eval_every
        next_ckpt = (self.global_step // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        bar = _progress(cfg.steps, self.global_step, cfg.progress, f"{cfg.algo}-{cfg.dist} {cfg.task}")
        sample_every = cfg.logger.train_sample_every
        last_eval = float("nan")
        row_start, row_step, update_seconds = time.perf_counter(), self.global_step, 0.0
        previous_sigterm = signal.signal(signal.SIGTERM, _interrupt)  # `kill` saves a checkpoint, as Ctrl-C does
        try:
            # Training envs: seed + i on the first reset of this (or a resumed) run, continuing their own RNG after.
            obs, _ = vec.reset(seed=[cfg.seed * 1_000 + self.update * n + i for i in range(n)])
            if self.global_step == 0:
                last_eval = self.evaluate()
            while self.global_step < cfg.steps or not learner.at_boundary:  # PPO finishes its last rollout
                nobs = self._normalize(obs, update=True)
                u, distribution = learner.act(nobs)
                env_action = to_env_action(u, space, cfg.dist)
                if self.recorder is not None and sample_every and decisions % (sample_every * n) == 0:
                    alpha, beta = _beta_parameters(distribution)
                    self.recorder.sample(self.global_step, env_action[0], alpha, beta)
                decisions += n
                work = learner.update if learner.update_while_stepping else _no_update
                (obs, reward, terminated, truncated, info), (stats, seconds) = _step_while(vec, env_action, work)
                update_seconds += seconds
                done = terminated | truncated
                ep_return += reward
                ep_true += _true_rewards(info, reward, done)
                if "skill_faults" in info:
                    mask = info.get("_skill_faults", np.ones(n, bool))
                    faults[mask], calls[mask] = info["skill_faults"][mask], info["skill_calls"][mask]
                for i in np.flatnonzero(done):
                    recent_returns.append(float(ep_return[i]))
                    recent_true.append(float(ep_true[i]))
                    self.episodes += 1
                    ep_return[i], ep_true[i] = 0.0, 0.0
                next_obs = obs
                if done.any():  # the true successor of an ended episode is its final observation
                    next_obs = obs.copy()
                    for i in np.flatnonzero(done):
                        next_obs[i] = info["final_obs"][i]
                learner.observe(Step(nobs, u, reward, self._normalize(next_obs), terminated, truncated))
                self.global_step += env_steps_per_step
                if not learner.update_while_stepping:
                    stats, seconds = _timed(learner.update)
                    update_seconds += seconds
                if not learner.at_boundary:
                    continue
                committed = (self.global_step, self.episodes)
                if stats:  # a train.csv row is due
                    elapsed = time.perf_counter() - row_start
                    done_steps = self.global_step - row_step
                    train_return = float(np.mean(recent_returns)) if recent_returns else float("nan")
                    true_return = float(np.mean(recent_true)) if recent_true else float("nan")
                    recent_returns.clear()
                    recent_true.clear()
                    stats.update({"episodes": self.episodes, "train/episode_reward": train_return,
                                  "train/true_episode_reward": true_return,
                                  "charts/SPS": done_steps / elapsed, "charts/update_seconds": update_seconds,
                                  "charts/rollout_SPS": done_steps / max(elapsed - update_seconds, 1e-9)})  # fmt: skip
                    stats.update({f"faults/{s}": float(faults[:, k].sum()) for k, s in enumerate(self.skill_names)})
                    self.update += 1
                    self._write("train", stats)
                    all_skipped = stats.get("losses/skipped", 0) == stats.get("losses/minibatches", -1)
                    skipped_in_a_row = skipped_in_a_row + 1 if all_skipped else 0
                    row_start, row_step, update_seconds = time.perf_counter(), self.global_step, 0.0
                    if bar is not None:
                        bar.set_postfix(train_return=f"{train_return:.0f}", eval=f"{last_eval:.0f}",
                                        SPS=f"{done_steps / elapsed:.0f}")  # fmt: skip
                self._check_health(faults.sum(0), calls.sum(0), skipped_in_a_row)
                finished = self.global_step >= cfg.steps
                if self.global_step >= next_eval or finished:
                    last_eval = self.evaluate(last=finished)
                    next_eval = (self.global_step // cfg.eval_every + 1) * cfg.eval_every
                if self.global_step >= next_ckpt or finished:
                    self.save()
                    next_ckpt = (self.global_step // cfg.checkpoint_every + 1) * cfg.checkpoint_every
                if bar is not None:
                    bar.update(self.global_step - bar.n)
        except KeyboardInterrupt:
            # Save the state at the last point with nothing pending: an interrupted PPO rollout is redone on resume,
            # so the resumed run ends on the same step count as an uninterrupted one.
            self.global_step, self.episodes = committed
            log.warning("interrupted: saving a checkpoint at step %d", self.global_step)
            self.save()
            raise
        finally:
            signal.signal(signal.SIGTERM, previous_sigterm)
            if bar is not None:
                bar.close()
            vec.close()
            for sink in self.sinks:
                sink.close()
        wall = time.perf_counter() - self._start
        return {"final_eval": last_eval, "best_eval": float(self.best_eval), "steps": self.global_step,
                "wall_seconds": wall}  # fmt: skip


def _true_rewards(info: Mapping[str, Any], reward: np.ndarray, done: np.ndarray) -> np.ndarray:
    """Each env's unshaped reward of the step: ``info["true_reward"]`` (an ended episode's in ``final_info``) where
    the task reports it, else the reward itself."""
    true = np.asarray(reward, np.float64).copy()
    for source, rows in ((info, ~done), (info.get("final_info", {}), done)):
        if "true_reward" in source:
            mask = rows & source.get("_true_reward", np.ones_like(done))
            true[mask] = source["true_reward"][mask]
    return true


def _timed(work: Callable[[], Any]) -> tuple[Any, float]:
    """``work()`` and the seconds it took."""
    tic = time.perf_counter()
    return work(), time.perf_counter() - tic


def _no_update() -> None:
    return None


def _step_while(vec: gym.vector.VectorEnv, action: np.ndarray, work: Callable[[], Any]) -> tuple[tuple, tuple]:
    """Step ``vec`` with ``action`` and run ``work()`` meanwhile when the envs step in worker processes. Returns the
    step's results and ``(work(), its seconds)``."""
    if isinstance(vec, gym.vector.AsyncVectorEnv):
        vec.step_async(action)
        done = _timed(work)
        return vec.step_wait(), done
    done = _timed(work)
    return vec.step(action), done


def _numpy_rng_state() -> dict[str, Any]:
    """numpy's legacy global generator, whole (key, position, cached Gaussian), as tensors and plain numbers."""
    name, key, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    return {"key": torch.from_numpy(key.astype(np.int64)), "pos": int(pos), "has_gauss": int(has_gauss),
            "gauss": float(gauss)}  # fmt: skip


def _set_numpy_rng_state(state: Any) -> None:
    if isinstance(state, torch.Tensor):  # older checkpoints saved the key alone
        state = {"key": state, "pos": 624, "has_gauss": 0, "gauss": 0.0}
    key = state["key"].numpy().astype(np.uint32)
    np.random.set_state(("MT19937", key, state["pos"], state["has_gauss"], state["gauss"]))  # noqa: NPY002


def _python_rng_state() -> dict[str, Any]:
    """Python's ``random`` state as plain containers (``weights_only`` loads them)."""
    version, internal, gauss_next = random.getstate()
    return {"version": int(version), "internal": list(internal), "gauss_next": gauss_next}


def _set_python_rng_state(state: Any) -> None:
    if not isinstance(state, dict):  # older checkpoints saved the internal state alone, without its version
        state = {"version": 3, "internal": list(state), "gauss_next": None}
    random.setstate((state["version"], tuple(int(x) for x in state["internal"]), state["gauss_next"]))


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _plain(value: Any) -> Any:
    """``value`` as nested dicts, lists and scalars (what a ``weights_only`` checkpoint may hold)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _progress(total: int, initial: int, enabled: bool, desc: str) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="step", dynamic_ncols=True, smoothing=0.1)
