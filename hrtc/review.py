"""Offline review of a run's skill activations, from its recording alone.

``load(path)`` reads a run directory's recording segments (or one ``.rrd``) back with rerun-sdk's reader;
``summarize`` gives, per evaluation episode, each skill's mean weight, its share of decisions as the dominant skill
and its mean alpha + beta; ``plot_activations`` draws, per episode, the weights over time with the dominant skill
shaded, the task's key state quantity under them (``task.key_state``: the pole angle, the altitude...) and alpha +
beta, each skill in its colour (:mod:`hrtc.logging.palette`, the same as in the viewer).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from hrtc.errors import HRTCError
from hrtc.logging.trace import weight_summary


@dataclass(frozen=True)
class Review:
    """A recording's evaluation episodes.

    ``episodes``: one row per episode (``episode``, ``return``, ``length``, ``global_step``, ``seed``); ``steps``: one
    row per decision (``episode``, ``env_step``, ``weights`` (K,), ``alpha``/``beta`` (K,) or None, ``key``: the
    task's key state quantity after the decision, NaN if not recorded); ``skill_names``; ``key_state``: the key
    state's name (None if the recording has none).
    """

    episodes: pd.DataFrame
    steps: pd.DataFrame
    skill_names: tuple[str, ...]
    paths: tuple[Path, ...]
    key_state: str | None = None


def recording_paths(path: str | Path) -> list[Path]:
    """The ``.rrd`` files of ``path``: itself if it is a file, else the run directory's segments in order."""
    from hrtc.logging.rerun_sink import segment_paths

    path = Path(path)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise HRTCError(f"{path} is neither a run directory nor a .rrd file")
    paths = segment_paths(path)
    if not paths:
        raise HRTCError(f"no recording*.rrd in {path} (was it run with logger.mode=off?)")
    return paths


def load(path: str | Path) -> Review:
    """Read the evaluation episodes of a run directory (all its segments) or of one ``.rrd`` file."""
    from hrtc.logging.rerun_sink import read_recording

    paths = recording_paths(path)
    try:
        steps = read_recording(paths, contents="/meta/**", index="env_step")
        episodes = read_recording(paths, contents="/eval/episode/**", index="episode")
    except (OSError, RuntimeError, ValueError) as error:
        raise HRTCError(f"cannot read {', '.join(map(str, paths))}: {error}") from error
    if episodes.empty or steps.empty or "/meta/weights" not in steps:
        raise HRTCError(f"{path} holds no finished evaluation episode yet")
    names_column = steps.get("/meta/weights:SeriesLines:names")
    names = tuple(next((list(v) for v in names_column if v is not None), [])) if names_column is not None else ()
    steps = steps[steps["/meta/weights"].notna()]
    table = pd.DataFrame({
        "episode": steps["episode"].astype(int).to_numpy(),
        "env_step": steps["env_step"].astype(int).to_numpy(),
        "weights": [np.asarray(w, dtype=np.float64) for w in steps["/meta/weights"]],
        "alpha": _cells(steps, "/meta/alpha"),
        "beta": _cells(steps, "/meta/beta"),
    })  # fmt: skip
    key_state, key = _key_state(paths)
    if key is not None:
        table = table.merge(key, on=["episode", "env_step"], how="left")
    else:
        table["key"] = np.nan
    episode_table = pd.DataFrame({"episode": episodes["episode"].astype(int).to_numpy()})
    for key in ("return", "length", "global_step", "seed"):
        column = episodes.get(f"/eval/episode/{key}")
        cells = column if column is not None else [None] * len(episode_table)
        episode_table[key] = [float(v[0]) if v is not None else np.nan for v in cells]
    # A resumed run may have re-run an episode index; the later segment's rows win.
    episode_table = episode_table.drop_duplicates("episode", keep="last").sort_values("episode")
    table = table.drop_duplicates(["episode", "env_step"], keep="last")
    table = table[table["episode"].isin(episode_table["episode"])].sort_values(["episode", "env_step"])
    if not names:
        names = tuple(f"w{k}" for k in range(len(table["weights"].iloc[0])))
    return Review(episode_table.reset_index(drop=True), table.reset_index(drop=True), names, tuple(paths), key_state)


def _key_state(paths: list[Path]) -> tuple[str | None, pd.DataFrame | None]:
    """The recorded key state (``state/<name>``): its name and a table ``episode``, ``env_step``, ``key``."""
    from hrtc.logging.rerun_sink import read_recording

    frame = read_recording(paths, contents="/state/**", index="env_step")
    columns = [c for c in frame.columns if c.startswith("/state/") and ":" not in c]
    if frame.empty or not columns:
        return None, None
    frame = frame[frame[columns[0]].notna()]
    key = pd.DataFrame({
        "episode": frame["episode"].astype(int).to_numpy(),
        "env_step": frame["env_step"].astype(int).to_numpy(),
        "key": [float(v[0]) for v in frame[columns[0]]],
    })  # fmt: skip
    return columns[0].removeprefix("/state/"), key.drop_duplicates(["episode", "env_step"], keep="last")


def _cells(frame: pd.DataFrame, column: str) -> list:
    if column not in frame:
        return [None] * len(frame)
    return [np.asarray(v, dtype=np.float64) if v is not None else None for v in frame[column]]


def summarize(review: Review) -> pd.DataFrame:
    """One row per episode: ``episode``, ``global_step``, ``return``, and per skill ``<name>/mean_weight``,
    ``<name>/dominant_share``, ``<name>/mean_alpha_plus_beta`` (see :func:`hrtc.logging.trace.weight_summary`)."""
    rows = []
    for _, episode in review.episodes.iterrows():
        part = review.steps[review.steps["episode"] == episode["episode"]]
        if part.empty:
            continue
        weights = np.stack(part["weights"].to_list())
        has_beta = part["alpha"].iloc[0] is not None
        alpha = np.stack(part["alpha"].to_list()) if has_beta else None
        beta = np.stack(part["beta"].to_list()) if has_beta else None
        row = {"episode": int(episode["episode"]), "global_step": episode["global_step"], "return": episode["return"]}
        for name, stats in weight_summary(weights, alpha, beta, review.skill_names).items():
            row.update({f"{name}/{key}": value for key, value in stats.items()})
        rows.append(row)
    return pd.DataFrame(rows)


def format_summary(summary: pd.DataFrame, skill_names: tuple[str, ...]) -> str:
    """The summary as a text table: per skill ``mean weight / dominant share / mean alpha+beta``."""
    header = f"{'episode':>7} {'step':>8} {'return':>8}  " + "  ".join(f"{n[:22]:>22}" for n in skill_names)
    lines = [header, f"{'':>7} {'':>8} {'':>8}  " + "  ".join(f"{'w / dom / a+b':>22}" for _ in skill_names)]
    for _, row in summary.iterrows():
        cells = []
        for name in skill_names:
            confidence = row[f"{name}/mean_alpha_plus_beta"]
            conf = f"{confidence:6.1f}" if np.isfinite(confidence) else "     -"
            cells.append(f"{row[f'{name}/mean_weight']:5.2f} / {row[f'{name}/dominant_share']:4.0%} / {conf}")
        lines.append(f"{int(row['episode']):>7} {row['global_step']:>8.0f} {row['return']:>8.1f}  "
                     + "  ".join(f"{c:>22}" for c in cells))  # fmt: skip
    return "\n".join(lines)


def pick_episodes(review: Review, max_panels: int = 6) -> list[int]:
    """Episodes worth a panel: the first, the best, the last, and evenly spaced ones between."""
    episodes = review.episodes["episode"].to_list()
    if len(episodes) <= max_panels:
        return episodes
    best = int(review.episodes.loc[review.episodes["return"].idxmax(), "episode"])
    chosen = {episodes[0], episodes[-1], best}
    for index in np.linspace(0, len(episodes) - 1, max_panels).round().astype(int):
        if len(chosen) >= max_panels:
            break
        chosen.add(episodes[index])
    return sorted(chosen)


def dominant_spans(weights: np.ndarray, x: np.ndarray) -> list[tuple[float, float, int]]:
    """Runs of decisions with the same dominant skill (largest weight, ties to the first): ``(start, end, k)`` in the
    units of ``x`` (T,), each run ending where the next begins. ``weights`` (T, K)."""
    dominant = np.argmax(weights, axis=1)
    change = np.flatnonzero(np.diff(dominant)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(dominant)]])
    edges = np.concatenate([[x[0] - (x[1] - x[0] if len(x) > 1 else 1)], x])  # decision t acts over (x[t-1], x[t]]
    return [(float(edges[a]), float(edges[b]), int(dominant[a])) for a, b in zip(starts, ends, strict=True)]


def plot_activations(review: Review, path: str | Path, max_panels: int = 6) -> Path:
    """``activations.png``: per chosen episode, titled with its return, three rows against env steps: each skill's
    weight with the dominant skill shaded, the task's key state quantity (when recorded) and alpha + beta (Beta
    policies), each skill in its :func:`~hrtc.logging.palette.skill_colors` colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hrtc.logging.palette import mpl, skill_colors

    colors = [mpl(c) for c in skill_colors(review.skill_names)]
    chosen = pick_episodes(review, max_panels)
    has_key = bool(review.steps["key"].notna().any())
    has_beta = review.steps["alpha"].map(lambda a: a is not None).any()
    rows = ["weights", *(["key"] if has_key else []), *(["confidence"] if has_beta else [])]
    ratios = {"weights": 2.0, "key": 1.2, "confidence": 1.0}
    fig, axes = plt.subplots(len(chosen) * len(rows), 1, sharex=True, squeeze=False,
                             figsize=(10, 0.6 + len(chosen) * sum(ratios[r] for r in rows) * 1.05),
                             gridspec_kw={"height_ratios": [ratios[r] for r in rows] * len(chosen)})  # fmt: skip
    info = review.episodes.set_index("episode")
    for i, episode in enumerate(chosen):
        panel = dict(zip(rows, axes[i * len(rows) : (i + 1) * len(rows), 0], strict=True))
        part = review.steps[review.steps["episode"] == episode]
        weights = np.stack(part["weights"].to_list())
        x = part["env_step"].to_numpy() - _episode_start(review, episode)  # env steps into the episode
        spans = dominant_spans(weights, x)
        for name in rows:
            if name == "confidence":
                continue
            for start, end, k in spans:
                panel[name].axvspan(start, end, color=colors[k], alpha=0.13, lw=0)
        ax = panel["weights"]
        for k, name in enumerate(review.skill_names):
            ax.plot(x, weights[:, k], label=name, lw=1.4, color=colors[k])
        row = info.loc[episode]
        ax.set_title(f"episode {episode} (policy at step {row['global_step']:.0f}): return {row['return']:.1f}; "
                     f"shading: the dominant skill", fontsize=9, loc="left")  # fmt: skip
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel("weight")
        if has_key:
            key = part["key"].to_numpy(dtype=np.float64)
            if np.nanmax(np.abs(key)) <= np.pi + 1e-9:  # an angle wrapping at +-pi: break the line, don't draw a jump
                key = np.where(np.concatenate([[False], np.abs(np.diff(key)) > np.pi]), np.nan, key)
            panel["key"].plot(x, key, color="black", lw=1.2)
            panel["key"].set_ylabel(review.key_state or "key state", fontsize=8)
        if has_beta:
            confidence = np.stack(part["alpha"].to_list()) + np.stack(part["beta"].to_list())
            for k in range(len(review.skill_names)):
                panel["confidence"].plot(x, confidence[:, k], color=colors[k], lw=1.1)
            panel["confidence"].set_ylim(bottom=2.0)  # alpha, beta >= 1: a flat line at the floor is no confidence
            panel["confidence"].set_ylabel("alpha + beta", fontsize=8)
        for a in panel.values():
            a.grid(alpha=0.3)
            a.margins(x=0)
    axes[0, 0].legend(loc="upper right", ncol=len(review.skill_names), fontsize=8)
    axes[-1, 0].set_xlabel("env steps into the episode")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)  # scripts/review.py --out may name a folder still to be made
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _episode_start(review: Review, episode: int) -> int:
    """The env step at which ``episode`` began on the recording's ``env_step`` axis: the end of the previous one + 1
    (episodes are laid end to end), or its first decision's step less one decision's length for the first."""
    steps = review.steps
    before = steps[steps["episode"] < episode]
    if not before.empty and int(before["episode"].max()) == episode - 1:
        return int(before["env_step"].max()) + 1
    part = steps[steps["episode"] == episode]["env_step"].to_numpy()
    return int(part[0] - (part[1] - part[0])) if len(part) > 1 else int(part[0]) - 1
