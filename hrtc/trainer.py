"""The training loop: rollouts in vector environments, PPO updates, evaluation with the Beta mean, checkpoints.

HRTC and plain PPO share every line here. For HRTC the environment is a :class:`~hrtc.composition.ComposedEnv`
(its action is the skill-weight vector); for PPO it is the raw task. A sample ``u`` of the policy's distribution
becomes the environment's action by :func:`to_env_action`.
"""

from __future__ import annotations

import functools
import logging
import random
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from hrtc.checkpoint import load_checkpoint, save_checkpoint
from hrtc.composition import BLEND_MODES, ComposedEnv, build_library
from hrtc.errors import CheckpointError, ConfigError, UnknownNameError
from hrtc.logging import CsvSink, Sink
from hrtc.normalize import ObsNormalizer, RewardScaler
from hrtc.policy import ActorCritic
from hrtc.ppo import Batch, PPOConfig, compute_gae, ppo_update

log = logging.getLogger(__name__)

ROOT_CONF = Path(__file__).resolve().parent / "conf"  # the Hydra configs shipped with the package

ALGOS = ("hrtc", "ppo")
DISTS = ("beta", "normal")
TRAIN_COLUMNS = (
    "episodes", "train/episode_reward", "losses/policy_loss", "losses/value_loss", "losses/entropy",
    "losses/approx_kl", "losses/clipfrac", "losses/explained_variance", "losses/skipped", "charts/learning_rate",
    "charts/SPS", "charts/rollout_SPS", "charts/update_seconds",
)  # fmt: skip
EVAL_COLUMNS = ("episode_reward", "episode_reward_std", "episodes", "train_episodes", "wall_seconds")


@dataclass(frozen=True)
class RunConfig:
    """Everything one training run needs, validated. Built from the Hydra config by :meth:`from_mapping`."""

    task: str
    skills: Mapping[str, Any]
    algo: str = "hrtc"
    dist: str = "beta"
    beta_init_bias: float = 0.0
    action_filter: str = "sum"
    decision_every: int = 1
    seed: int = 1
    steps: int = 100_000
    num_envs: int = 2
    vector: str = "async"
    hidden: tuple[int, ...] = (64, 64)
    eval_every: int = 5_000
    eval_episodes: int = 3
    checkpoint_every: int = 10_000
    torch_threads: int = 1
    progress: bool = True
    solve_threshold: float | None = None
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    ppo: PPOConfig = field(default_factory=PPOConfig)

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise UnknownNameError("algo", self.algo, ALGOS)
        if self.dist not in DISTS:
            raise UnknownNameError("dist", self.dist, DISTS)
        if self.action_filter not in BLEND_MODES:
            raise UnknownNameError("action filter mode", self.action_filter, BLEND_MODES)
        if self.vector not in ("async", "sync"):
            raise UnknownNameError("vector mode", self.vector, ("async", "sync"))
        positive = {"steps": self.steps, "num_envs": self.num_envs, "eval_every": self.eval_every,
                    "eval_episodes": self.eval_episodes, "checkpoint_every": self.checkpoint_every,
                    "ppo.num_steps": self.ppo.num_steps, "ppo.update_epochs": self.ppo.update_epochs,
                    "ppo.num_minibatches": self.ppo.num_minibatches, "torch_threads": self.torch_threads,
                    "algo.decision_every": self.decision_every}  # fmt: skip
        for name, value in positive.items():
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
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

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> RunConfig:
        """Build from the resolved config tree (plain dicts): ``task``, ``algo``, ``dist``, ``ppo``, top-level keys."""
        cfg = dict(cfg)
        task, algo, dist = dict(cfg.pop("task")), dict(cfg.pop("algo")), dict(cfg.pop("dist"))
        ppo_cfg = dict(cfg.pop("ppo", {}) or {})
        ppo_names = {f.name for f in fields(PPOConfig)}
        unknown = set(ppo_cfg) - ppo_names
        if unknown:
            raise ConfigError(f"unknown ppo keys {sorted(unknown)}; valid: {sorted(ppo_names)}")
        top = {f.name for f in fields(cls)} - {"task", "skills", "algo", "dist", "action_filter", "ppo",
                                                "solve_threshold", "env_kwargs"}  # fmt: skip
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
            ppo=PPOConfig(**ppo_cfg),
            **kwargs,
        )


# --------------------------------------------------------------------------------------------------- environments
def make_env(task: str, algo: str, skills: Mapping[str, Any], action_filter: str = "sum",
             env_kwargs: Mapping[str, Any] | None = None, decision_every: int = 1) -> gym.Env:  # fmt: skip
    """The environment the policy acts in: the task itself (``ppo``) or the task composed with its skills (``hrtc``)."""
    import envs

    env = envs.make(task, **dict(env_kwargs or {}))
    if algo == "hrtc":
        env = ComposedEnv(env, build_library(skills), action_filter, decision_every)  # type: ignore[arg-type]
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
    return ActorCritic(obs_dim, int(space.shape[0]), cfg.dist, cfg.hidden, centre, log_std, cfg.beta_init_bias)


def normalize_obs(normalizer: ObsNormalizer | None, obs: np.ndarray, update: bool = False) -> np.ndarray:
    """``obs`` (batch, obs_dim) as the policy sees it: normalised when the run normalises, float32 always."""
    return normalizer(obs, update) if normalizer is not None else obs.astype(np.float32)


# --------------------------------------------------------------------------------------------------- evaluation
@torch.no_grad()
def evaluate(
    policy: ActorCritic,
    normalizer: ObsNormalizer | None,
    env: gym.Env,
    seeds: Sequence[int],
    dist: str,
    on_step: Callable[[int, int, np.ndarray, dict], None] | None = None,
) -> np.ndarray:
    """Returns of one deterministic episode per seed (the distribution's mode: the Beta mean for HRTC)."""
    returns = []
    for episode, seed in enumerate(seeds):
        obs, _ = env.reset(seed=int(seed))
        total, done, t = 0.0, False, 0
        while not done:
            u = policy.distribution(torch.as_tensor(normalize_obs(normalizer, obs[None]))).mode().numpy()[0]
            obs, reward, terminated, truncated, info = env.step(to_env_action(u, env.action_space, dist))
            total += float(reward)
            done = terminated or truncated
            if on_step is not None:
                on_step(episode, t, u, info)
            t += 1
        returns.append(total)
    return np.asarray(returns)


def eval_seeds(seed: int, episodes: int) -> list[int]:
    """Evaluation episode seeds: the same at every evaluation, and disjoint from the training envs' reset seeds
    (``1000 * seed + ...``, below a million for any seed under 1000)."""
    return [1_000_000 + 1_000 * seed + k for k in range(episodes)]


# --------------------------------------------------------------------------------------------------- training
class Trainer:
    """One training run writing into ``run_dir``: ``train.csv``, ``eval.csv``, ``checkpoints/``.

    ``sinks`` receive the same rows as the CSVs (e.g. a Rerun recording); ``resume`` continues from
    ``checkpoints/last.pt``.
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
        self.policy = policy_for(cfg, obs_dim, space)
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=cfg.ppo.learning_rate, eps=1e-5)
        self.normalizer = ObsNormalizer((obs_dim,)) if cfg.ppo.normalize_obs else None
        # One decision spans decision_every env steps: discount per decision accordingly.
        self.steps_per_decision = cfg.decision_every if cfg.algo == "hrtc" else 1
        self.gamma = cfg.ppo.gamma**self.steps_per_decision
        self.reward_scaler = RewardScaler(cfg.num_envs, self.gamma) if cfg.ppo.scale_reward else None
        self.global_step, self.update, self.episodes = 0, 0, 0
        self.best_eval = -np.inf
        self.wall_offset = 0.0  # wall time of the run before a resume, s
        self._start = time.perf_counter()  # reset when train() starts
        if resume:
            self._restore(self.ckpt_dir / "last.pt")
        self.sinks: list[Sink] = [CsvSink(self.run_dir, {"train": TRAIN_COLUMNS, "eval": EVAL_COLUMNS}, resume), *sinks]

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "policy": self.policy.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_rms": self.normalizer.rms.state_dict() if self.normalizer else {},
            "reward_rms": self.reward_scaler.rms.state_dict() if self.reward_scaler else {},
            "global_step": self.global_step,
            "update": self.update,
            "episodes": self.episodes,
            "best_eval": float(self.best_eval),
            "wall_seconds": self.wall_offset + time.perf_counter() - self._start,
            "rng": {
                "torch": torch.get_rng_state(),
                "generator": self.generator.get_state(),
                "numpy": torch.from_numpy(np.random.get_state()[1].astype(np.int64)),  # noqa: NPY002
                "python": list(random.getstate()[1]),
            },
            "meta": {
                "task": self.cfg.task,
                "algo": self.cfg.algo,
                "dist": self.cfg.dist,
                "skills": list(self.skill_names),
                "obs_dim": self.policy.obs_dim,
                "out_dim": self.policy.out_dim,
                "hidden": list(self.cfg.hidden),
                "action_filter": self.cfg.action_filter,
                # Enough to rebuild this policy as a skill of another task (skills.learned): plain containers only.
                "skills_cfg": _plain(self.cfg.skills),
                "env_kwargs": _plain(self.cfg.env_kwargs),
                "decision_every": self.steps_per_decision,
                "action_low": self.eval_env.action_space.low.tolist(),
                "action_high": self.eval_env.action_space.high.tolist(),
            },
        }

    def save(self, name: str = "last.pt") -> Path:
        return save_checkpoint(self.ckpt_dir / name, self.state_dict())

    def _restore(self, path: Path) -> None:
        state = load_checkpoint(path)
        meta = state["meta"]
        mine = self.state_dict()["meta"]
        if meta["skills"] != mine["skills"] or meta["obs_dim"] != mine["obs_dim"] or meta["out_dim"] != mine["out_dim"]:
            raise CheckpointError(
                f"{path} was trained with skills {meta['skills']} (obs {meta['obs_dim']}, out {meta['out_dim']}); "
                f"this run has {mine['skills']} (obs {mine['obs_dim']}, out {mine['out_dim']})"
            )
        self.policy.load_state_dict(state["policy"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.normalizer and state["obs_rms"]:
            self.normalizer.rms.load_state_dict(state["obs_rms"])
        if self.reward_scaler and state.get("reward_rms"):
            self.reward_scaler.rms.load_state_dict(state["reward_rms"])
        self.global_step, self.update = int(state["global_step"]), int(state["update"])
        self.episodes, self.best_eval = int(state["episodes"]), float(state["best_eval"])
        self.wall_offset = float(state.get("wall_seconds", 0.0))
        rng = state["rng"]
        torch.set_rng_state(rng["torch"])
        self.generator.set_state(rng["generator"])
        np.random.set_state(("MT19937", rng["numpy"].numpy().astype(np.uint32), 624, 0, 0.0))  # noqa: NPY002
        log.info("resumed from %s at step %d", path, self.global_step)

    # ------------------------------------------------------------------ evaluation
    def evaluate(self) -> float:
        returns = evaluate(self.policy, self.normalizer, self.eval_env,
                           eval_seeds(self.cfg.seed, self.cfg.eval_episodes), self.cfg.dist)  # fmt: skip
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
        """Run until ``cfg.steps`` env steps; returns the final evaluation and throughput."""
        cfg, ppo = self.cfg, self.cfg.ppo
        n, t_len = cfg.num_envs, ppo.num_steps
        batch_size = n * t_len
        env_steps_per_update = batch_size * self.steps_per_decision
        num_updates = -(-cfg.steps // env_steps_per_update)
        vec = self._vector_env()
        space = self.eval_env.action_space
        obs_dim = self.policy.obs_dim
        buf_obs = np.zeros((t_len, n, obs_dim), np.float32)
        buf_u = np.zeros((t_len, n, self.policy.out_dim), np.float32)
        buf_logp, buf_rew, buf_done, buf_val = (np.zeros((t_len, n), np.float32) for _ in range(4))
        ep_return = np.zeros(n)
        recent_returns: list[float] = []
        self._start = time.perf_counter()
        next_eval = (self.global_step // cfg.eval_every + 1) * cfg.eval_every
        next_ckpt = (self.global_step // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        bar = _progress(cfg.steps, self.global_step, cfg.progress, f"{cfg.algo}-{cfg.dist} {cfg.task}")
        last_eval = float("nan")
        try:
            # Training envs: seed + i on the first reset of this (or a resumed) run, continuing their own RNG after.
            obs, _ = vec.reset(seed=[cfg.seed * 1_000 + self.update * n + i for i in range(n)])
            if self.global_step == 0:
                last_eval = self.evaluate()
            while self.update < num_updates:
                tic = time.perf_counter()
                if ppo.anneal_lr:
                    frac = 1.0 - self.update / num_updates
                    self.optimizer.param_groups[0]["lr"] = frac * ppo.learning_rate
                for t in range(t_len):
                    nobs = self._normalize(obs, update=True)
                    with torch.no_grad():
                        tobs = torch.as_tensor(nobs)
                        dist = self.policy.distribution(tobs)
                        u = dist.sample()
                        buf_logp[t] = dist.log_prob(u).numpy()
                        buf_val[t] = self.policy.value(tobs).numpy()
                    u_np = u.numpy()
                    buf_obs[t], buf_u[t] = nobs, u_np
                    obs, reward, terminated, truncated, info = vec.step(to_env_action(u_np, space, cfg.dist))
                    done = terminated | truncated
                    ep_return += reward
                    for i in np.flatnonzero(done):
                        recent_returns.append(float(ep_return[i]))
                        self.episodes += 1
                        ep_return[i] = 0.0
                    scaled = self.reward_scaler(reward, done) if self.reward_scaler else reward.astype(np.float64)
                    if truncated.any():  # bootstrap the time limit: it is not a terminal state
                        idx = np.flatnonzero(truncated)
                        final = np.stack([info["final_obs"][i] for i in idx])
                        with torch.no_grad():
                            v_final = self.policy.value(torch.as_tensor(self._normalize(final))).numpy()
                        scaled[idx] += self.gamma * v_final
                    buf_rew[t], buf_done[t] = scaled, done
                    self.global_step += n * self.steps_per_decision
                rollout_seconds = time.perf_counter() - tic
                with torch.no_grad():
                    next_value = self.policy.value(torch.as_tensor(self._normalize(obs))).numpy()
                adv, ret = compute_gae(buf_rew, buf_val, buf_done, next_value, self.gamma, ppo.gae_lambda)
                batch = Batch(
                    torch.as_tensor(buf_obs.reshape(batch_size, obs_dim)),
                    torch.as_tensor(buf_u.reshape(batch_size, -1)),
                    torch.as_tensor(buf_logp.reshape(-1)),
                    torch.as_tensor(adv.reshape(-1), dtype=torch.float32),
                    torch.as_tensor(ret.reshape(-1), dtype=torch.float32),
                    torch.as_tensor(buf_val.reshape(-1)),
                )
                tu = time.perf_counter()
                stats = ppo_update(self.policy, self.optimizer, batch, ppo, self.generator)
                self.update += 1
                elapsed = time.perf_counter() - tic
                train_return = float(np.mean(recent_returns)) if recent_returns else float("nan")
                recent_returns.clear()
                stats.update({
                    "episodes": self.episodes,
                    "train/episode_reward": train_return,
                    "charts/learning_rate": self.optimizer.param_groups[0]["lr"],
                    "charts/SPS": env_steps_per_update / elapsed,
                    "charts/update_seconds": time.perf_counter() - tu,
                    "charts/rollout_SPS": env_steps_per_update / rollout_seconds,
                })  # fmt: skip
                self._write("train", stats)
                if self.global_step >= next_eval or self.update == num_updates:
                    last_eval = self.evaluate()
                    next_eval = (self.global_step // cfg.eval_every + 1) * cfg.eval_every
                if self.global_step >= next_ckpt or self.update == num_updates:
                    self.save()
                    next_ckpt = (self.global_step // cfg.checkpoint_every + 1) * cfg.checkpoint_every
                if bar is not None:
                    bar.update(env_steps_per_update)
                    bar.set_postfix(train_return=f"{train_return:.0f}", eval=f"{last_eval:.0f}",
                                    SPS=f"{env_steps_per_update / elapsed:.0f}")  # fmt: skip
        except KeyboardInterrupt:
            log.warning("interrupted: saving a checkpoint at step %d", self.global_step)
            self.save()
            raise
        finally:
            if bar is not None:
                bar.close()
            vec.close()
            for sink in self.sinks:
                sink.close()
        wall = time.perf_counter() - self._start
        return {"final_eval": last_eval, "best_eval": float(self.best_eval), "steps": self.global_step,
                "wall_seconds": wall}  # fmt: skip


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
