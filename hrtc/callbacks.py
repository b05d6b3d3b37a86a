"""What a training run does besides collecting and learning: small callbacks, each testable and replaceable alone.

The trainer (:class:`hrtc.trainer.Trainer`) calls every callback at four points:

- ``on_start(run)`` once, after the vector envs are reset;
- ``on_step(run, step)`` after every vector step (a :class:`Transition`);
- ``on_update(run, stats)`` at every point where the learner holds nothing pending (after each PPO update, after
  every step for SAC): ``stats`` is the learner's ``train.csv`` row when one is due, else None or empty. A callback
  returning True stops the run there (as if its step budget were spent);
- ``on_end(run, interrupted)`` once, in reverse order, however the run ends (``interrupted``: Ctrl-C or SIGTERM,
  after the trainer rewound its counters to the last point with nothing pending).

``run`` is the trainer as a :class:`Run`: its counters, its evaluation results, its vector env and ``save``. Each
callback gets its own piece of the config when it is built.
"""

from __future__ import annotations

import logging
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from hrtc.episodes import beta_parameters, eval_seeds, evaluate_episodes
from hrtc.errors import HRTCError, SkillError
from hrtc.logging import Sink
from hrtc.logging.trace import Recorder

log = logging.getLogger(__name__)


class Transition(NamedTuple):
    """One vector step of N envs as the callbacks see it."""

    global_step: int  # env steps before this step
    actions: np.ndarray  # (N, A) what the envs were sent (the skill weights for HRTC)
    distribution: Any  # the meta-policy's distribution the actions were sampled from
    rewards: np.ndarray  # (N,) summed over the decision's env steps
    done: np.ndarray  # (N,) an episode ended (terminated or truncated)
    info: Mapping[str, Any]  # the vector env's info
    episode_returns: tuple[float, ...]  # the returns of the episodes that ended with this step
    update_seconds: float  # time the learner spent updating during and after this step, s


class Run(Protocol):
    """What callbacks read and set of the trainer."""

    global_step: int
    episodes: int
    best_eval: float
    last_eval: float
    vec: Any  # the training vector env while the run trains (its ``restarts``: hrtc.vector.RestartingVectorEnv)

    @property
    def finished(self) -> bool: ...
    def wall_seconds(self) -> float: ...
    def save(self, name: str = "last.pt") -> Path: ...


class Callback(Protocol):
    def on_start(self, run: Run) -> None: ...
    def on_step(self, run: Run, step: Transition) -> None: ...
    def on_update(self, run: Run, stats: dict[str, float] | None) -> bool | None: ...
    def on_end(self, run: Run, interrupted: bool) -> None: ...


class BaseCallback:
    """A callback that does nothing at every point: subclasses override what they need."""

    def on_start(self, run: Run) -> None:
        return None

    def on_step(self, run: Run, step: Transition) -> None:
        return None

    def on_update(self, run: Run, stats: dict[str, float] | None) -> bool | None:
        return None

    def on_end(self, run: Run, interrupted: bool) -> None:
        return None


def next_multiple(step: int, every: int) -> int:
    """The first multiple of ``every`` after ``step``."""
    return (step // every + 1) * every


# --------------------------------------------------------------------------------------------------- skill faults
class SkillFaults(BaseCallback):
    """Lifetime faults and calls of each skill, summed over the training envs (read from the composed envs' info).
    A replaced vector-env worker's skills count from zero (``info["worker_restarted"]``): the dead one's stay in the
    totals."""

    def __init__(self, skill_names: Sequence[str], num_envs: int) -> None:
        self.skill_names = tuple(skill_names)
        self.faults = np.zeros((num_envs, len(self.skill_names)))
        self.calls = np.zeros((num_envs, len(self.skill_names)))
        self.lost_faults, self.lost_calls = np.zeros_like(self.faults), np.zeros_like(self.calls)  # of dead workers

    def on_step(self, run: Run, step: Transition) -> None:
        info = step.info
        if "worker_restarted" in info:
            lost = info["_worker_restarted"]
            self.lost_faults[lost] += self.faults[lost]
            self.lost_calls[lost] += self.calls[lost]
            self.faults[lost], self.calls[lost] = 0.0, 0.0
        if "skill_faults" in info:
            mask = info.get("_skill_faults", np.ones(len(self.faults), bool))
            self.faults[mask], self.calls[mask] = info["skill_faults"][mask], info["skill_calls"][mask]

    def totals(self) -> tuple[np.ndarray, np.ndarray]:
        """(faults, calls) per skill, (K,) each."""
        return (self.faults + self.lost_faults).sum(0), (self.calls + self.lost_calls).sum(0)


# --------------------------------------------------------------------------------------------------- metrics
# train.csv: these, with the learner's own columns after the first three, then each skill's fault count and the
# vector-env worker restarts.
# train/true_episode_reward: the task's own return where the env shapes its reward (info["true_reward"]).
TRAIN_COLUMNS = ("episodes", "train/episode_reward", "train/true_episode_reward", "charts/SPS", "charts/rollout_SPS",
                 "charts/update_seconds")  # fmt: skip
# true_episode_reward: the evaluation episodes' mean of the task's own return (the same as episode_reward where the
# env does not shape its reward).
EVAL_COLUMNS = ("episode_reward", "episode_reward_std", "episodes", "train_episodes", "wall_seconds",
                "true_episode_reward")  # fmt: skip


def csv_columns(learner_columns: Sequence[str], skill_names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """The columns of ``train.csv`` and ``eval.csv`` (after ``step``) that :class:`MetricsLog` fills."""
    faults = (*(f"faults/{name}" for name in skill_names), "faults/worker_restarts")
    return {"train": (*TRAIN_COLUMNS[:3], *learner_columns, *TRAIN_COLUMNS[3:], *faults), "eval": EVAL_COLUMNS}


class MetricsLog(BaseCallback):
    """Rows of metrics to the sinks (``train.csv``, ``eval.csv``, a recording...): the learner's ``train.csv`` rows
    with the episodes, the mean return of the episodes ended since the last row (and their mean true return, where the
    task shapes its reward: :func:`true_rewards`), the throughput, the update time,
    each skill's faults (from ``faults``) and the vector env's worker restarts (``run.vec.restarts``) added.
    :meth:`write` takes any other stream's rows. Closes the sinks."""

    def __init__(self, sinks: Sequence[Sink], faults: SkillFaults | None = None) -> None:
        self.sinks, self.faults = list(sinks), faults
        self.returns: list[float] = []
        self.true_returns: list[float] = []  # the same episodes' unshaped returns
        self.ep_true = np.zeros(0)  # each training env's unshaped return so far
        self.row_start, self.row_step, self.update_seconds = time.perf_counter(), 0, 0.0

    def write(self, stream: str, step: int, metrics: Mapping[str, float]) -> None:
        for sink in self.sinks:
            sink.write(stream, step, metrics)

    def on_start(self, run: Run) -> None:
        self.row_start, self.row_step, self.update_seconds = time.perf_counter(), run.global_step, 0.0
        self.ep_true = np.zeros(0)  # a (resumed) run's envs start new episodes

    def on_step(self, run: Run, step: Transition) -> None:
        self.returns.extend(step.episode_returns)
        self.update_seconds += step.update_seconds
        if len(self.ep_true) != len(step.rewards):
            self.ep_true = np.zeros(len(step.rewards))
        self.ep_true += true_rewards(step.info, step.rewards, step.done)
        self.true_returns.extend(float(r) for r in self.ep_true[step.done])
        self.ep_true[step.done] = 0.0

    def on_update(self, run: Run, stats: dict[str, float] | None) -> None:
        if not stats:  # no row due
            return
        elapsed = time.perf_counter() - self.row_start
        done_steps = run.global_step - self.row_step
        stats.update({"episodes": run.episodes,
                      "train/episode_reward": _mean(self.returns),
                      "train/true_episode_reward": _mean(self.true_returns),
                      "charts/SPS": done_steps / elapsed, "charts/update_seconds": self.update_seconds,
                      "charts/rollout_SPS": done_steps / max(elapsed - self.update_seconds, 1e-9)})  # fmt: skip
        if self.faults is not None:
            faults, _ = self.faults.totals()
            stats.update({f"faults/{s}": float(f) for s, f in zip(self.faults.skill_names, faults, strict=True)})
        stats["faults/worker_restarts"] = float(getattr(getattr(run, "vec", None), "restarts", 0))
        self.write("train", run.global_step, stats)
        self.returns.clear()
        self.true_returns.clear()
        self.row_start, self.row_step, self.update_seconds = time.perf_counter(), run.global_step, 0.0

    def on_end(self, run: Run, interrupted: bool) -> None:
        for sink in self.sinks:
            sink.close()


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def true_rewards(info: Mapping[str, Any], reward: np.ndarray, done: np.ndarray) -> np.ndarray:
    """Each env's unshaped reward of the step: ``info["true_reward"]`` (an ended episode's in ``final_info``) where
    the task reports it, else the reward itself."""
    true = np.asarray(reward, np.float64).copy()
    for source, rows in ((info, ~done), (info.get("final_info", {}), done)):
        if "true_reward" in source:
            mask = rows & source.get("_true_reward", np.ones_like(done))
            true[mask] = source["true_reward"][mask]
    return true


# --------------------------------------------------------------------------------------------------- health
class HealthCheck(BaseCallback):
    """Stops the run (saving it first) when a skill faults in more than ``max_fault_rate`` of its calls (once it has
    been called 200 times), or (keeping the last checkpoint) when the learner's loss was not finite in
    ``max_skipped_updates`` updates in a row; raises :class:`SkillError` or :class:`HRTCError` saying which."""

    def __init__(self, faults: SkillFaults, max_fault_rate: float, max_skipped_updates: int) -> None:
        self.faults, self.max_fault_rate, self.max_skipped_updates = faults, max_fault_rate, max_skipped_updates
        self.skipped_in_a_row = 0

    def on_update(self, run: Run, stats: dict[str, float] | None) -> None:
        if stats:
            all_skipped = stats.get("losses/skipped", 0) == stats.get("losses/minibatches", -1)
            self.skipped_in_a_row = self.skipped_in_a_row + 1 if all_skipped else 0
        for name, f, c in zip(self.faults.skill_names, *self.faults.totals(), strict=True):
            if c >= 200 and f / c > self.max_fault_rate:
                run.save()
                raise SkillError(f"skill {name!r} faulted in {f:.0f} of {c:.0f} calls ({f / c:.1%}, more than "
                                 f"max_skill_fault_rate {self.max_fault_rate:.1%}); the run is saved at "
                                 f"step {run.global_step}, see the warnings above for the faults")  # fmt: skip
        if self.skipped_in_a_row >= self.max_skipped_updates:
            raise HRTCError(f"the PPO loss was not finite in {self.skipped_in_a_row} updates in a row (every minibatch "
                            f"skipped); stopping at step {run.global_step}, last checkpoint kept")  # fmt: skip


# --------------------------------------------------------------------------------------------------- evaluation
class Evaluation(BaseCallback):
    """Deterministic episodes of the meta-policy (its distribution's mode) on ``env`` at step 0 (of a fresh run),
    every ``every`` env steps and at the end: ``episodes`` episodes on the seeds :func:`eval_seeds` gives for
    ``seed``, traced to ``recorder`` if any (with frames from ``render``). Each evaluation is an ``eval`` row through
    ``write``, sets ``run.last_eval`` and, when it beats ``run.best_eval``, saves ``best.pt``."""

    def __init__(self, policy: Any, normalizer: Any, env: Any, dist: str, every: int, episodes: int, seed: int,
                 write: Callable[[str, int, Mapping[str, float]], None], recorder: Recorder | None = None,
                 render: Callable[[], np.ndarray | None] | None = None) -> None:  # fmt: skip
        self.policy, self.normalizer, self.env, self.dist = policy, normalizer, env, dist
        self.every, self.seeds, self.write = every, eval_seeds(seed, episodes), write
        self.recorder, self.render = recorder, render
        self.next = every

    def on_start(self, run: Run) -> None:
        self.next = next_multiple(run.global_step, self.every)
        if run.global_step == 0:
            self.evaluate(run)

    def on_update(self, run: Run, stats: dict[str, float] | None) -> None:
        if run.global_step >= self.next or run.finished:
            self.evaluate(run, last=run.finished)
            self.next = next_multiple(run.global_step, self.every)

    def evaluate(self, run: Run, last: bool = False) -> float:
        if self.recorder is not None:
            self.recorder.start_evaluation(run.global_step, last)
        returns, true_returns = evaluate_episodes(self.policy, self.normalizer, self.env, self.seeds, self.dist,
                                                  self.recorder, self.render)  # fmt: skip
        mean = float(returns.mean())
        self.write("eval", run.global_step, {"episode_reward": mean, "episode_reward_std": float(returns.std()),
                                             "episodes": len(returns), "train_episodes": run.episodes,
                                             "wall_seconds": run.wall_seconds(),
                                             "true_episode_reward": float(true_returns.mean())})  # fmt: skip
        run.last_eval = mean
        if mean > run.best_eval:
            run.best_eval = mean
            run.save("best.pt")
        return mean


# --------------------------------------------------------------------------------------------------- checkpoints
class Checkpoints(BaseCallback):
    """``last.pt`` every ``every`` env steps, at the end, and when the run is interrupted (at the last point with
    nothing pending, so that the resumed run redoes an interrupted rollout and ends on the same step count)."""

    def __init__(self, every: int) -> None:
        self.every, self.next = every, every

    def on_start(self, run: Run) -> None:
        self.next = next_multiple(run.global_step, self.every)

    def on_update(self, run: Run, stats: dict[str, float] | None) -> None:
        if run.global_step >= self.next or run.finished:
            run.save()
            self.next = next_multiple(run.global_step, self.every)

    def on_end(self, run: Run, interrupted: bool) -> None:
        if interrupted:
            log.warning("interrupted: saving a checkpoint at step %d", run.global_step)
            run.save()


# --------------------------------------------------------------------------------------------------- progress
class Progress(BaseCallback):
    """A progress bar of ``total`` env steps, with the last training return, evaluation and throughput."""

    def __init__(self, total: int, desc: str) -> None:
        self.total, self.desc = total, desc
        self.bar: Any = None

    def on_start(self, run: Run) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=self.total, initial=run.global_step, desc=self.desc, unit="step", dynamic_ncols=True,
                        smoothing=0.1)  # fmt: skip

    def on_update(self, run: Run, stats: dict[str, float] | None) -> None:
        if stats:
            nan = float("nan")
            train_return, sps = stats.get("train/episode_reward", nan), stats.get("charts/SPS", nan)
            self.bar.set_postfix(train_return=f"{train_return:.0f}", eval=f"{run.last_eval:.0f}", SPS=f"{sps:.0f}")
        self.bar.update(run.global_step - self.bar.n)

    def on_end(self, run: Run, interrupted: bool) -> None:
        if self.bar is not None:
            self.bar.close()


# --------------------------------------------------------------------------------------------------- signals
class TerminateAsInterrupt(BaseCallback):
    """SIGTERM (``kill``) ends the run as Ctrl-C does: a checkpoint is saved (:class:`Checkpoints`) and the run
    stops with :class:`KeyboardInterrupt`. Either signal is also remembered, and raised again at the end of the step
    it came in: a library that swallowed the first raise (CasADi does to 5-20 % inside a solve) cannot keep
    the run going. The previous handlers are back when the run ends."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.previous: dict[int, Any] = {}
        self.pending: int | None = None

    def on_start(self, run: Run) -> None:
        self.pending = None
        self.previous = {signum: signal.signal(signum, self._interrupt) for signum in self.SIGNALS}

    def on_step(self, run: Run, step: Transition) -> None:
        if self.pending is not None:
            raise KeyboardInterrupt(f"signal {self.pending}")

    def on_end(self, run: Run, interrupted: bool) -> None:
        for signum, previous in self.previous.items():
            signal.signal(signum, previous)
        self.previous, self.pending = {}, None

    def _interrupt(self, signum: int, frame: Any) -> None:
        self.pending = signum
        raise KeyboardInterrupt(f"signal {signum}")


# --------------------------------------------------------------------------------------------------- recording
class TrainingSamples(BaseCallback):
    """The first training env's decision (its weights and Beta parameters) every ``every`` vector steps, to a
    recording's training timeline (``sink.sample``: :class:`~hrtc.logging.rerun_sink.RerunSink`)."""

    def __init__(self, sink: Any, every: int) -> None:
        self.sink, self.every, self.steps = sink, every, 0

    def on_start(self, run: Run) -> None:
        self.steps = 0

    def on_step(self, run: Run, step: Transition) -> None:
        if self.steps % self.every == 0:
            alpha, beta = beta_parameters(step.distribution)
            self.sink.sample(step.global_step, step.actions[0], alpha, beta)
        self.steps += 1
