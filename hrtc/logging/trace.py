"""What one evaluation episode did, step by step: the data a recording is made of (no rerun import here).

An :class:`EpisodeTrace` is filled by :func:`hrtc.episodes.run_episodes` (one :meth:`EpisodeTrace.add` per policy
decision) and handed to a :class:`Recorder` when the episode ends. For HRTC a decision's ``weights`` are the skill
weights; for plain PPO they are the policy's output ``u`` (there are no skills).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class RecordingConfig:
    """The ``logger`` block of a run's config.

    mode: ``off`` | ``save`` (``<run_dir>/recording.rrd``) | ``spawn`` (a viewer, and the file) | ``connect`` (a
    running viewer or server at ``url``, and the file).
    frames: camera frames of evaluation episodes, one every ``frame_every`` env steps, ``frame_size`` (height, width)
    pixels, in ``frame_episodes`` episodes of the ``frame_evals_every``-th, 2 ``frame_evals_every``-th...
    evaluation and of the last one (not of the first, the untrained policy's at step 0).
    Frames are the expensive part of a recording: a 240 x 320 MuJoCo frame takes about 37 ms of CPU on this
    machine's software renderer (31 ms at 120 x 160), the rest of an evaluation's record about 0.35 ms a decision.
    When the run knows how many episodes an evaluation has, the framed episodes are its last ones: the viewer opens at
    the end of the recording, on the last episode of the last evaluation, and its camera shows that episode.
    train_sample_every: the weights, alpha and beta of the first training env are recorded every this many policy
    decisions (0: never).
    action_names: the task's action components (``task.action_names``: ``cart_force``...), used for the blended
    action and the proposals; empty: ``a0``, ``a1``...
    key_state: the named quantity of the task's state (``task.key_state``, a key of ``env.unwrapped.skill_state()``
    of size 1: ``pole_angle``, ``y``...) recorded per decision as ``state/<key_state>``; None: none.
    window: env steps shown before the time cursor in the evaluation plots; None: the longest evaluation episode
    recorded before the layout is written (after the first training update).
    """

    mode: str = "save"
    url: str | None = None
    frames: bool = True
    frame_every: int = 20
    frame_size: tuple[int, int] = (240, 320)
    frame_episodes: int = 1
    frame_evals_every: int = 10
    train_sample_every: int = 25
    action_names: tuple[str, ...] = ()
    key_state: str | None = None
    window: int | None = None

    MODES = ("off", "save", "spawn", "connect")

    def __post_init__(self) -> None:
        from hrtc.errors import ConfigError, UnknownNameError

        if self.mode not in self.MODES:
            raise UnknownNameError("logger mode", self.mode, self.MODES)
        for name in ("frame_every", "frame_evals_every"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"logger.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("frame_episodes", "train_sample_every"):
            if int(getattr(self, name)) < 0:
                raise ConfigError(f"logger.{name} must be >= 0, got {getattr(self, name)}")
        if len(self.frame_size) != 2 or min(self.frame_size) < 8:
            raise ConfigError(f"logger.frame_size must be [height, width] >= 8 pixels, got {list(self.frame_size)}")
        if self.window is not None and int(self.window) < 1:
            raise ConfigError(f"logger.window must be >= 1 env step (or null), got {self.window}")
        if len(set(self.action_names)) != len(self.action_names):
            raise ConfigError(f"logger.action_names must be distinct, got {list(self.action_names)}")
        if self.mode == "connect" and not self.url:
            raise ConfigError("logger.mode=connect needs logger.url (e.g. rerun+http://127.0.0.1:9876/proxy)")

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> RecordingConfig:
        from dataclasses import fields

        from hrtc.errors import ConfigError

        cfg = dict(cfg or {})
        names = {f.name for f in fields(cls)}
        unknown = set(cfg) - names
        if unknown:
            raise ConfigError(f"unknown logger keys {sorted(unknown)}; valid: {sorted(names)}")
        if "frame_size" in cfg:
            cfg["frame_size"] = tuple(int(v) for v in cfg["frame_size"])
        cfg["action_names"] = tuple(str(v) for v in cfg.get("action_names") or ())
        return cls(**cfg)


@dataclass
class EpisodeTrace:
    """Per-decision arrays of one evaluation episode; ``frame_every`` 0 records no frames.

    After the episode: ``weights`` (T, K), ``alpha``/``beta`` (T, K) (Beta policies; empty otherwise), ``proposals``
    (T, K, A) (HRTC), ``action`` (T, A) the action sent to the task, ``reward`` (T,) summed over the decision's env
    steps, ``env_step`` (T,) env steps into the episode after the decision, ``obs`` (T, obs_dim) as the policy saw
    it, ``skill_info`` per skill name a dict of diagnostic name -> (T,) array; ``frames`` list of (env_step, image);
    ``key`` (T,) the task's ``key_state`` quantity after each decision, read from ``state()`` (the task's
    ``skill_state``) when both are given.
    """

    episode: int
    seed: int
    skill_names: tuple[str, ...]
    frame_every: int = 0
    render: Callable[[], np.ndarray | None] | None = None
    state: Callable[[], Mapping[str, np.ndarray]] | None = None
    key_state: str | None = None
    weights: list = field(default_factory=list)
    alpha: list = field(default_factory=list)
    beta: list = field(default_factory=list)
    proposals: list = field(default_factory=list)
    action: list = field(default_factory=list)
    reward: list = field(default_factory=list)
    env_step: list = field(default_factory=list)
    obs: list = field(default_factory=list)
    key: list = field(default_factory=list)
    skill_info: dict[str, dict[str, list]] = field(default_factory=dict)
    frames: list[tuple[int, np.ndarray]] = field(default_factory=list)
    episode_return: float = float("nan")
    values: np.ndarray | None = None

    def add(self, obs: np.ndarray, u: np.ndarray, alpha: np.ndarray | None, beta: np.ndarray | None,
            env_action: np.ndarray, reward: float, info: Mapping[str, Any]) -> None:  # fmt: skip
        """Record one decision: the policy's input ``obs`` and output ``u``, the task's step result ``info``."""
        last = self.env_step[-1] if self.env_step else 0
        env_step = int(info.get("env_steps", last + 1))
        self.obs.append(np.asarray(obs, dtype=np.float32))
        self.weights.append(np.asarray(info.get("weights", u), dtype=np.float64))
        if alpha is not None and beta is not None:
            self.alpha.append(np.asarray(alpha, dtype=np.float64))
            self.beta.append(np.asarray(beta, dtype=np.float64))
        if "proposals" in info:
            self.proposals.append(np.asarray(info["proposals"], dtype=np.float64))
        self.action.append(np.asarray(info.get("action", env_action), dtype=np.float64))
        self.reward.append(float(reward))
        self.env_step.append(env_step)
        if self.key_state is not None and self.state is not None:
            self.key.append(key_value(self.state(), self.key_state))
        for name, diagnostics in (info.get("skills") or {}).items():
            store = self.skill_info.setdefault(name, {})
            for key, value in diagnostics.items():
                store.setdefault(key, []).append(float(value))
        if self.frame_every and self.render is not None and env_step // self.frame_every > last // self.frame_every:
            frame = self.render()
            if frame is not None:
                self.frames.append((env_step, np.asarray(frame)))

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-decision lists as arrays (empty arrays where nothing was recorded)."""
        out = {name: np.asarray(getattr(self, name)) for name in
               ("weights", "alpha", "beta", "proposals", "action", "reward", "env_step", "key")}  # fmt: skip
        return out


def key_value(state: Mapping[str, np.ndarray], key: str) -> float:
    """The task's key state quantity ``key`` of a named state (``skill_state()``), a float; a clear error when the
    task has no such quantity or it is not a single number."""
    from hrtc.errors import ConfigError

    if key not in state:
        raise ConfigError(f"key_state {key!r} is not in the task's named state; it has {', '.join(sorted(state))}")
    value = np.asarray(state[key], dtype=np.float64).reshape(-1)
    if value.size != 1:
        raise ConfigError(f"key_state {key!r} has {value.size} numbers; the recording plots one (declare a scalar)")
    return float(value[0])


class Recorder(Protocol):
    """Receives evaluation episodes. ``start_evaluation`` announces an evaluation (its episodes follow), ``begin``
    returns the trace of one episode to fill (frames or not), ``end`` takes it back."""

    def start_evaluation(self, global_step: int, last: bool = False) -> None: ...

    def begin(
        self, episode_in_eval: int, seed: int, render: Callable[[], np.ndarray | None] | None
    ) -> EpisodeTrace: ...

    def end(self, trace: EpisodeTrace) -> None: ...


def weight_summary(weights: np.ndarray, alpha: np.ndarray | None = None, beta: np.ndarray | None = None,
                   names: Sequence[str] = ()) -> dict[str, dict[str, float]]:  # fmt: skip
    """Per skill: mean weight, share of decisions where it had the largest weight (ties to the first), and mean
    alpha + beta (the meta-policy's confidence; NaN without Beta parameters). ``weights`` (T, K)."""
    weights = np.asarray(weights, dtype=np.float64)
    names = list(names) or [f"w{k}" for k in range(weights.shape[1])]
    dominant = np.bincount(np.argmax(weights, axis=1), minlength=weights.shape[1]) / len(weights)
    confidence = (np.asarray(alpha) + np.asarray(beta)).mean(axis=0) if alpha is not None and len(alpha) else None
    return {
        name: {
            "mean_weight": float(weights[:, k].mean()),
            "dominant_share": float(dominant[k]),
            "mean_alpha_plus_beta": float(confidence[k]) if confidence is not None else float("nan"),
        }
        for k, name in enumerate(names)
    }


class TraceCollector:
    """A :class:`Recorder` that keeps every finished trace (for statistics) and passes every call on to ``inner`` if
    any. Without ``inner`` it records no frames."""

    def __init__(self, inner: Recorder | None = None) -> None:
        self.inner = inner
        self.traces: list[EpisodeTrace] = []

    def start_evaluation(self, global_step: int, last: bool = False) -> None:
        if self.inner is not None:
            self.inner.start_evaluation(global_step, last)

    def begin(self, episode_in_eval: int, seed: int, render: Callable[[], np.ndarray | None] | None) -> EpisodeTrace:
        if self.inner is not None:
            return self.inner.begin(episode_in_eval, seed, render)
        return EpisodeTrace(len(self.traces), seed, ())

    def end(self, trace: EpisodeTrace) -> None:
        self.traces.append(trace)
        if self.inner is not None:
            self.inner.end(trace)


def skill_statistics(traces: Sequence[EpisodeTrace]) -> dict[str, dict[str, float]]:
    """Per skill over all decisions of ``traces``: median and 99th-percentile solve time (``solve_ms`` when the
    skill reports it, else the measured ``compute_ms``), ms; ``failures``: decisions whose ``status`` was not 0;
    ``faults``: non-finite proposals replaced by a fallback; ``decisions``."""
    merged: dict[str, dict[str, list[float]]] = {}
    for trace in traces:
        for name, diagnostics in trace.skill_info.items():
            store = merged.setdefault(name, {})
            for key, values in diagnostics.items():
                store.setdefault(key, []).extend(values)
    out = {}
    for name, diagnostics in merged.items():
        times = np.asarray(diagnostics.get("solve_ms") or diagnostics.get("compute_ms") or [np.nan])
        status = np.asarray(diagnostics.get("status", []))
        out[name] = {
            "decisions": float(len(next(iter(diagnostics.values()), []))),
            "median_ms": float(np.median(times)),
            "p99_ms": float(np.percentile(times, 99)),
            "failures": float(np.count_nonzero(status)),
            "faults": float(np.sum(diagnostics.get("fault", []))),
        }
    return out


def format_returns(returns: np.ndarray) -> str:
    """``returns over N episodes: mean ± std (min, max)``."""
    return (f"returns over {len(returns)} episodes: {returns.mean():.1f} ± {returns.std():.1f} "
            f"(min {returns.min():.1f}, max {returns.max():.1f})")  # fmt: skip


def format_skill_statistics(stats: Mapping[str, Mapping[str, float]], only: Sequence[str] | None = None) -> list[str]:
    """:func:`skill_statistics` as text lines, one per skill (those in ``only`` when given)."""
    lines = ["skill      decisions  median ms   p99 ms  failures  faults"]
    for name, s in stats.items():
        if only is None or name in only:
            lines.append(f"{name:<10} {s['decisions']:>9.0f}  {s['median_ms']:>9.3f}  {s['p99_ms']:>7.3f}  "
                         f"{s['failures']:>8.0f}  {s['faults']:>6.0f}")  # fmt: skip
    return lines
