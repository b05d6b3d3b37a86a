"""The Rerun recording of a run: the only module that imports rerun.

Entities (a skill's config name is its entity name):

- per decision of every evaluation episode, on timelines ``env_step`` (evaluation env steps laid end to end over
  the run: one monotone axis for the plots and the video) and ``episode`` (the evaluation episode's index in the run):
  ``meta/weights`` (one series per skill), ``meta/alpha``, ``meta/beta``, ``meta/confidence`` (alpha + beta),
  ``meta/effective_weights`` (skill trees: every node's weight times its parents', one series per tree path),
  ``skills/<name>/action``, ``skills/<name>/<diagnostic>`` (solver status, solve time, cost, faults...),
  ``action/blended`` (series named by the task's ``action_names``), ``reward``, ``value``, ``state/<key_state>`` (the
  task's key state quantity after the decision), and ``world/camera`` frames (cleared at every episode's start, so an
  episode without frames shows none);
- per evaluation episode, on ``episode`` and ``env_step``: ``eval/episode/return``, ``eval/episode/length``,
  ``eval/episode/global_step`` (the training step of the policy that ran it), ``eval/episode/seed``;
- sampled training decisions (first training env) on ``global_step``: ``meta/weights``, ``meta/alpha``,
  ``meta/beta``, ``meta/confidence``;
- training metrics (``train.csv``'s columns) as ``train/<name>`` on ``update`` and ``global_step``; evaluation rows as
  ``eval/<name>`` on ``global_step``;
- static: ``tree`` (the skill library as text), the series names and colours (:mod:`hrtc.logging.palette`: one colour
  per skill in every view, white and greys for everything else).

The layout (:func:`blueprint`) is sent once per segment, after the first training update or when the sink closes,
with views only for the entities recorded by then; :func:`read_blueprint` reads it back from a file.

Per-step data is buffered for an episode and sent as columns when it ends (``send_columns``: 0.2 ms for 1000 steps,
against 0.13 ms per ``log`` call), so recording costs little next to the episode itself.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import rerun as rr
import rerun.blueprint as rrb

from hrtc.logging.palette import NEUTRAL, greys, shades, skill_colors
from hrtc.logging.trace import EpisodeTrace, RecordingConfig

log = logging.getLogger(__name__)

APPLICATION_ID = "hrtc"


def segment_paths(run_dir: str | Path) -> list[Path]:
    """The recording segments of a run, in order: ``recording.rrd``, ``recording.1.rrd``, ... (one per resume)."""
    run_dir = Path(run_dir)
    found = [p for p in run_dir.glob("recording*.rrd") if _segment_index(p) is not None]
    return sorted(found, key=lambda p: _segment_index(p) or 0)


def _segment_index(path: Path) -> int | None:
    parts = path.name.split(".")
    if parts == ["recording", "rrd"]:
        return 0
    if len(parts) == 3 and parts[0] == "recording" and parts[2] == "rrd" and parts[1].isdigit():
        return int(parts[1])
    return None


# Training metrics that share a scale share a view; every other metric gets its own (one quantity per axis).
_TRAIN_GROUPS = {
    "KL divergence": ("train/losses/approx_kl", "train/losses/old_approx_kl"),
    "minibatches (count)": ("train/losses/minibatches", "train/losses/skipped"),
    "steps per second": ("train/charts/SPS", "train/charts/rollout_SPS"),
}
_EVAL_RETURNS = ("eval/episode/return", "eval/episode_reward", "eval/episode_reward_std")
_TRAIN_NAMES = {"train/train/episode_reward": "training return", "train/charts/learning_rate": "learning rate",
                "train/charts/update_seconds": "update time (s)", "train/episodes": "training episodes"}  # fmt: skip


def _time_series(name: str, contents: Sequence[str], y: tuple[float, float] | None = None,
                 window: int | None = None) -> rrb.TimeSeriesView:  # fmt: skip
    """A plot of the entities ``contents``; ``y``: a fixed vertical range; ``window``: the x axis shows the last
    ``window`` steps before the time cursor (else the whole timeline)."""
    boundary = rrb.TimeRangeBoundary
    if window is None:
        x_range = rr.TimeRange(start=boundary.infinite(), end=boundary.infinite())
    else:
        x_range = rr.TimeRange(start=boundary.cursor_relative(seq=-int(window)), end=boundary.cursor_relative(seq=0))
    axis_y = rrb.ScalarAxis(range=y, zoom_lock=True) if y is not None else None
    return rrb.TimeSeriesView(origin="/", contents=[f"+ /{c}" for c in contents], name=name, axis_y=axis_y,
                              axis_x=rrb.TimeAxis(view_range=x_range))  # fmt: skip


def blueprint(logged: Collection[str], skill_names: Sequence[str], key_state: str | None = None,
              window: int = 1000, plain: bool = False) -> rrb.Blueprint:  # fmt: skip
    """The layout a recording opens on, with views only for the entities in ``logged`` (paths without the leading
    slash). ``plain``: a policy on raw actions (PPO): ``meta/weights`` holds its outputs, not skill weights.

    The viewer opens on the ``env_step`` timeline at the end of the recording (the last evaluation episode): the
    evaluation tab shows the last ``window`` env steps of the weights (fixed [0, 1] axis), the key state, alpha +
    beta, the camera, proposals and blend, reward and value; the training tab has one view per training quantity
    (on ``global_step`` and ``update``; the per-episode evaluation returns also on ``env_step``); the skills tab
    each skill's diagnostics, one view per scale (cost, timings, status and faults).
    """
    has = set(logged).__contains__

    def series(name: str, contents: Sequence[str], y: tuple[float, float] | None = None,
               windowed: bool = True) -> rrb.TimeSeriesView | None:  # fmt: skip
        present = [c for c in contents if has(c)]
        return _time_series(name, present, y, window if windowed else None) if present else None

    def views(*items: rrb.View | rrb.Container | None) -> list:
        return [item for item in items if item is not None]

    if plain:
        weights = series("policy output u (plain PPO, no skills)", ["meta/weights"])
    else:
        weights = series("skill weights", ["meta/weights"], (0.0, 1.0))
    effective = series("effective weights (skill tree)", ["meta/effective_weights"], (0.0, 1.0))
    state = series(key_state, [f"state/{key_state}"]) if key_state else None
    confidence = series("confidence: alpha + beta", ["meta/confidence"])
    camera = rrb.Spatial2DView(origin="world/camera", name="camera") if has("world/camera") else None
    actions = series("proposals and blended action", ["action/blended", *[f"skills/{n}/action" for n in skill_names]])
    reward = series("reward per decision", ["reward"])
    value = series("value (critic)", ["value"])
    left = views(weights, effective, state, confidence)
    right = views(camera, actions, rrb.Horizontal(*views(reward, value)) if reward or value else None)
    columns = views(rrb.Vertical(*left) if left else None, rrb.Vertical(*right) if right else None)
    evaluation = rrb.Horizontal(*columns, column_shares=[3, 2][: len(columns)], name="evaluation")

    train = sorted(path for path in logged if path.startswith("train/"))
    grouped = {path for paths in _TRAIN_GROUPS.values() for path in paths}
    training = views(
        series("evaluation return", _EVAL_RETURNS, windowed=False),
        series("evaluation episode length", ["eval/episode/length"], windowed=False),
        *[series(name, paths, windowed=False) for name, paths in _TRAIN_GROUPS.items()],
        series("faults (count)", [p for p in train if p.startswith("train/faults/")], windowed=False),  # + workers
        *[series(_TRAIN_NAMES.get(p, p.removeprefix("train/losses/").removeprefix("train/")), [p], windowed=False)
          for p in train if p not in grouped and not p.startswith("train/faults/")],
    )  # fmt: skip
    tabs = [evaluation]
    if training:
        tabs.append(rrb.Grid(*training, name="training (timeline: global_step)"))
    per_skill = []
    for name in skill_names:
        diagnostics = sorted(p.removeprefix(f"skills/{name}/") for p in logged if p.startswith(f"skills/{name}/"))
        timing = [d for d in diagnostics if d.endswith("_ms")]
        codes = [d for d in diagnostics if d in ("status", "fault")]
        others = [d for d in diagnostics if d not in timing and d not in codes and d != "action"]
        per_skill += views(
            *[series(f"{name}: {d}", [f"skills/{name}/{d}"]) for d in others],
            series(f"{name}: time (ms)", [f"skills/{name}/{d}" for d in timing]),
            series(f"{name}: status, faults", [f"skills/{name}/{d}" for d in codes]),
        )
    text = rrb.TextDocumentView(origin="tree", name="skill tree") if has("tree") else None
    if per_skill or text:
        tabs.append(rrb.Horizontal(*views(text, rrb.Grid(*per_skill) if per_skill else None), name="skills"))
    return rrb.Blueprint(
        rrb.Tabs(*tabs, active_tab=0),
        rrb.TimePanel(timeline="env_step", play_state="following", state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


class RerunSink:
    """A :class:`~hrtc.logging.Sink` and :class:`~hrtc.logging.trace.Recorder` writing ``<run_dir>/recording.rrd``.

    ``skill_names``: the weight vector's components (HRTC) or action names (PPO); ``tree``: the skill library as
    text; ``resume``: continue a run in a new segment ``recording.<n>.rrd`` whose episode and env-step counters carry
    on from the earlier segments; ``state_source``: the task's named state (``env.unwrapped.skill_state``) read after
    every evaluation decision for ``cfg.key_state``; ``eval_episodes``: episodes per evaluation (frames go to the last
    ones).

    The layout (:func:`blueprint`) is written once, after the first training update (or at :meth:`close`), with views
    for what the recording holds by then.
    """

    def __init__(self, run_dir: str | Path, cfg: RecordingConfig, skill_names: Sequence[str], action_dim: int,
                 tree: str = "", resume: bool = False, recording_id: str | None = None,
                 tree_paths: Sequence[str] = (),
                 state_source: Callable[[], Mapping[str, np.ndarray]] | None = None,
                 eval_episodes: int | None = None) -> None:  # fmt: skip
        from hrtc.errors import ConfigError

        self.cfg, self.action_dim = cfg, int(action_dim)
        if cfg.action_names and len(cfg.action_names) != self.action_dim:
            raise ConfigError(f"action_names {list(cfg.action_names)} name {len(cfg.action_names)} components; the "
                              f"task's action has {self.action_dim}")  # fmt: skip
        self.action_names = tuple(cfg.action_names) or tuple(f"a{i}" for i in range(self.action_dim))
        names = tuple(skill_names)
        # Plain PPO (the trainer names its outputs a0, a1...): the policy's outputs are the task's action components.
        self.plain = names == tuple(f"a{i}" for i in range(self.action_dim))
        if self.plain:
            names = self.action_names
        self.skill_names = names
        self.colors = skill_colors(names)
        # Nested skills (an HRTC policy as a skill): every node's effective weight gets a series.
        self.tree_paths = tuple(tree_paths) if len(tree_paths) > len(self.skill_names) else ()
        self.state_source = state_source if cfg.key_state else None
        self.eval_episodes = int(eval_episodes) if eval_episodes else None
        run_dir = Path(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        previous = segment_paths(run_dir) if resume else []
        self.path = run_dir / (f"recording.{len(previous)}.rrd" if previous else "recording.rrd")
        self.episode, self.env_step = _counters(previous)
        recording_id = recording_id or str(uuid.uuid5(uuid.NAMESPACE_URL, str(run_dir.resolve())))
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self._connect()
        self.global_step, self.updates, self._eval_index = 0, 0, 0
        self._frames_this_eval = False
        self._samples: list[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]] = []
        self.logged: set[str] = set()  # entity paths holding data: the layout shows these and no others
        self._longest = 0  # the longest evaluation episode so far, env steps
        self._blueprint_sent = False
        self._renders = False  # frames are on and the task can render: the layout has a camera view
        self._styled: set[str] = set()  # entities whose series names and colours are logged
        self._log_static(tree)

    @classmethod
    def for_env(cls, run_dir: str | Path, cfg: RecordingConfig, env: Any, title: str, resume: bool = False,
                eval_episodes: int | None = None, updates: int = 0) -> RerunSink:  # fmt: skip
        """A recording of the episodes of ``env`` (a composed env: its skills and skill tree; else the policy's
        outputs ``a0``, ``a1``...), titled ``title``; its ``update`` timeline continues from ``updates`` (a resumed
        run's)."""
        from hrtc.tree import describe

        size = int(env.action_space.shape[0])
        names = tuple(getattr(env, "skill_names", ())) or tuple(f"a{i}" for i in range(size))
        tree, paths = describe(env, title)
        sink = cls(run_dir, cfg, names, int(getattr(env, "action_dim", size)), tree, resume, tree_paths=paths,
                   state_source=env.unwrapped.skill_state, eval_episodes=eval_episodes)  # fmt: skip
        sink.updates = int(updates)
        return sink

    def _connect(self) -> None:
        mode, path = self.cfg.mode, str(self.path)
        if mode == "save":
            self.rec.save(path)
            return
        url = self.cfg.url
        if mode == "spawn":
            port = 9876
            try:
                rr.spawn(port=port, connect=False, recording=self.rec)
            except Exception as error:  # no viewer binary or no display: keep the file, say so once
                log.warning("could not spawn a Rerun viewer (%s); recording to %s only", error, path)
                self.rec.save(path)
                return
            url = f"rerun+http://127.0.0.1:{port}/proxy"
        self.rec.set_sinks(rr.GrpcSink(url=url), rr.FileSink(path))

    def send_blueprint(self) -> None:
        """Write the layout for what is recorded now (once per segment: later calls do nothing)."""
        if self._blueprint_sent:
            return
        window = self.cfg.window or self._longest or 1000
        # Frames come with later evaluations: a task that renders gets its camera view from the start.
        logged = self.logged | ({"world/camera"} if self._renders else set())
        self.rec.send_blueprint(blueprint(logged, self.skill_names, self.cfg.key_state, window, self.plain))
        self._blueprint_sent = True

    def _log_static(self, tree: str) -> None:
        rec, names, colors = self.rec, list(self.skill_names), self.colors
        for entity in ("meta/weights", "meta/alpha", "meta/beta", "meta/confidence"):
            rec.log(entity, rr.SeriesLines(names=names, colors=colors), static=True)
        if self.tree_paths:
            rec.log("meta/effective_weights", rr.SeriesLines(names=list(self.tree_paths), colors=self._path_colors()),
                    static=True)  # fmt: skip
        actions = list(self.action_names)
        blend = [f"blended/{a}" for a in actions]
        rec.log("action/blended", rr.SeriesLines(names=blend, colors=greys(len(actions)), widths=2.0),
                static=True)  # fmt: skip
        for name, color in zip(self.skill_names if not self.plain else (), colors, strict=False):
            lines = rr.SeriesLines(names=[f"{name}/{a}" for a in actions], colors=shades(color, len(actions)))
            rec.log(f"skills/{name}/action", lines, static=True)
        for entity in ("reward", "value"):
            rec.log(entity, rr.SeriesLines(names=[entity], colors=[NEUTRAL]), static=True)
        self._style("eval/episode", {key: 0.0 for key in ("return", "length", "global_step", "seed")})
        if self.cfg.key_state:
            rec.log(f"state/{self.cfg.key_state}", rr.SeriesLines(names=[self.cfg.key_state], colors=[NEUTRAL]),
                    static=True)  # fmt: skip
        text = rr.TextDocument(tree or "(no skills: plain PPO)", media_type=rr.MediaType.MARKDOWN)
        rec.log("tree", text, static=True)
        self.logged.add("tree")

    def _path_colors(self) -> list:
        """A tree path's colour: its top-level skill's, lighter with depth."""
        index = {name: k for k, name in enumerate(self.skill_names)}
        out = []
        for path in self.tree_paths:
            parts = path.split("/")
            color = self.colors[index.get(parts[0], 0)]
            out.append(shades(color, 4)[min(len(parts) - 1, 3)])
        return out

    # ------------------------------------------------------------------ Sink
    def write(self, stream: str, step: int, metrics: Mapping[str, float]) -> None:
        self.global_step = int(step)
        rec = self.rec
        rec.reset_time()
        rec.set_time("global_step", sequence=int(step))
        if stream == "train":
            self._flush_samples()
            rec.reset_time()
            rec.set_time("global_step", sequence=int(step))
            self.updates += 1
            rec.set_time("update", sequence=self.updates)
        for key, value in metrics.items():
            value = float(value)
            if np.isfinite(value):
                rec.log(f"{stream}/{key}", rr.Scalars([value]))
                self.logged.add(f"{stream}/{key}")
        rec.reset_time()
        self._style(stream, metrics)
        if stream == "train":
            self.send_blueprint()
        if stream == "eval":
            rec.flush()  # an evaluation's episodes are on disk once it is reported: a killed run keeps them

    def _style(self, stream: str, metrics: Mapping[str, float]) -> None:
        """Name and colour each metric's series once: a skill's faults in the skill's colour, every other metric in
        white or grey (never a skill's colour), the members of a shared view in distinct shades."""
        groups = [*_TRAIN_GROUPS.values(), _EVAL_RETURNS]
        for key in metrics:
            entity = f"{stream}/{key}"
            if entity in self._styled:
                continue
            skill = key.removeprefix("faults/")
            if key.startswith("faults/") and skill in self.skill_names:
                color = self.colors[self.skill_names.index(skill)]
            else:
                group = next((g for g in groups if entity in g), (entity,))
                color = greys(len(group))[group.index(entity)]
            self.rec.log(entity, rr.SeriesLines(names=[key.split("/")[-1]], colors=[color]), static=True)
            self._styled.add(entity)

    def close(self) -> None:
        self._flush_samples()
        self.send_blueprint()
        self.rec.flush()
        self.rec.disconnect()

    # ------------------------------------------------------------------ training samples
    def sample(self, global_step: int, weights: np.ndarray, alpha: np.ndarray | None, beta: np.ndarray | None) -> None:
        """One sampled training decision (weights ``(K,)``, Beta parameters or None); sent with the next update."""
        self._samples.append((int(global_step), np.asarray(weights, np.float64), alpha, beta))

    def _flush_samples(self) -> None:
        if not self._samples:
            return
        steps = np.array([s[0] for s in self._samples])
        index = [rr.TimeColumn("global_step", sequence=steps)]
        self._columns("meta/weights", index, np.stack([s[1] for s in self._samples]))
        if self._samples[0][2] is not None:
            alpha = np.stack([np.asarray(s[2], np.float64) for s in self._samples])
            beta = np.stack([np.asarray(s[3], np.float64) for s in self._samples])
            self._columns("meta/alpha", index, alpha)
            self._columns("meta/beta", index, beta)
            self._columns("meta/confidence", index, alpha + beta)
        self._samples.clear()

    # ------------------------------------------------------------------ evaluation episodes (Recorder)
    def start_evaluation(self, global_step: int, last: bool = False) -> None:
        """Called before each evaluation: decides whether its episodes carry camera frames."""
        self.global_step = int(global_step)
        # The frame_evals_every-th, 2 x frame_evals_every-th... evaluation and the last: not the untrained policy's at
        # step 0 (frames are most of a recording's cost; the viewer opens on the last evaluation).
        self._eval_index += 1
        self._frames_this_eval = self.cfg.frames and (last or self._eval_index % self.cfg.frame_evals_every == 0)

    def begin(self, episode_in_eval: int, seed: int, render: Callable[[], np.ndarray | None] | None) -> EpisodeTrace:
        # The last frame_episodes episodes of an evaluation when its size is known (the viewer opens on the last
        # episode of the run), else the first ones.
        first = self.eval_episodes - self.cfg.frame_episodes if self.eval_episodes else 0
        framed = first <= episode_in_eval < first + self.cfg.frame_episodes
        frames = self._frames_this_eval and framed and render is not None
        self._renders = self._renders or (self.cfg.frames and render is not None)
        return EpisodeTrace(self.episode, int(seed), self.skill_names, self.cfg.frame_every if frames else 0, render,
                            state=self.state_source, key_state=self.cfg.key_state)  # fmt: skip

    def end(self, trace: EpisodeTrace) -> None:
        data = trace.arrays()
        length = len(data["reward"])
        if length == 0:
            return
        steps = self.env_step + data["env_step"]
        episodes = np.full(length, trace.episode)
        index = [rr.TimeColumn("env_step", sequence=steps), rr.TimeColumn("episode", sequence=episodes)]
        self._columns("meta/weights", index, data["weights"])
        if len(data["alpha"]):
            self._columns("meta/alpha", index, data["alpha"])
            self._columns("meta/beta", index, data["beta"])
            self._columns("meta/confidence", index, data["alpha"] + data["beta"])
        if len(data["proposals"]):
            for k, name in enumerate(self.skill_names):
                self._columns(f"skills/{name}/action", index, data["proposals"][:, k, :])
        if self.tree_paths:
            self._columns("meta/effective_weights", index, self._effective(trace, data["weights"]))
        self._columns("action/blended", index, data["action"])
        self._columns("reward", index, data["reward"][:, None])
        if trace.values is not None:
            self._columns("value", index, np.asarray(trace.values, np.float64).reshape(length, 1))
        if len(data["key"]):
            self._columns(f"state/{self.cfg.key_state}", index, data["key"][:, None])
        for name, diagnostics in trace.skill_info.items():
            color = self.colors[self.skill_names.index(name)] if name in self.skill_names else NEUTRAL
            timings = sorted(k for k in diagnostics if k.endswith("_ms"))
            for key, values in diagnostics.items():
                if len(values) == length:
                    entity = f"skills/{name}/{key}"
                    if entity not in self._styled:
                        shade = shades(color, len(timings))[timings.index(key)] if key in timings else color
                        self.rec.log(entity, rr.SeriesLines(names=[f"{name}/{key}"], colors=[shade]), static=True)
                        self._styled.add(entity)
                    self._columns(entity, index, np.asarray(values)[:, None])
        rec = self.rec
        # The camera shows this episode's frames only: an episode without frames leaves it empty, not showing the
        # last frame of an earlier one.
        rec.reset_time()
        rec.set_time("env_step", sequence=self.env_step)
        rec.set_time("episode", sequence=trace.episode)
        rec.log("world/camera", rr.Clear(recursive=False))
        if trace.frames:
            self.logged.add("world/camera")
        for env_step, frame in trace.frames:
            rec.reset_time()
            rec.set_time("env_step", sequence=int(self.env_step + env_step))
            rec.set_time("episode", sequence=trace.episode)
            rec.log("world/camera", rr.Image(frame).compress(jpeg_quality=80))
        rec.reset_time()
        rec.set_time("episode", sequence=trace.episode)
        rec.set_time("env_step", sequence=int(steps[-1]))
        summary = {"return": trace.episode_return, "length": float(data["env_step"][-1]),
                   "global_step": float(self.global_step), "seed": float(trace.seed)}  # fmt: skip
        for key, value in summary.items():
            rec.log(f"eval/episode/{key}", rr.Scalars([value]))
            self.logged.add(f"eval/episode/{key}")
        rec.reset_time()
        self._longest = max(self._longest, int(data["env_step"][-1]))
        self.episode += 1
        self.env_step = int(steps[-1]) + 1

    def _effective(self, trace: EpisodeTrace, weights: np.ndarray) -> np.ndarray:
        """(T, nodes) effective weights: a child's weight times its parents' (``hrtc.tree.effective_weights``)."""
        from hrtc.tree import effective_weights

        rows = []
        for t, w in enumerate(weights):
            info = {name: {k: v[t] for k, v in d.items() if len(v) > t} for name, d in trace.skill_info.items()}
            eff = effective_weights(self.skill_names, w, info)
            rows.append([eff.get(path, np.nan) for path in self.tree_paths])
        return np.asarray(rows)

    def _columns(self, entity: str, index: list, values: np.ndarray) -> None:
        self.logged.add(entity)
        self.rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)))


def _counters(previous: Sequence[Path]) -> tuple[int, int]:
    """The next episode index and env step after the earlier segments of a resumed run."""
    if not previous:
        return 0, 0
    frames = read_recording(previous, contents="/eval/episode/**", index="episode")
    if frames.empty:
        return 0, 0
    episode = int(frames["episode"].max()) + 1
    env_step = int(frames["env_step"].max()) + 1 if "env_step" in frames else 0
    return episode, env_step


# --------------------------------------------------------------------------------------------------- reading back
def read_recording(paths: Sequence[str | Path], contents: str = "/**", index: str | None = "env_step") -> pd.DataFrame:
    """The recorded rows on timeline ``index`` (None: the static data) of the entities matching ``contents``, from
    every segment in order.

    Columns are the timelines, one column per scalar entity path (``/meta/weights``...: each cell an array) and the
    other components under rerun's own names (``/meta/weights:SeriesLines:names``...). Files of a
    run that is still going or was killed (no footer yet) are read with a whole-file scan; the last episode of a
    killed run may be missing (episodes are written when they end).
    """
    import warnings

    import pandas as pd
    from rerun.chunk import RrdReader

    tables = []
    for path in paths:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "RRD file has no footer": expected for a run in progress
            store = RrdReader(str(path)).stream().collect()
        if index is not None and index not in [c.name for c in store.schema().index_columns()]:
            continue  # nothing was logged on that timeline yet
        table = store.reader(index=index, contents=contents).to_pandas()
        tables.append(table.rename(columns=lambda c: c.removesuffix(":Scalars:scalars")))
    if not tables:
        return pd.DataFrame()
    return pd.concat(tables, ignore_index=True)


def entity_paths(paths: Sequence[str | Path]) -> set[str]:
    """Every entity path (without the leading slash) holding a component in the recordings ``paths``."""
    import warnings

    from rerun.chunk import RrdReader

    found: set[str] = set()
    for path in paths:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            schema = RrdReader(str(path)).stream().collect().schema()
        found |= {c.entity_path.lstrip("/") for c in schema.component_columns() if not c.is_property}
    return found


def stores(path: str | Path) -> dict[str, int]:
    """How many stores of each kind (``recording``, ``blueprint``) an ``.rrd`` file holds."""
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(str(path))
        return {"recording": len(reader.recordings()), "blueprint": len(reader.blueprints())}


def read_blueprint(path: str | Path) -> dict[str, Any]:
    """The layout stored in an ``.rrd`` file, read back with rerun-sdk's reader: ``timeline`` and ``play_state``
    (``paused``, ``playing``, ``following``) of the time panel, and ``views``: per view, by display name, its ``class``
    (``TimeSeries``, ``Spatial2D``, ``TextDocument``), ``origin``, ``contents`` (the entity paths it shows),
    ``y_range`` ([low, high], or None: automatic) and ``x_range`` (``{"start": {kind: value}, "end": ...}`` with kind
    ``CursorRelative``, ``Absolute`` or ``Infinite``; None if unset)."""
    import warnings

    import pyarrow as pa
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(str(path))
        if not reader.blueprints():
            return {"timeline": None, "play_state": None, "views": {}}
        store = reader.stream(store=reader.blueprints()[-1]).collect()
        table = store.reader(index="blueprint", contents="/**").to_arrow_table()
    cells: dict[str, Any] = {}
    for name in table.column_names:
        column = table.column(name)
        values = [column[i] for i in range(len(column)) if column[i].is_valid]
        if values and isinstance(values[-1], pa.ListScalar) and len(values[-1].values):
            cells[name] = _plain(values[-1].values)
    views: dict[str, dict[str, Any]] = {}
    for name, value in cells.items():
        entity, _, component = name.partition(":")
        if not entity.startswith("/view/"):
            continue
        view_id, _, part = entity.removeprefix("/view/").partition("/")
        views.setdefault(view_id, {"y_range": None, "x_range": None, "contents": []})
        if component == "ViewBlueprint:display_name":
            views[view_id]["name"] = value
        elif component == "ViewBlueprint:class_identifier":
            views[view_id]["class"] = value
        elif component == "ViewBlueprint:space_origin":
            views[view_id]["origin"] = value
        elif part == "ScalarAxis" and component == "ScalarAxis:range":
            views[view_id]["y_range"] = list(value)
        elif part == "TimeAxis" and component == "TimeAxis:view_range":
            views[view_id]["x_range"] = value
    for name in table.column_names:  # a view's query is a list of expressions: read it whole
        entity, _, component = name.partition(":")
        if entity.startswith("/view/") and entity.endswith("/ViewContents") and component == "ViewContents:query":
            view_id = entity.removeprefix("/view/").split("/")[0]
            column = [c for c in table.column(name) if c.is_valid]
            origin = views[view_id].get("origin", "/").strip("/")
            queries = [str(q) for q in column[-1].values.to_pylist()] if column else []
            views[view_id]["contents"] = [_query_path(q, origin) for q in queries]
    play_state = cells.get("/time_panel:TimePanelBlueprint:play_state")
    return {
        "timeline": cells.get("/time_panel:TimePanelBlueprint:timeline"),
        "play_state": {1: "paused", 2: "playing", 3: "following"}.get(play_state, play_state),
        "views": {v.get("name", view_id): v for view_id, v in views.items()},
    }


def _query_path(query: str, origin: str) -> str:
    """``+ /a/b`` or ``$origin/**`` as an entity path without the leading slash (``a/b``, ``<origin>/**``)."""
    path = query.strip().removeprefix("+").strip().replace("$origin", f"/{origin}" if origin else "")
    return path.lstrip("/")


def _plain(array: Any, i: int = 0) -> Any:
    """Element ``i`` of an arrow array as plain Python, keeping which variant a union holds
    (``{"CursorRelative": -1000}``, ``{"Infinite": None}``): pyarrow's union scalars lose the variant of a null."""
    import pyarrow as pa

    kind = array.type
    if pa.types.is_union(kind):
        code = array.type_codes[i].as_py()
        child = list(kind.type_codes).index(code)
        value = array.field(child)
        return {kind.field(child).name: _plain(value, array.offsets[i].as_py()) if len(value) else None}
    if pa.types.is_struct(kind):
        return {kind.field(j).name: _plain(field, i) for j, field in enumerate(array.flatten())}
    if pa.types.is_list(kind) or pa.types.is_fixed_size_list(kind) or pa.types.is_large_list(kind):
        values = array[i].values
        return [_plain(values, j) for j in range(len(values))]
    return array[i].as_py()


# --------------------------------------------------------------------------------------------------- screenshots
def screenshot(recording: str | Path, out: str | Path, port: int = 9877, settle_s: float = 5.0,
               env_step: int | None = None) -> Path:  # fmt: skip
    """Save a PNG of Rerun's own viewer showing ``recording`` on its stored layout, with no display.

    Spawns the viewer that ships with rerun-sdk headless (``rerun --headless``, 1920x1080) on ``port``, opens the
    file, waits ``settle_s`` seconds for it to load and draw, optionally moves the time cursor to ``env_step`` (by
    default the viewer stays where the layout opens it: the end), saves the screenshot and quits. Needs a Vulkan
    driver; on a machine without a GPU Mesa's lavapipe renders on the CPU (``apt-get install mesa-vulkan-drivers``,
    ``WGPU_BACKEND=vulkan``). Raises :class:`~hrtc.errors.HRTCError` when the viewer cannot start or draw.
    """
    import os
    import shutil
    import sys
    import time

    from rerun.experimental import ViewerClient

    from hrtc.errors import HRTCError

    recording, out = Path(recording).resolve(), Path(out).resolve()
    beside = Path(sys.executable).parent / "rerun"  # the viewer binary in this environment's bin/
    executable = str(beside) if beside.exists() else shutil.which("rerun")
    if executable is None:
        raise HRTCError("no `rerun` viewer executable (it ships with rerun-sdk: is the environment's bin/ on PATH?)")
    os.environ.setdefault("WGPU_BACKEND", "vulkan")
    try:
        viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True, executable_path=executable)
    except Exception as error:
        raise HRTCError(f"could not start a headless Rerun viewer: {error}") from error
    try:
        time.sleep(2.0)  # the viewer's gRPC server comes up
        viewer.open(str(recording))
        time.sleep(settle_s)
        if env_step is not None:
            viewer.set_time("env_step", sequence=int(env_step), play_state="paused")
            time.sleep(1.0)
        out.parent.mkdir(parents=True, exist_ok=True)
        viewer.save_screenshot(str(out))
    except Exception as error:
        raise HRTCError(f"the headless Rerun viewer could not show {recording}: {error}") from error
    finally:
        viewer.quit()
    return out
