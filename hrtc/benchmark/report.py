"""From raw evaluation curves to the paper's Table 1 and Fig. 2: solutions, collapses and robust statistics.

A run *solves* the task at its first evaluation whose mean return (over the rule's deterministic episodes) reaches
the threshold; its cost is the env steps (and training episodes) spent by then. It *collapses* when, after solving,
``collapse_window`` consecutive evaluations fall below the threshold. A run that never solves is censored: its cost
is "more than the budget", kept as ``inf`` so that order statistics (median, IQM, fastest) stay exact, while the mean
and std, which cannot handle censoring, are taken over the solved runs only and say how many those are.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

LABELS = {
    "hrtc_beta": "HRTC Beta (PPO)",
    "hrtc_beta_sac": "HRTC Beta (SAC learner)",
    "hrtc_normal": "HRTC Normal (PPO)",
    "ppo_beta": "PPO Beta",
    "ppo_normal": "PPO Normal",
    "sb3_ppo": "SB3 PPO",
    "sb3_sac": "SB3 SAC",
    "sb3_td3": "SB3 TD3",
    "sb3_a2c": "SB3 A2C",
    "sb3_sac_composed": "SB3 SAC on ComposedEnv",
}


@dataclass(frozen=True)
class SolveRule:
    """When a run counts as solved: the mean of ``episodes`` deterministic evaluation episodes reaches
    ``threshold``; collapsed: afterwards ``collapse_window`` consecutive evaluations below it."""

    threshold: float
    episodes: int
    collapse_window: int = 3


@dataclass(frozen=True)
class Outcome:
    """One run judged by a :class:`SolveRule`. Costs are None when the run did not solve within its budget."""

    solved_step: int | None
    solved_episode: int | None
    solved_wall: float | None
    collapse_step: int | None
    final: float
    best: float

    @property
    def solved(self) -> bool:
        return self.solved_step is not None

    @property
    def collapsed(self) -> bool:
        return self.collapse_step is not None


# --------------------------------------------------------------------------------------------------- per run
def first_solve(values: Sequence[float], threshold: float) -> int | None:
    """Index of the first value at or above ``threshold``, or None."""
    hits = np.flatnonzero(np.asarray(values, dtype=float) >= threshold)
    return int(hits[0]) if hits.size else None


def find_collapse(values: Sequence[float], threshold: float, window: int) -> int | None:
    """Index of the evaluation that completes the first run of ``window`` consecutive values below ``threshold``
    after the first solve, or None (never solved, or never fell below for that long)."""
    return _collapse_after(values, threshold, window, first_solve(values, threshold))


def _collapse_after(values: Sequence[float], threshold: float, window: int, start: int | None) -> int | None:
    if start is None:
        return None
    below = 0
    for i in range(start + 1, len(values)):
        below = below + 1 if values[i] < threshold else 0
        if below >= window:
            return i
    return None


def outcome(result: Mapping[str, Any], rule: SolveRule) -> Outcome:
    """Judge one run. The solve decision reads ``solve_reward`` (the mean over the rule's episodes, None where an
    evaluation did not pass the screen) when the curve has it; collapses read the evaluation curve itself."""
    curve = result["curve"]
    values = curve["episode_reward"]
    decide = curve.get("solve_reward") or values
    i = first_solve([-math.inf if v is None else v for v in decide], rule.threshold)
    c = _collapse_after(values, rule.threshold, rule.collapse_window, i)
    return Outcome(
        solved_step=None if i is None else int(curve["step"][i]),
        solved_episode=None if i is None else int(curve["episodes"][i]),
        solved_wall=None if i is None else float(curve["wall_seconds"][i]),
        collapse_step=None if c is None else int(curve["step"][c]),
        final=float(values[-1]),
        best=float(max(values)),
    )


# --------------------------------------------------------------------------------------------------- statistics
def iqm(values: Sequence[float]) -> float:
    """Interquartile mean: the mean of the middle half, dropping ``floor(n/4)`` values at each end (as
    ``scipy.stats.trim_mean(x, 0.25)`` and rliable do). ``inf`` entries (unsolved runs) sort last."""
    x = np.sort(np.asarray(values, dtype=float))
    k = int(0.25 * x.size)
    return float(np.mean(x[k : x.size - k]))


def median(values: Sequence[float]) -> float:
    """The median; with an even count the mean of the middle two (``inf`` when either is)."""
    return float(np.median(np.asarray(values, dtype=float)))


def bootstrap_ci(
    values: Sequence[float],
    statistic: Callable[[Sequence[float]], float],
    level: float = 0.95,
    resamples: int = 5_000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``statistic`` (resampling runs with replacement).

    The bounds are order statistics of the resampled statistic (no interpolation), so an ``inf`` (censored) value
    yields an ``inf`` bound instead of a NaN. With few runs the interval is wide and approximate: it is the spread
    the data allow, not a guarantee of coverage."""
    x = np.asarray(values, dtype=float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(resamples, x.size))
    stats = np.array([statistic(x[row]) for row in idx])
    alpha = (1.0 - level) / 2
    lo, hi = np.quantile(stats, [alpha, 1.0 - alpha], method="inverted_cdf")
    return float(lo), float(hi)


@dataclass(frozen=True)
class Summary:
    """Costs to solution of one algorithm over its seeds (``inf`` for an unsolved run)."""

    costs: tuple[float, ...]
    solved: int
    collapses: int
    mean: float  # over solved runs; NaN when none solved
    std: float
    median: float
    median_ci: tuple[float, float]
    iqm: float
    iqm_ci: tuple[float, float]


def summarize(costs: Sequence[float], collapses: int) -> Summary:
    x = np.asarray(costs, dtype=float)
    finite = x[np.isfinite(x)]
    return Summary(
        costs=tuple(float(c) for c in x),
        solved=int(finite.size),
        collapses=collapses,
        mean=float(finite.mean()) if finite.size else math.nan,
        std=float(finite.std(ddof=1)) if finite.size > 1 else math.nan,  # sample std, as tables usually give
        median=median(x),
        median_ci=bootstrap_ci(x, median),
        iqm=iqm(x),
        iqm_ci=bootstrap_ci(x, iqm),
    )


def fastest_counts(costs: Mapping[str, Mapping[int, float]]) -> dict[str, int]:
    """Per seed, the algorithm(s) with the lowest finite cost get one count (ties: each); unsolved seeds none."""
    counts = dict.fromkeys(costs, 0)
    seeds = sorted({s for per_seed in costs.values() for s in per_seed})
    for seed in seeds:
        row = {a: c[seed] for a, c in costs.items() if seed in c and math.isfinite(c[seed])}
        if row:
            best = min(row.values())
            for a, c in row.items():
                counts[a] += int(c == best)
    return counts


# --------------------------------------------------------------------------------------------------- the table
def analyse(runs: Mapping[str, Mapping[str, Any]], rule: SolveRule) -> dict[str, dict[int, Outcome]]:
    """Outcomes by algorithm and seed, algorithms in the order they first appear."""
    out: dict[str, dict[int, Outcome]] = {}
    for result in runs.values():
        out.setdefault(result["algo"], {})[int(result["seed"])] = outcome(result, rule)
    return {a: dict(sorted(o.items())) for a, o in out.items()}


def cost_table(outcomes: Mapping[str, Mapping[int, Outcome]], unit: str) -> dict[str, dict[int, float]]:
    """Cost to solution (``unit``: "steps" or "episodes"), ``inf`` where unsolved."""
    attr = "solved_step" if unit == "steps" else "solved_episode"
    return {
        a: {s: math.inf if getattr(o, attr) is None else float(getattr(o, attr)) for s, o in per_seed.items()}
        for a, per_seed in outcomes.items()
    }


def _num(x: float, budget: float | None = None) -> str:
    if math.isnan(x):
        return "n/a"
    if math.isinf(x):
        return f"> {budget:,.0f}" if budget else "not solved"
    return f"{x:,.0f}"


def _ci(ci: tuple[float, float], budget: float | None) -> str:
    return f"[{_num(ci[0], budget)}, {_num(ci[1], budget)}]"


def markdown_table(outcomes: Mapping[str, Mapping[int, Outcome]], unit: str, budget: float | None) -> list[str]:
    """The paper's Table 1 shape: a row per seed, then collapses, fastest solutions, mean ± std, median and IQM
    with 95% bootstrap CIs. ``budget`` (in ``unit``) labels censored values; None when it varies (episodes)."""
    costs = cost_table(outcomes, unit)
    algos = list(outcomes)
    fastest = fastest_counts(costs)
    sums = {a: summarize(list(costs[a].values()), sum(o.collapsed for o in outcomes[a].values())) for a in algos}
    lines = [
        "| seed | " + " | ".join(LABELS.get(a, a) for a in algos) + " |",
        "|---" * (len(algos) + 1) + "|",
    ]
    for seed in sorted({s for a in algos for s in outcomes[a]}):
        cells = []
        for a in algos:
            o = outcomes[a].get(seed)
            if o is None:
                cells.append("")
                continue
            cell = "—" if not o.solved else _num(costs[a][seed])
            cell += f" (best {o.best:.0f})" if not o.solved else (" †" if o.collapsed else "")
            cells.append(cell)
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    best_median = min(sums[a].median for a in algos)
    best_iqm = min(sums[a].iqm for a in algos)

    def bold(text: str, flag: bool) -> str:
        return f"**{text}**" if flag else text

    rows = {
        "solved": [f"{sums[a].solved}/{len(sums[a].costs)}" for a in algos],
        "collapses †": [str(sums[a].collapses) for a in algos],
        "fastest solution": [str(fastest[a]) for a in algos],
        "mean ± std (solved runs)": [
            "—" if sums[a].solved == 0 else f"{_num(sums[a].mean)} ± {_num(sums[a].std)}" for a in algos
        ],
        "median [95% CI]": [
            bold(f"{_num(sums[a].median, budget)}", math.isfinite(best_median) and sums[a].median == best_median)
            + f" {_ci(sums[a].median_ci, budget)}"
            for a in algos
        ],
        "IQM [95% CI]": [
            bold(f"{_num(sums[a].iqm, budget)}", math.isfinite(best_iqm) and sums[a].iqm == best_iqm)
            + f" {_ci(sums[a].iqm_ci, budget)}"
            for a in algos
        ],
    }
    lines += [f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows.items()]
    return lines


def headline(
    outcomes: Mapping[str, Mapping[int, Outcome]], reference: str = "hrtc_beta", budget: float | None = None
) -> list[str]:
    """Whether ``reference`` needs fewer env steps than every other algorithm (by median and IQM) with lower
    spread (the IQR of the costs, unsolved as inf), stated for each rival where it does not hold."""
    if reference not in outcomes:
        return [f"{reference} was not run: no headline."]
    costs = cost_table(outcomes, "steps")
    ref = np.asarray(list(costs[reference].values()))
    ref_med, ref_iqm, ref_iqr = median(ref), iqm(ref), _iqr(ref)
    wins, losses = [], []
    for algo in outcomes:
        if algo == reference:
            continue
        x = np.asarray(list(costs[algo].values()))
        med, mean_iq, spread = median(x), iqm(x), _iqr(x)
        # Faster: no worse by either statistic and better by one (both infinite is a tie, not a win).
        faster = ref_med <= med and ref_iqm <= mean_iq and (ref_med < med or ref_iqm < mean_iq)
        tighter = ref_iqr < spread or (math.isinf(spread) and math.isfinite(ref_iqr))
        label = LABELS.get(algo, algo)
        facts = f"median {_num(med, budget)}, IQM {_num(mean_iq, budget)}, IQR {_spread(spread)}"
        (wins if faster and tighter else losses).append(f"{label} ({facts})")
    ref_label = LABELS.get(reference, reference)
    lines = [
        f"{ref_label}: env steps to solve, median {_num(ref_med, budget)}, IQM {_num(ref_iqm, budget)}, "
        f"IQR {_spread(ref_iqr)} (an unsolved run counts as needing infinitely many steps)."
    ]
    if not wins and not losses:
        lines.append("No other algorithm ran in this table: no headline (compare with the references and the other "
                     "tables of this task).")  # fmt: skip
    elif not losses:
        lines.append(f"**Headline holds**: {ref_label} needs fewer env steps to solve than every other algorithm, "
                     "by median and IQM, with a smaller interquartile range.")  # fmt: skip
    else:
        lines.append(f"**Headline does not fully hold.** {ref_label} is faster (median and IQM) with a smaller "
                     f"spread than: {', '.join(wins) or 'none'}.")  # fmt: skip
        lines.append(f"Not against: {', '.join(losses)}.")
    return lines + untrained_solutions(outcomes)


def untrained_solutions(outcomes: Mapping[str, Mapping[int, Outcome]]) -> list[str]:
    """A line per algorithm with runs that met the rule at env step 0, before any update: their steps-to-solve
    measure the starting policy (for HRTC: the skill library at the initial weights), not learning."""
    lines = []
    for algo, per_seed in outcomes.items():
        at_start = sorted(seed for seed, o in per_seed.items() if o.solved_step == 0)
        if at_start:
            lines.append(
                f"{LABELS.get(algo, algo)}: {len(at_start)} of {len(per_seed)} runs (seed{'s' * (len(at_start) > 1)} "
                f"{', '.join(map(str, at_start))}) met the rule at step 0, before any update: for them the table "
                "measures the starting policy, not learning."
            )
    return lines


def _spread(iqr_value: float) -> str:
    return "unbounded (a quarter or more unsolved)" if math.isinf(iqr_value) else _num(iqr_value)


def _iqr(x: np.ndarray) -> float:
    q1, q3 = np.quantile(np.asarray(x, dtype=float), [0.25, 0.75], method="inverted_cdf")
    return float(q3 - q1) if math.isfinite(q3) else math.inf


# --------------------------------------------------------------------------------------------------- outputs
def write_report(results: Mapping[str, Any], out: Path, rule: SolveRule) -> str:
    """Write ``table.md``, ``curves.png`` and ``summary.json`` (the table's numbers: each run's outcome and each
    algorithm's statistics, machine-readable) into ``out`` from a results dict (results.json's content)."""
    runs = results["runs"]
    outcomes = analyse(runs, rule)
    budget = int(results["budget"])
    task = results["task"]
    final_n = int(results.get("final_episodes") or 0)
    expected = results.get("expected_runs") or len(results["seeds"]) * len(results.get("algos", outcomes))
    present = sum(len(o) for o in outcomes.values())
    lines = [
        f"# {task}: env steps and episodes until solution (the paper's Table 1)",
        "",
        *(
            [f"**Partial: {present} of {expected} runs finished**; the same command continues the rest.", ""]
            if present < expected
            else []
        ),
        f"Solved: the mean return of {rule.episodes} deterministic evaluation episodes (seeds disjoint from training)"
        f" reaches **{rule.threshold:g}**{_screen_note(results, rule)}; evaluations every {results['eval_every']:,}"
        " env steps; budget "
        f"{budget:,} env steps per run; seeds {results['seeds']}. **†** collapsed: after solving, "
        f"{rule.collapse_window} consecutive evaluations below {rule.threshold:g} (counted in the statistics, "
        "unlike the paper, which omitted collapsed runs). — : not solved within the budget (best evaluation in "
        "brackets). Bold: the lowest. CIs: percentile bootstrap over seeds, 5,000 resamples.",
        "",
        "## Env steps until solution",
        "",
        *markdown_table(outcomes, "steps", budget),
        "",
        "## Training episodes until solution",
        "",
        *markdown_table(outcomes, "episodes", None),
        "",
        "## Headline",
        "",
        *headline(outcomes, reference=str(results.get("algos", ["hrtc_beta"])[0]), budget=budget),
        "",
        "## Per algorithm",
        "",
        f"| algorithm | last evaluation, median [min, max] | final policy over {final_n} episodes, median [min, max]"
        " | best evaluation, median | lowest evaluation after first solving, per seed | wall time per run, median |"
        " wall time to solution, median (solved runs) | train env steps/s, median | settings |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for algo, per_seed in outcomes.items():
        finals = [o.final for o in per_seed.values()]
        mine = {int(r["seed"]): r for r in runs.values() if r["algo"] == algo}
        walls = [r["wall_seconds"] for r in mine.values()]
        solve_walls = [o.solved_wall for o in per_seed.values() if o.solved_wall is not None]
        settings = next(r["settings"] for r in mine.values())
        policy_finals = [float(np.mean(r["final_returns"])) for r in mine.values() if r.get("final_returns")]
        lows = [_lowest_after_solve(mine[seed]["curve"], rule.threshold) for seed in sorted(mine)]
        sps = [r["train_sps"] for r in mine.values() if r.get("train_sps") is not None]
        lines.append(
            f"| {LABELS.get(algo, algo)} | {np.median(finals):.0f} [{min(finals):.0f}, {max(finals):.0f}] "
            f"| {_median_range(policy_finals)} "
            f"| {np.median([o.best for o in per_seed.values()]):.0f} "
            f"| {', '.join('—' if v is None else f'{v:.0f}' for v in lows)} | {np.median(walls):.0f} s "
            f"| {f'{np.median(solve_walls):.0f} s' if solve_walls else '—'} "
            f"| {f'{np.median(sps):.0f}' if sps else '—'} | {settings} |"
        )
    lines += ["", "Wall times are from a shared, loaded machine (machine.txt): compare them only roughly."]
    lines += throughput_lines(runs, list(outcomes))
    from hrtc.benchmark.studies import study_lines

    lines += study_lines(results, rule, out)
    base = results.get("final_seed_base")
    where = "evaluation seeds" if base is None else f"seeds {base:,} + 1000 seed + k"
    seed = results.get("reference_seed", 1)
    if seed == "runs":
        where += f" of every run seed ({', '.join(map(str, results['seeds']))}), one after the other"
    else:
        where += f" of seed {seed}"
    lines += reference_lines(results.get("references"), where)
    lines += ["", "Notes:", *(f"- {note}" for note in results["notes"])] if results.get("notes") else []
    text = "\n".join(lines) + "\n"
    (out / "table.md").write_text(text)
    (out / "summary.json").write_text(json.dumps(summary(outcomes, rule), indent=1))
    plot_curves(runs, rule, out / "curves.png", title=f"{task}: median and interquartile band over seeds",
                episodes=int(results.get("eval_episodes", rule.episodes)))  # fmt: skip
    return text


def throughput_lines(runs: Mapping[str, Mapping[str, Any]], algos: Sequence[str]) -> list[str]:
    """Each algorithm's training env steps/s (the median over its runs) relative to the first algorithm's."""
    sps = {a: [r["train_sps"] for r in runs.values() if r["algo"] == a and r.get("train_sps")] for a in algos}
    sps = {a: float(np.median(v)) for a, v in sps.items() if v}
    if len(sps) < 2 or algos[0] not in sps:
        return []
    ratios = ", ".join(f"{LABELS.get(a, a)} {v / sps[algos[0]]:.2f}" for a, v in sps.items())
    return ["", f"Training env steps/s relative to {LABELS.get(algos[0], algos[0])} (medians over runs): {ratios}."]


def _median_range(values: list[float]) -> str:
    return f"{np.median(values):.0f} [{min(values):.0f}, {max(values):.0f}]" if values else "—"


def _lowest_after_solve(curve: Mapping[str, Any], threshold: float) -> float | None:
    """The lowest evaluation after the first one reaching ``threshold`` (None if none reached it): a collapse shows."""
    values = list(curve["episode_reward"])
    first = next((i for i, v in enumerate(values) if v >= threshold), None)
    return None if first is None else float(min(values[first:]))


def reference_lines(references: Mapping[str, Any] | None, seeds: str = "evaluation seeds of seed 1") -> list[str]:
    """The references table: each rule over the task's skills (each skill alone, the untrained blend, declared hand
    rules), mean and std of its returns on the evaluation seeds."""
    if not references:
        return []
    if isinstance(next(iter(references.values())), dict):  # the success metric's summaries
        from hrtc.benchmark.studies import success_table

        return ["", "## References over the same skills (no learning)", "", *success_table(references)]
    n = len(next(iter(references.values())))
    lines = ["", f"## References over the same skills ({n} episodes each, {seeds})", "",
             "| rule | mean return | std |", "|---|---|---|"]  # fmt: skip
    lines += [f"| {name} | {np.mean(v):.1f} | {np.std(v):.1f} |" for name, v in references.items()]
    return lines


def summary(outcomes: Mapping[str, Mapping[int, Outcome]], rule: SolveRule) -> dict[str, Any]:
    """Each run's outcome and each algorithm's statistics in env steps and episodes (``inf``: not solved)."""
    out: dict[str, Any] = {"rule": vars(rule), "runs": {}, "algorithms": {}}
    for algo, per_seed in outcomes.items():
        for seed, o in per_seed.items():
            out["runs"][f"{algo}/seed{seed}"] = {**vars(o), "solved": o.solved, "collapsed": o.collapsed}
        out["algorithms"][algo] = {}
        for unit in ("steps", "episodes"):
            costs = cost_table({algo: per_seed}, unit)[algo]
            collapses = sum(o.collapsed for o in per_seed.values())
            out["algorithms"][algo][unit] = vars(summarize(list(costs.values()), collapses))
        out["algorithms"][algo]["fastest_steps"] = fastest_counts(cost_table(outcomes, "steps"))[algo]
    return out


def _screen_note(results: Mapping[str, Any], rule: SolveRule) -> str:
    screen = int(results.get("eval_episodes", rule.episodes))
    if screen >= rule.episodes:
        return ""
    rest = rule.episodes - screen
    return (f" (each evaluation runs {screen} episodes, which draw the curves; when their mean reaches the "
            f"threshold, the same policy runs the other {rest} at once and the {rule.episodes} decide)")  # fmt: skip


def _grid_curve(x: Sequence[float], y: Sequence[float], grid: np.ndarray) -> np.ndarray:
    """``y(x)`` interpolated onto ``grid``, NaN outside the run's range; repeated x keep their last value."""
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.append(xs[1:] != xs[:-1], True)  # last of each run of equal x
    xs, ys = xs[keep], ys[keep]
    out = np.interp(grid, xs, ys)
    out[(grid < xs[0]) | (grid > xs[-1])] = np.nan
    return out


def plot_curves(
    runs: Mapping[str, Mapping[str, Any]], rule: SolveRule, path: Path, title: str, episodes: int | None = None
) -> None:
    """Fig. 2 in this project's terms: evaluation return (the mean of ``episodes`` deterministic episodes per
    evaluation) against env steps and against training episodes, the median over seeds with the interquartile band
    (25th-75th percentile)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_algo: dict[str, list[Mapping[str, Any]]] = {}
    for r in runs.values():
        by_algo.setdefault(r["algo"], []).append(r["curve"])
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharey=True)
    for ax, key, xlabel in ((axes[0], "step", "env steps"), (axes[1], "episodes", "training episodes")):
        top = max(max(c[key]) for curves in by_algo.values() for c in curves)
        grid = np.linspace(0, top, 201)
        for i, (algo, curves) in enumerate(by_algo.items()):
            ys = np.array([_grid_curve(c[key], c["episode_reward"], grid) for c in curves])
            enough = np.sum(np.isfinite(ys), axis=0) >= max(1, len(curves) // 2 + 1)  # most seeds reach this x
            with warnings.catch_warnings():  # columns no seed reaches are all-NaN: masked out below
                warnings.simplefilter("ignore", RuntimeWarning)
                q25, q50, q75 = np.nanpercentile(ys, [25, 50, 75], axis=0)
            style = {"lw": 2.2} if algo == "hrtc_beta" else {"lw": 1.3}
            label = f"{LABELS.get(algo, algo)} (n={len(curves)})"
            ax.plot(grid[enough], q50[enough], color=f"C{i}", label=label, **style)
            ax.fill_between(grid[enough], q25[enough], q75[enough], color=f"C{i}", alpha=0.15)
        ax.axhline(rule.threshold, color="k", ls="--", lw=1, label=f"solve threshold {rule.threshold:g}")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"evaluation return (mean of {episodes or rule.episodes} deterministic episodes)")
    axes[1].legend(fontsize=8, loc="best")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cpu_model(cpuinfo: str | None = None) -> str:
    """The processor where Linux says it: its model name, family and model numbers, and the bfloat16 matrix
    instructions it has (float results of the same seed differ between CPU models, and a model name such as "AMD
    EPYC" covers several generations: family 25 is Zen 3-4, 26 Zen 5); else the architecture."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            if fields:
                break  # the first processor's block is enough
            continue
        fields.setdefault(key.strip(), value.strip())
    if "model name" not in fields:
        return platform.processor() or platform.machine()
    line = f"{platform.machine()} {fields['model name']}"
    numbers = [f"{name} {fields[key]}" for key, name in (("cpu family", "family"), ("model", "model")) if key in fields]
    flags = [f for f in ("amx_bf16", "avx512_bf16") if f in fields.get("flags", "").split()]
    details = ", ".join(numbers) + ("; " if numbers and flags else "") + " ".join(flags)
    return f"{line} ({details})" if details else line


def machine_info() -> str:
    """One line describing this machine (and the Ray cluster, if one is connected)."""
    import torch

    line = (
        f"{platform.platform()}; python {platform.python_version()}; {os.cpu_count()} cores; torch {torch.__version__};"
        f" {_cpu_model()}; date {time.strftime('%Y-%m-%d %H:%M')}; load average"
        f" {os.getloadavg()[0]:.1f} at the start"
    )
    try:
        import ray

        line += f"; ray {ray.__version__}"
    except ImportError:
        line += "; ray not installed (process pool)"
    return line + "\n"
