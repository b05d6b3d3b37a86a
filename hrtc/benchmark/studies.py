"""The sections of ``table.md`` a benchmark config asks for beyond the paper's Table 1 (:mod:`hrtc.benchmark.report`):

- ``final_best``: the final and the best evaluated policy of each run over ``final_episodes`` (LunarLander's
  100-episode means), with the steps to the threshold and the training throughput.
- ``thresholds`` and ``compare``: steps to each threshold, returns at the start, final, best and over the run; the
  ratio of two algorithms' median steps to each threshold (transfer: fine-tuned / from scratch; reuse).
- the ``success`` metric: success, collisions and time to reach on the unseen targets, per target family.
- the ``episodes`` metric: the solve rules over consecutive training episodes, frames per second, the projection to
  the paper's episodes-to-solve, and ``episodes.png``.
- ``trace``: the skill tree of an algorithm's task and every node's effective weight over one evaluation episode of
  its best run (``tree.txt``, ``tree_weights.csv``, ``tree_weights.png``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hrtc.benchmark.report import SolveRule, first_solve


def study_lines(results: Mapping[str, Any], rule: SolveRule, out: Path) -> list[str]:
    by_algo: dict[str, dict[int, Mapping[str, Any]]] = {}
    for r in results["runs"].values():
        by_algo.setdefault(r["algo"], {})[int(r["seed"])] = r
    by_algo = {a: dict(sorted(by_algo[a].items())) for a in results.get("algos", by_algo) if a in by_algo}
    lines: list[str] = []
    if results.get("final_best"):
        lines += final_best_lines(by_algo, rule, int(results.get("final_episodes") or 0))
    if results.get("thresholds") or results.get("compare"):
        lines += threshold_lines(by_algo, [rule.threshold, *results.get("thresholds", [])], results.get("compare", []))
    metric = results.get("metric") or {}
    if metric.get("name") == "success":
        rows = {f"{a}, seed {s}, {which}.pt": v for a, runs in by_algo.items() for s, r in runs.items()
                for which, v in r.get("success", {}).items()}  # fmt: skip
        lines += ["", "## Success on unseen targets", "", *success_table(rows)]
    if metric.get("name") == "episodes":
        lines += episodes_lines(by_algo, rule, metric, out)
    if results.get("trace") in by_algo:
        lines += trace_lines(by_algo[results["trace"]], out)
    return lines


def _join(values: Sequence[float | None], digits: int = 0) -> str:
    return ", ".join("-" if v is None or not math.isfinite(v) else f"{v:,.{digits}f}" for v in values)


def _steps_to(run: Mapping[str, Any], threshold: float) -> float:
    curve = run["curve"]
    i = first_solve(curve["episode_reward"], threshold)
    return math.inf if i is None else float(curve["step"][i])


def _median(values: Sequence[float]) -> float:
    return float(np.median(values)) if len(values) else math.nan


def _steps_text(value: float, budget: int) -> str:
    return f"{value:,.0f}" if math.isfinite(value) else f"not reached (> {budget:,})"


def final_best_lines(by_algo: Mapping[str, Mapping[int, Any]], rule: SolveRule, episodes: int) -> list[str]:
    t = f"{rule.threshold:g}"
    lines = ["", f"## The final and the best evaluated policy over {episodes} episodes", "",
             f"Each run's final policy and its best evaluated one (chosen on the periodic evaluations) over {episodes} "
             f"deterministic episodes on seeds disjoint from training and from the periodic evaluations. Steps to {t}:"
             " the first periodic evaluation at or above it.", "",
             f"| algorithm | seeds | final per seed | **median final** | best per seed | median best | steps to {t} per"
             f" seed | median steps to {t} | train env steps/s |", "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for algo, runs in by_algo.items():
        finals = [float(np.mean(r["final_returns"])) for r in runs.values() if r.get("final_returns")]
        bests = [float(np.mean(r["best_returns"])) for r in runs.values() if r.get("best_returns")]
        hits = [_steps_to(r, rule.threshold) for r in runs.values()]
        sps = [r["train_sps"] for r in runs.values() if r.get("train_sps") is not None]
        budget = max(r["steps"] for r in runs.values())
        lines.append(f"| {algo} | {len(runs)} | {_join(finals)} | **{_median(finals):.0f}** | {_join(bests)} "
                     f"| {_median(bests):.0f} | {_join(hits)} | {_steps_text(_median(hits), budget)} "
                     f"| {_median(sps):.0f} |")  # fmt: skip
    return lines


def threshold_lines(by_algo: Mapping[str, Mapping[int, Any]], thresholds: Sequence[float],
                    compare: Sequence[Sequence[str]]) -> list[str]:  # fmt: skip
    heads = " | ".join(f"steps to {t:g} per seed" for t in thresholds)
    lines = ["", "## Steps to each threshold", "", f"| run | task | return at 0 | final per seed | best per seed "
             f"| mean over the run | {heads} | wall s (median) | train env steps/s (median) |",
             "|---" * (8 + len(thresholds)) + "|"]  # fmt: skip
    medians: dict[str, list[float]] = {}
    budgets: dict[str, int] = {}
    for algo, runs in by_algo.items():
        vals = list(runs.values())
        curves = [r["curve"]["episode_reward"] for r in vals]
        budgets[algo] = max(r["curve"]["step"][-1] for r in vals)
        hits = [[_steps_to(r, t) for r in vals] for t in thresholds]
        medians[algo] = [_median(h) for h in hits]
        cells = [f"{_join(h)} (median {_steps_text(m, budgets[algo])})" for h, m in zip(hits, medians[algo],
                                                                                      strict=True)]  # fmt: skip
        sps = [r["train_sps"] for r in vals if r.get("train_sps") is not None]
        lines.append(f"| {algo} | {vals[0]['task']} | {_join([c[0] for c in curves])} "
                     f"| {_join([c[-1] for c in curves])} | {_join([max(c) for c in curves])} "
                     f"| {_join([float(np.mean(c)) for c in curves])} "
                     f"| {' | '.join(cells)} | {_median([r['wall_seconds'] for r in vals]):.0f} "
                     f"| {_median(sps):.0f} |")  # fmt: skip
    for a, b in (p for p in compare if p[0] in medians and p[1] in medians):
        for i, t in enumerate(thresholds):
            x, y = medians[a][i], medians[b][i]
            if math.isfinite(x) and math.isfinite(y):
                text = f"{x / y:.2f}" if y > 0 else "n/a (the second at 0)"
            elif math.isfinite(x):
                text = f"< {x / budgets[b]:.2f} ({b} did not reach {t:g} within {budgets[b]:,} steps)"
            else:
                text = f"not defined: {a} did not reach {t:g} within {budgets[a]:,} steps"
            lines.append(f"- median steps to {t:g}, {a} / {b}: **{text}**")
    return lines


def success_table(entries: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """A row per method: success, collisions, success without collision, mean time to reach, per target family."""
    lines = ["| method | targets | success | collisions | success without collision | mean time to reach (s) | "
             "success per family | collisions per family |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, entry in entries.items():
        s = entry["summary"]
        a = s["all"]
        families = [k for k in s if k != "all"]
        per = " / ".join(f"{s[f]['success']:.1%}" if s[f]["targets"] else "—" for f in families)
        hits = " / ".join(f"{s[f]['collision']:.1%}" if s[f]["targets"] else "—" for f in families)
        names = f" ({' / '.join(families)})" if families else ""
        lines.append(f"| {name} | {a['targets']} | {a['success']:.1%} | {a['collision']:.1%} | "
                     f"{a['success_without_collision']:.1%} | {a['mean_time_to_reach_s']:.2f} | {per or '—'}{names} "
                     f"| {hits or '—'} |")  # fmt: skip
    return lines


def episodes_lines(by_algo: Mapping[str, Mapping[int, Any]], rule: SolveRule, metric: Mapping[str, Any],
                   out: Path) -> list[str]:  # fmt: skip
    from hrtc.benchmark.metrics import best_window_mean, running_scores, running_solved_at, solved_at

    windows = [int(w) for w in metric.get("windows", [10, 100])]
    paper = dict(metric.get("paper_episodes") or {})
    cutoff = int(metric.get("cutoff", 10_000))
    heads = " | ".join(f"best {w}-mean | solved (mean {rule.threshold:g} over {w})" for w in windows)
    heads += f" | best running score | solved (running score > {rule.threshold:g})"
    heads += f" | solved (c): evaluations' true return >= {rule.threshold:g}, confirmed on more tracks"
    lines = ["", "## Training episodes", "", "Returns of every training episode in the order they finished (the "
             "trainer's evaluation episodes left out; a shaping task's shaped score, the one the learner saw, with "
             "gymnasium's own return beside); frames/s over training and evaluation, updates included. Running score: "
             "0.99 running + 0.01 score after each episode (the reference implementation's rule). Frames to a "
             "solution: the training frames up to that episode. Projected hours: the paper's episodes-to-solve x "
             "1000 frames at the measured frames/s.", "",
             f"| run | episodes | frames | wall (min) | frames/s | last-10 mean | last-10 true return | {heads} "
             f"| paper: episodes to solve | projected h to the paper's episodes | projected h to {cutoff:,} episodes |",
             "|---" * (13 + 2 * len(windows)) + "|"]  # fmt: skip
    plotted = {}
    for algo, runs in by_algo.items():
        for seed, r in runs.items():
            log = r.get("episodes_log")
            if not log:
                continue
            x = np.asarray(log["returns"], float)
            plotted[f"{algo} seed {seed}"] = (x, r["curve"])
            fps = log["frames_per_second"]
            frames_to = np.cumsum(log.get("train_frames") or np.zeros(len(x), int))
            cells = []
            for w in windows:
                best, at = best_window_mean(x, w), solved_at(x, w, rule.threshold)
                cells += ["n/a" if best is None else f"{best:.0f}", _reached(at, frames_to)]
            running = running_scores(x)
            cells += [f"{running.max():.0f}" if len(x) else "n/a",
                      _reached(running_solved_at(x, rule.threshold), frames_to),
                      _reached(true_solved_after(r["curve"], rule.threshold), frames_to)]  # fmt: skip
            ok = fps and math.isfinite(fps)
            last10 = f"{x[-10:].mean():.0f}" if len(x) >= 10 else "n/a"
            true10 = np.asarray(log.get("true_returns") or [math.nan], float)[-10:]
            last10 += f" | {true10.mean():.0f}" if len(x) >= 10 and np.isfinite(true10).all() else " | n/a"
            hours = [n * 1000 / fps / 3600 if ok else math.nan for n in (paper.get(algo), cutoff) if n is not None]
            lines.append(f"| {algo} seed {seed} | {len(x)} | {log['frames']:,} | {log['wall_seconds'] / 60:.1f} "
                         f"| {fps:.0f} | {last10} | {' | '.join(cells)} "
                         f"| {paper.get(algo, '—')} | {_join(hours[:-1] if algo in paper else [], 1) or '—'} "
                         f"| {hours[-1]:.1f} |")  # fmt: skip
    for name, (_, curve) in plotted.items():
        lines.append(f"\n{_evaluations_line(name, curve, rule.threshold)}")
    if plotted:
        _plot_episodes(plotted, rule.threshold, windows[0], out / "episodes.png")
        lines += ["", "![training episodes](episodes.png)"]
    return lines


def true_solved_after(curve: Mapping[str, Any], threshold: float) -> int | None:
    """Rule (c): the training episodes before the first evaluation whose true return, confirmed on all its tracks
    (the curve's ``true_solve_reward``), reaches ``threshold``; None when none did (or none was screened)."""
    confirmed = curve.get("true_solve_reward") or [None] * len(curve["episodes"])
    hits = (int(n) for n, v in zip(curve["episodes"], confirmed, strict=True) if v is not None and v >= threshold)
    return next(hits, None)


def _evaluations_line(name: str, curve: Mapping[str, Any], threshold: float) -> str:
    """A run's deterministic evaluations, with the task's own (true) return beside a shaped one where it was recorded,
    and rule (c): the evaluations' true return reaching ``threshold``, then confirmed on more tracks."""
    true = curve.get("true_reward") or [None] * len(curve["episode_reward"])
    confirmed = curve.get("true_solve_reward") or [None] * len(true)
    rows = zip(curve["episodes"], curve["episode_reward"], true, confirmed, strict=True)
    cells = [f"{e:.0f}" + ("" if t is None or abs(t - e) < 0.5 else f" (true {t:.0f})")
             + ("" if c is None else f" [more tracks: true {c:.0f}]") + f" after {n} episodes"
             for n, e, t, c in rows]  # fmt: skip
    line = f"Evaluations of {name} (deterministic: the distribution's mode): {', '.join(cells)}."
    recorded = [t for t in true if t is not None]
    if recorded:
        best = max(recorded)
        solved = true_solved_after(curve, threshold)
        if solved is not None:
            verdict = f"confirmed after {solved} episodes"
        elif best >= threshold:
            failed = [c for c in confirmed if c is not None]
            verdict = f"not confirmed on more tracks (best {max(failed):.0f})" if failed else "screen only: unconfirmed"
        else:
            verdict = "not reached"
        line += (f" Rule (c), the evaluations' true return >= {threshold:g}: best {best:.0f} over the "
                 f"{len(recorded)} evaluations that recorded it ({verdict}).")  # fmt: skip
    return line


def _reached(episode: int | None, frames_to: np.ndarray) -> str:
    """A solve rule's cell: the episode that reached it and the training frames up to it (when they were logged)."""
    if episode is None:
        return "not reached"
    return f"episode {episode}" + (f" ({frames_to[episode - 1]:,} frames)" if frames_to[-1] else "")


def _plot_episodes(plotted: Mapping[str, Any], threshold: float, window: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for i, (name, (x, curve)) in enumerate(plotted.items()):
        episodes = np.arange(1, len(x) + 1)
        ax.plot(episodes, x, color=f"C{i}", alpha=0.25, lw=0.8)
        if len(x) >= window:
            mean = np.convolve(x, np.ones(window) / window, mode="valid")
            ax.plot(episodes[window - 1 :], mean, color=f"C{i}", lw=2, label=f"{name}: mean of {window} episodes")
        ax.plot(curve["episodes"], curve["episode_reward"], "o--", color=f"C{i}", ms=4, label=f"{name}: evaluation")
    ax.axhline(threshold, color="k", ls=":", lw=1, label=f"solved: {threshold:g}")
    ax.set_xlabel("training episode")
    ax.set_ylabel("return")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trace_lines(runs: Mapping[int, Mapping[str, Any]], out: Path) -> list[str]:
    """The skill tree of the runs' task, and the effective weights over one evaluation episode of the best run."""
    from hrtc.cli import task_config
    from hrtc.composition import build_library
    from hrtc.tree import format_tree, skill_tree

    best = max(runs.values(), key=lambda r: max(r["curve"]["episode_reward"]))
    text = format_tree(skill_tree(build_library(task_config(best["task"])["skills"]), "meta", "meta-policy"))
    (out / "tree.txt").write_text(text + "\n")
    lines = ["", f"## The skill tree of {best['task']}", "", "```text", text, "```"]
    checkpoint = Path(best["run_dir"]) / "checkpoints" / "best.pt"
    if not checkpoint.exists():  # the runs' files stay on the machine that trained them
        return lines + ["", f"(no {checkpoint} here: the effective weights were not traced)"]
    frame = tree_trace(checkpoint)
    frame.to_csv(out / "tree_weights.csv", index=False)
    _plot_trace(frame, out / "tree_weights.png", f"{best['algo']} seed {best['seed']}")
    return lines + [
        "",
        f"Effective weights of every node over one evaluation episode of the best run ({best['algo']} "
        f"seed {best['seed']}, return {frame.attrs['return']:.0f}): tree_weights.png, tree_weights.csv.",
    ]


def tree_trace(checkpoint: Path, seed: int = 1_000_000) -> Any:
    """One deterministic episode of a trained tree: every node's effective weight and the task's key state per
    decision."""
    import pandas as pd

    from hrtc.benchmark.metrics import checkpoint_env
    from hrtc.checkpoint import load_policy
    from hrtc.cli import task_config
    from hrtc.episodes import mode_decider
    from hrtc.tree import effective_weights

    loaded = load_policy(checkpoint)
    env = checkpoint_env(loaded.meta)
    key = task_config(loaded.meta["task"]).get("key_state") or "pole_angle"
    decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])
    rows: list[dict] = []
    obs, _ = env.reset(seed=seed)
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(decide(obs).action)
        total, done = total + float(reward), terminated or truncated
        state = float(np.atleast_1d(env.unwrapped.skill_state()[key])[0])
        rows.append({"env_step": info["env_steps"], key: state,
                     **effective_weights(env.skill_names, info["weights"], info["skills"])})  # fmt: skip
    env.close()
    frame = pd.DataFrame(rows)
    frame.attrs["return"] = total
    return frame


def _plot_trace(frame: Any, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    key = frame.columns[1]
    cols = [c for c in frame.columns[2:]]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(3, 1))
    for i, col in enumerate(cols):
        ax.plot(frame["env_step"], frame[col], lw=1.6 - 0.5 * col.count("/"), color=f"C{i}", label=col,
                ls="-" if "/" not in col else "--")  # fmt: skip
    ax.set_ylabel("effective weight")
    ax.set_title(f"effective weight of every node (child x parent), one episode of {title}", fontsize=9)
    ax.legend(fontsize=7, ncol=3)
    ax2.plot(frame["env_step"], frame[key], color="k", lw=1)
    ax2.set_ylabel(key)
    ax2.set_xlabel("env step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
