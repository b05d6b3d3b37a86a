"""The training loop: collect decisions in vector envs, hand them to the learner, let the callbacks act.

HRTC and plain PPO share every line here. For HRTC the environment is a :class:`~hrtc.composition.ComposedEnv`
(its action is the skill-weight vector); for PPO it is the raw task. A sample of the meta-policy's distribution
becomes the environment's action by :func:`~hrtc.policy.to_action`. How the meta-policy learns is the learner's
(:mod:`hrtc.learner`: PPO or SAC); everything else a run does (metrics, evaluation, checkpoints, health checks,
progress, signals, recording) is a callback (:mod:`hrtc.callbacks`).
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from hrtc.callbacks import (
    Callback,
    Checkpoints,
    Evaluation,
    HealthCheck,
    MetricsLog,
    Progress,
    SkillFaults,
    TerminateAsInterrupt,
    TrainingSamples,
    Transition,
    csv_columns,
)
from hrtc.checkpoint import load_checkpoint, load_policy_weights, plain, rng_state, save_checkpoint, set_rng_state
from hrtc.config import RunConfig
from hrtc.environments import env_factory, frame_source, no_update, step_while, timed, vector_env
from hrtc.errors import CheckpointError, WorkerError, interrupt_within
from hrtc.learner import Step, build_learner
from hrtc.logging import CsvSink, Sink
from hrtc.normalize import ObsNormalizer, RewardScaler, normalize_obs
from hrtc.policy import build_policy, start_at, to_action

log = logging.getLogger(__name__)


class Trainer:
    """One training run writing into ``run_dir``: ``train.csv``, ``eval.csv``, ``checkpoints/``.

    ``sinks`` receive the same rows as the CSVs; ``resume`` continues from ``checkpoints/last.pt``; ``callbacks``
    replaces the standard ones (:meth:`standard_callbacks`).
    """

    def __init__(self, cfg: RunConfig, run_dir: str | Path, sinks: Sequence[Sink] = (), resume: bool = False,
                 callbacks: Sequence[Callback] | None = None) -> None:  # fmt: skip
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
        self.policy = build_policy(obs_dim, space.low, space.high, cfg.dist, cfg.hidden, cfg.beta_init_bias,
                                   cfg.encoder, cfg.activation, cfg.weight_init, cfg.policy_device)  # fmt: skip
        self.steps_per_decision = cfg.steps_per_decision  # the learner discounts per decision accordingly
        self.learner = build_learner(cfg.learner, cfg.learner_settings, self.policy, cfg.num_envs, cfg.steps,
                                     self.steps_per_decision, self.generator, cfg.weight_margin)  # fmt: skip
        self.normalizer = ObsNormalizer((obs_dim,)) if cfg.learner_settings.normalize_obs else None
        self.global_step, self.update, self.episodes = 0, 0, 0
        self.best_eval, self.last_eval = -np.inf, float("nan")
        self.wall_offset = 0.0  # wall time of the run before a resume, s
        self._start = time.perf_counter()  # reset when train() starts
        if self.skill_names:  # the skills' first proposals: a wrong action size is an error now, not in a worker
            self.eval_env.reset(seed=cfg.seed)
        if cfg.init_from and not resume:  # fine-tune: start from a trained policy of the same shape
            load_policy_weights(self, cfg.init_from)
        if cfg.init_weights and not resume:  # start from a blend (e.g. a task's hand rule), not all weights at 0.5
            start_at(self.policy, cfg.init_weights, self.skill_names, cfg.weight_margin)
        if resume and not (self.ckpt_dir / "last.pt").exists():
            log.warning("resume: no checkpoint in %s yet; starting from scratch", self.ckpt_dir)
            resume = False
        if resume:
            self._restore(self.ckpt_dir / "last.pt")
        self.callbacks = list(callbacks) if callbacks is not None else self.standard_callbacks(sinks, resume)

    def standard_callbacks(self, sinks: Sequence[Sink] = (), resume: bool = False) -> list[Callback]:
        """In order: SIGTERM as Ctrl-C, the skills' fault counts, the metrics (to the CSVs, continued from the
        checkpoint's step on ``resume`` with the rows of the work a crash lost dropped; to ``sinks``; to a recording
        per ``cfg.logger``), the recording's training samples, a progress bar, health checks, evaluations, checkpoints.
        """
        cfg, env = self.cfg, self.eval_env
        columns = csv_columns(self.learner.columns, self.skill_names)
        sinks = [CsvSink(self.run_dir, columns, append=resume, keep_until=self.global_step if resume else None), *sinks]
        recorder, render = None, None
        if cfg.logger.mode != "off":
            from hrtc.logging.rerun_sink import RerunSink

            title = f"{cfg.task}: {cfg.algo}-{cfg.dist}"
            recorder = RerunSink.for_env(self.run_dir, cfg.logger, env, title, resume, cfg.eval_episodes, self.update)
            sinks.append(recorder)
            render = frame_source(env, cfg.logger.frame_size) if cfg.logger.frames else None
        faults = SkillFaults(self.skill_names, cfg.num_envs)
        metrics = MetricsLog(sinks, faults)
        callbacks: list[Callback] = [TerminateAsInterrupt(), faults, metrics]
        if recorder is not None and cfg.logger.train_sample_every:
            callbacks.append(TrainingSamples(recorder, cfg.logger.train_sample_every))
        if cfg.progress:
            callbacks.append(Progress(cfg.steps, f"{cfg.algo}-{cfg.dist} {cfg.task}"))
        return [*callbacks, HealthCheck(faults, cfg.max_skill_fault_rate, cfg.max_skipped_updates),
                Evaluation(self.policy, self.normalizer, env, cfg.dist, cfg.eval_every, cfg.eval_episodes, cfg.seed,
                           metrics.write, recorder, render),
                Checkpoints(cfg.checkpoint_every)]  # fmt: skip

    @property
    def reward_scaler(self) -> RewardScaler | None:
        """PPO's reward scaler (None for SAC or when PPO does not scale)."""
        return getattr(self.learner, "reward_scaler", None)

    @property
    def finished(self) -> bool:
        return self.global_step >= self.cfg.steps

    def wall_seconds(self) -> float:
        """The run's wall time so far (before a resume too), s."""
        return self.wall_offset + time.perf_counter() - self._start

    # ------------------------------------------------------------------ the loop
    def train(self) -> dict[str, float]:
        """Run until ``cfg.steps`` env steps (PPO finishes its last rollout); returns the final and best evaluation
        and the wall time. Callbacks act at every point where the learner holds nothing pending; an interrupted run
        is rewound to the last such point, so that its checkpoint redoes an interrupted PPO rollout on resume."""
        cfg, learner, n = self.cfg, self.learner, self.cfg.num_envs
        self.vec = vec = vector_env(env_factory(cfg), n, cfg.vector, cfg.max_worker_restarts)
        self._start, self.last_eval, self.ep_return = time.perf_counter(), float("nan"), np.zeros(n)
        committed, interrupted, stop = (self.global_step, self.episodes), False, False
        try:
            # Training envs: seed + i on the first reset of this (or a resumed) run, continuing their own RNG after.
            obs, _ = vec.reset(seed=[cfg.seed * 1_000 + self.update * n + i for i in range(n)])
            for callback in self.callbacks:
                callback.on_start(self)
            while not stop and (self.global_step < cfg.steps or not learner.at_boundary):
                obs, stats = self.collect(vec, obs)
                if not learner.at_boundary:
                    continue
                committed = (self.global_step, self.episodes)
                self.update += bool(stats)  # a train.csv row is due
                stop = any([bool(callback.on_update(self, stats)) for callback in self.callbacks])
        except KeyboardInterrupt:
            self.global_step, self.episodes = committed
            interrupted = True
            raise
        except WorkerError as error:  # workers died past max_worker_restarts: saved as on an interrupt, one line
            self.global_step, self.episodes = committed
            self.save()
            raise WorkerError(f"{error}; the run is saved at step {self.global_step}") from None
        except Exception as error:  # Ctrl-C or SIGTERM that a C extension turned into a SystemError is still one
            if (interrupt := interrupt_within(error)) is None:
                raise
            self.global_step, self.episodes = committed
            interrupted = True
            raise interrupt from error
        finally:
            try:
                for callback in reversed(self.callbacks):
                    callback.on_end(self, interrupted)
            finally:  # Ctrl-C reaches the env workers too: an interrupted run stops them rather than asking them
                vec.close(terminate=interrupted)
        return {"final_eval": self.last_eval, "best_eval": float(self.best_eval), "steps": self.global_step,
                "wall_seconds": time.perf_counter() - self._start}  # fmt: skip

    def collect(self, vec: gym.vector.VectorEnv, obs: np.ndarray) -> tuple[np.ndarray, dict[str, float] | None]:
        """One vector step: the learner decides, the envs step (the learner updates meanwhile if it can), the learner
        observes (and updates, if it did not meanwhile), the callbacks see it. Returns the next observations and the
        update's statistics (see :meth:`hrtc.learner.Learner.update`)."""
        learner, space = self.learner, self.eval_env.action_space
        nobs = normalize_obs(self.normalizer, obs, update=True)
        samples, distribution = learner.act(nobs)
        actions = to_action(samples, space.low, space.high, self.cfg.dist).astype(np.float32)
        work = learner.update if learner.update_while_stepping else no_update
        (obs, reward, terminated, truncated, info), (stats, seconds) = step_while(vec, actions, work)
        done = terminated | truncated
        self.ep_return += reward
        ended = tuple(float(self.ep_return[i]) for i in np.flatnonzero(done))
        self.ep_return[done] = 0.0
        self.episodes += len(ended)
        next_obs = obs
        if done.any():  # the true successor of an ended episode is its final observation
            next_obs = obs.copy()
            for i in np.flatnonzero(done):
                next_obs[i] = info["final_obs"][i]
        learner.observe(Step(nobs, samples, reward, normalize_obs(self.normalizer, next_obs), terminated, truncated))
        step, self.global_step = self.global_step, self.global_step + self.cfg.num_envs * self.steps_per_decision
        if not learner.update_while_stepping:
            stats, after = timed(learner.update)
            seconds += after
        transition = Transition(step, actions, distribution, reward, done, info, ended, seconds)
        for callback in self.callbacks:
            callback.on_step(self, transition)
        return obs, stats

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        cfg, space = self.cfg, self.eval_env.action_space
        # Enough to rebuild this policy as a skill of another task (skills.learned): plain containers only.
        meta = {"task": cfg.task, "algo": cfg.algo, "dist": cfg.dist, "learner": cfg.learner, "hidden": [*cfg.hidden],
                "skills": list(self.skill_names), "obs_dim": self.policy.obs_dim, "out_dim": self.policy.out_dim,
                "activation": cfg.activation, "action_filter": cfg.action_filter, "skills_cfg": plain(cfg.skills),
                "env_kwargs": plain(cfg.env_kwargs), "decision_every": self.steps_per_decision,
                "action_low": space.low.tolist(), "action_high": space.high.tolist(),
                "encoder": plain(cfg.encoder), "weight_margin": cfg.weight_margin}  # fmt: skip
        return {
            "policy": self.policy.state_dict(),
            "optimizer": self.learner.state_dict(),  # the learner's whole training state (optimisers, buffers...)
            "obs_rms": self.normalizer.rms.state_dict() if self.normalizer else {},
            "global_step": self.global_step,
            "update": self.update,
            "episodes": self.episodes,
            "best_eval": float(self.best_eval),
            "wall_seconds": self.wall_seconds(),
            "rng": rng_state(self.generator),
            "meta": meta,
        }

    def save(self, name: str = "last.pt") -> Path:
        state = self.state_dict()
        if name != "last.pt":  # only last.pt resumes: others keep the policy, not the learner's buffers
            state["optimizer"] = {}
        return save_checkpoint(self.ckpt_dir / name, state)

    def _restore(self, path: Path) -> None:
        state = load_checkpoint(path)
        meta, mine = state["meta"], self.state_dict()["meta"]
        if any(meta.get(k, "ppo" if k == "learner" else None) != mine[k] for k in ("skills", "obs_dim", "out_dim",
                                                                                   "learner")):  # fmt: skip
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
        set_rng_state(state["rng"], self.generator)
        log.info("resumed from %s at step %d", path, self.global_step)
