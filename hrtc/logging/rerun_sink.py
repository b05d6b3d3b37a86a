"""The Rerun recording of a run: the only module that imports rerun.

Entities (a skill's config name is its entity name):

- per decision of every evaluation episode, on timelines ``env_step`` (evaluation env steps laid end to end over
  the run: one monotone axis for the plots and the video) and ``episode`` (the evaluation episode's index in the run):
  ``meta/weights`` (one series per skill), ``meta/alpha``, ``meta/beta``, ``meta/confidence`` (alpha + beta),
  ``meta/effective_weights`` (skill trees: every node's weight times its parents', one series per tree path),
  ``skills/<name>/action``, ``skills/<name>/<diagnostic>`` (solver status, solve time, cost, faults...),
  ``action/blended``, ``reward``, ``value``, and ``world/camera`` frames;
- per evaluation episode, on ``episode``: ``eval/episode/return``, ``eval/episode/length``,
  ``eval/episode/global_step`` (the training step of the policy that ran it), ``eval/episode/seed``;
- sampled training decisions (first training env) on ``global_step``: ``meta/weights``, ``meta/alpha``,
  ``meta/beta``, ``meta/confidence``;
- training metrics (``train.csv``'s columns) as ``train/<name>`` on ``update`` and ``global_step``; evaluation rows as
  ``eval/<name>`` on ``global_step``;
- static: ``tree`` (the skill library as text) and the series names.

Per-step data is buffered for an episode and sent as columns when it ends (``send_columns``: 0.2 ms for 1000 steps,
against 0.13 ms per ``log`` call), so recording costs little next to the episode itself.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import rerun as rr
import rerun.blueprint as rrb

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


def blueprint(skill_names: Sequence[str], frames: bool = True) -> rrb.Blueprint:
    """Weights and confidence above the video and the actions; training curves and skills in their own tabs."""
    top = rrb.Horizontal(
        rrb.TimeSeriesView(origin="meta/weights", name="skill weights"),
        rrb.TimeSeriesView(origin="meta/confidence", name="confidence (alpha + beta)"),
        rrb.TimeSeriesView(origin="meta/effective_weights", name="effective weights (skill trees)"),
    )
    actions = rrb.TimeSeriesView(
        origin="/", contents=["action/**", *[f"skills/{n}/action" for n in skill_names]], name="proposals and blend"
    )
    returns = rrb.TimeSeriesView(origin="/", contents=["reward", "value"], name="reward and value")
    bottom = (
        rrb.Horizontal(rrb.Spatial2DView(origin="world/camera", name="camera"), actions, returns)
        if frames
        else (rrb.Horizontal(actions, returns))
    )
    evaluation = rrb.Vertical(top, bottom, name="evaluation")
    training = rrb.Grid(
        rrb.TimeSeriesView(origin="eval", name="evaluation returns"),
        rrb.TimeSeriesView(origin="train/train", name="training returns"),
        rrb.TimeSeriesView(origin="train/losses", name="losses"),
        rrb.TimeSeriesView(origin="train/charts", name="charts"),
        name="training",
    )
    skills = rrb.Horizontal(
        rrb.TextDocumentView(origin="tree", name="skill tree"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"skills/{n}", name=n) for n in skill_names]),
        name="skills",
    )
    return rrb.Blueprint(rrb.Tabs(evaluation, training, skills), collapse_panels=True)


class RerunSink:
    """A :class:`~hrtc.logging.Sink` and :class:`~hrtc.logging.trace.Recorder` writing ``<run_dir>/recording.rrd``.

    ``skill_names``: the weight vector's components (HRTC) or action names (PPO); ``tree``: the skill library as
    text; ``resume``: continue a run in a new segment ``recording.<n>.rrd`` whose episode and env-step counters carry
    on from the earlier segments.
    """

    def __init__(self, run_dir: str | Path, cfg: RecordingConfig, skill_names: Sequence[str], action_dim: int,
                 tree: str = "", resume: bool = False, recording_id: str | None = None,
                 tree_paths: Sequence[str] = ()) -> None:  # fmt: skip
        self.cfg, self.skill_names, self.action_dim = cfg, tuple(skill_names), int(action_dim)
        # Nested skills (an HRTC policy as a skill): every node's effective weight gets a series.
        self.tree_paths = tuple(tree_paths) if len(tree_paths) > len(self.skill_names) else ()
        run_dir = Path(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        previous = segment_paths(run_dir) if resume else []
        self.path = run_dir / (f"recording.{len(previous)}.rrd" if previous else "recording.rrd")
        self.episode, self.env_step = _counters(previous)
        recording_id = recording_id or str(uuid.uuid5(uuid.NAMESPACE_URL, str(run_dir.resolve())))
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self._connect(blueprint(self.skill_names, cfg.frames))
        self.global_step, self.updates, self._eval_index = 0, 0, 0
        self._frames_this_eval = False
        self._samples: list[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]] = []
        self._log_static(tree)

    def _connect(self, bp: rrb.Blueprint) -> None:
        mode, path = self.cfg.mode, str(self.path)
        if mode == "save":
            self.rec.save(path, default_blueprint=bp)
            return
        url = self.cfg.url
        if mode == "spawn":
            port = 9876
            try:
                rr.spawn(port=port, connect=False, recording=self.rec)
            except Exception as error:  # no viewer binary or no display: keep the file, say so once
                log.warning("could not spawn a Rerun viewer (%s); recording to %s only", error, path)
                self.rec.save(path, default_blueprint=bp)
                return
            url = f"rerun+http://127.0.0.1:{port}/proxy"
        self.rec.set_sinks(rr.GrpcSink(url=url), rr.FileSink(path), default_blueprint=bp)

    def _log_static(self, tree: str) -> None:
        rec, names = self.rec, list(self.skill_names)
        for entity in ("meta/weights", "meta/alpha", "meta/beta", "meta/confidence"):
            rec.log(entity, rr.SeriesLines(names=names), static=True)
        if self.tree_paths:
            rec.log("meta/effective_weights", rr.SeriesLines(names=list(self.tree_paths)), static=True)
        actions = [f"a{i}" for i in range(self.action_dim)]
        rec.log("action/blended", rr.SeriesLines(names=actions), static=True)
        for name in self.skill_names:
            rec.log(f"skills/{name}/action", rr.SeriesLines(names=[f"{name}/{a}" for a in actions]), static=True)
        text = rr.TextDocument(tree or "(no skills: plain PPO)", media_type=rr.MediaType.MARKDOWN)
        rec.log("tree", text, static=True)

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
        rec.reset_time()
        if stream == "eval":
            rec.flush()  # an evaluation's episodes are on disk once it is reported: a killed run keeps them

    def close(self) -> None:
        self._flush_samples()
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
        self._frames_this_eval = self.cfg.frames and (last or self._eval_index % self.cfg.frame_evals_every == 0)
        self._eval_index += 1

    def begin(self, episode_in_eval: int, seed: int, render: Callable[[], np.ndarray | None] | None) -> EpisodeTrace:
        frames = self._frames_this_eval and episode_in_eval < self.cfg.frame_episodes and render is not None
        return EpisodeTrace(self.episode, int(seed), self.skill_names, self.cfg.frame_every if frames else 0, render)

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
        for name, diagnostics in trace.skill_info.items():
            for key, values in diagnostics.items():
                if len(values) == length:
                    self._columns(f"skills/{name}/{key}", index, np.asarray(values)[:, None])
        rec = self.rec
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
        rec.reset_time()
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


def stores(path: str | Path) -> dict[str, int]:
    """How many stores of each kind (``recording``, ``blueprint``) an ``.rrd`` file holds."""
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(str(path))
        return {"recording": len(reader.recordings()), "blueprint": len(reader.blueprints())}
