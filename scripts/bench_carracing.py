"""Learning curves on CarRacing (the paper's Table 1 setting): HRTC (Beta weights over the five static intents)
and PPO (Beta) on raw actions, side by side, with the same encoder and PPO settings, for a wall-time budget.

    python scripts/bench_carracing.py [--minutes 30] [--seed 1] [--out benchmarks/results/carracing]
    python scripts/bench_carracing.py --report-only   # rebuild table.md and curves.png from the runs in --out

Both runs are the real CLI (``scripts/train.py task=carracing``) in subprocesses started together (so they share
the machine's load), niced, and stopped with SIGINT (the trainer saves a checkpoint) when the budget is spent.
Every finished episode is logged by the environment itself (``env_kwargs.episode_log``: return, frames); the
trainer's evaluation episodes (seeds from ``hrtc.trainer.eval_seeds``) are told apart by their reset seed.
The solve rules are applied to the training episodes in the order they finished: the paper's (a mean return of
900 over 10 consecutive tracks) and gym's (over 100). The projection to the paper's budget uses the measured
frames per second of each run. Writes results.json, table.md, curves.png, command.txt, machine.txt into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TASK = "carracing"
SOLVE = 900.0
PAPER_WINDOW, GYM_WINDOW = 10, 100
# The paper's Table 1: episodes until solved (mean over its trials) for the two methods compared here.
PAPER_EPISODES = {"hrtc-beta": 1824, "ppo-beta": 2914}
PAPER_CUTOFF = 10_000  # the paper calls a run failed after 10,000 tracks
RUNS = {"hrtc-beta": ["algo=hrtc", "dist=beta"], "ppo-beta": ["algo=ppo", "dist=beta"]}
LOG_COLUMNS = ["wall_time", "pid", "reset_seed", "return", "frames", "lap_finished"]


def solved_at(returns: np.ndarray, window: int, threshold: float = SOLVE) -> int | None:
    """The 1-based episode at which the mean of the last ``window`` returns first reaches ``threshold``."""
    if len(returns) < window:
        return None
    means = np.convolve(returns, np.ones(window) / window, mode="valid")
    hit = np.flatnonzero(means >= threshold)
    return int(hit[0]) + window if len(hit) else None


def best_window_mean(returns: np.ndarray, window: int) -> float | None:
    if len(returns) < window:
        return None
    return float(np.convolve(returns, np.ones(window) / window, mode="valid").max())


def start_run(name: str, seed: int, out: Path, steps: int) -> tuple[subprocess.Popen, Path]:
    run_dir = out / "runs" / name
    run_dir.mkdir(parents=True, exist_ok=True)
    log = run_dir / "episodes.csv"
    log.unlink(missing_ok=True)
    cmd = ["nice", "-n", "5", sys.executable, str(ROOT / "scripts" / "train.py"), f"task={TASK}", f"seed={seed}",
           f"steps={steps}", "progress=false", f"hydra.run.dir={run_dir}", f"+task.env_kwargs.episode_log={log}",
           *RUNS[name]]  # fmt: skip
    (run_dir / "command.txt").write_text(" ".join(cmd) + "\n")
    (run_dir / "started.txt").write_text(f"{time.time():.3f}\n")
    stdout = open(run_dir / "stdout.txt", "w")  # noqa: SIM115  (closed with the process)
    # SIGINT back to its default in the child: a shell's background job inherits it ignored, and then Python
    # would not turn it into the KeyboardInterrupt that makes the trainer save and stop.
    restore = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # noqa: E731
    return subprocess.Popen(cmd, cwd=ROOT, stdout=stdout, stderr=subprocess.STDOUT, preexec_fn=restore), run_dir


def run_all(args: argparse.Namespace) -> None:
    procs = {name: start_run(name, args.seed, args.out, args.steps) for name in RUNS}
    deadline = time.time() + 60 * args.minutes
    loads = []
    while time.time() < deadline and any(p.poll() is None for p, _ in procs.values()):
        time.sleep(min(30.0, max(0.0, deadline - time.time())))
        loads.append(os.getloadavg()[0])
        counts = {name: _episodes(run_dir).shape[0] for name, (_, run_dir) in procs.items()}
        print(f"  {time.strftime('%H:%M:%S')} load {loads[-1]:.1f} episodes {counts}", flush=True)
    for proc, _ in procs.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # the trainer saves a checkpoint and closes its workers
    for proc, _ in procs.values():
        try:
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
    (args.out / "load.json").write_text(json.dumps({"loadavg_1min_every_30s": loads}))


def _episodes(run_dir: Path) -> pd.DataFrame:
    path = run_dir / "episodes.csv"
    if not path.exists() or path.stat().st_size == 0:
        return pd.DataFrame(columns=LOG_COLUMNS)
    return pd.read_csv(path, names=LOG_COLUMNS)


def summarise(name: str, run_dir: Path, seed: int, minutes: float) -> dict:
    """The run's training episodes that finished within ``minutes`` of its start, and the solve rules on them."""
    from hrtc.episodes import eval_seeds

    started = float((run_dir / "started.txt").read_text())
    log = _episodes(run_dir)
    log = log[log["wall_time"] <= started + 60 * minutes]  # a run may finish an episode while it is being stopped
    evaluation = log["reset_seed"].isin(eval_seeds(seed, 10_000))
    train = log[~evaluation].sort_values("wall_time")
    returns = train["return"].to_numpy(float)
    wall = float(log["wall_time"].max() - started) if len(log) else 0.0  # process start to the last finished episode
    frames = int(log["frames"].sum())  # training and evaluation frames: what the run simulated
    evals = pd.read_csv(run_dir / "eval.csv") if (run_dir / "eval.csv").exists() else pd.DataFrame()
    fps = frames / wall if wall > 0 else float("nan")
    paper_episodes = PAPER_EPISODES[name]
    return {
        "episodes": len(returns),
        "returns": returns.tolist(),
        "frames": frames,
        "wall_seconds": wall,
        "frames_per_second": fps,
        "last10_mean": float(returns[-10:].mean()) if len(returns) >= 10 else None,
        "best10_mean": best_window_mean(returns, PAPER_WINDOW),
        "best100_mean": best_window_mean(returns, GYM_WINDOW),
        "solved_paper_rule_at": solved_at(returns, PAPER_WINDOW),
        "solved_gym_rule_at": solved_at(returns, GYM_WINDOW),
        "eval": {
            "train_episodes": evals.get("train_episodes", pd.Series(dtype=float)).tolist(),
            "episode_reward": evals.get("episode_reward", pd.Series(dtype=float)).tolist(),
        },  # fmt: skip
        "projected_hours_to_paper_episodes": paper_episodes * 1000 / fps / 3600 if fps == fps else None,
        "projected_hours_to_10000_episodes": PAPER_CUTOFF * 1000 / fps / 3600 if fps == fps else None,
        "paper_episodes_to_solve": paper_episodes,
    }


def write_report(results: dict, args: argparse.Namespace, command: str) -> None:
    out = args.out
    (out / "results.json").write_text(json.dumps(results, indent=1))
    if not args.report_only:  # keep the command and machine of the runs themselves
        (out / "command.txt").write_text(command + "\n")
        (out / "machine.txt").write_text(_machine())
    load = json.loads((out / "load.json").read_text())["loadavg_1min_every_30s"] if (out / "load.json").exists() else []
    lines = [
        f"# CarRacing learning curves: HRTC (Beta) vs PPO (Beta), seed {args.seed}, {args.minutes:g} min wall each",
        "",
        "Both runs side by side on the same machine (2 cores shared with other jobs; 1-minute load average during "
        f"the runs: median {np.median(load) if load else float('nan'):.1f}), the same encoder and PPO settings "
        "(`hrtc/conf/task/carracing.yaml`), action repeat 8. Returns are gymnasium's, per training track (1000 "
        "frames at most). Solve rules: the paper's (mean 900 over 10 consecutive tracks) and gym's (over 100).",
        "",
        "| method | tracks | frames | wall (min) | frames/s | last-10 mean | best 10-mean | best 100-mean | "
        "solved (paper rule) | solved (gym rule) | paper: tracks to solve | projected h to the paper's tracks | "
        "projected h to 10,000 tracks |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results["runs"].items():
        lines.append(
            f"| {name} | {r['episodes']} | {r['frames']:,} | {r['wall_seconds'] / 60:.1f} | "
            f"{r['frames_per_second']:.0f} | {_fmt(r['last10_mean'])} | {_fmt(r['best10_mean'])} | "
            f"{_fmt(r['best100_mean'])} | {_solved(r['solved_paper_rule_at'])} | {_solved(r['solved_gym_rule_at'])} | "
            f"{r['paper_episodes_to_solve']} | {_fmt(r['projected_hours_to_paper_episodes'], 1)} | "
            f"{_fmt(r['projected_hours_to_10000_episodes'], 1)} |"
        )
    for name, r in results["runs"].items():
        evals = ", ".join(
            f"{e:.0f} after {n:.0f} tracks"
            for n, e in zip(r["eval"]["train_episodes"], r["eval"]["episode_reward"], strict=True)
        )
        lines.append(f"\nEvaluations of {name} (deterministic: the Beta mean, 5 tracks): {evals or 'none'}.")
    lines += [
        "",
        "Projected hours: the paper's episodes-to-solve (Table 1 mean) x 1000 frames at this run's measured "
        "frames/s (training and evaluation, two env workers, PPO updates included) on this shared machine.",
        *(f"\n{note}" for note in results.get("notes", [])),
        "",
        "![curves](curves.png)",
    ]
    (out / "table.md").write_text("\n".join(lines) + "\n")
    _plot(results, out / "curves.png")


def _fmt(value: float | None, digits: int = 0) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _solved(at: int | None) -> str:
    return "not reached" if at is None else f"track {at}"


def _plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for (name, r), colour in zip(results["runs"].items(), ("tab:blue", "tab:orange"), strict=False):
        returns = np.asarray(r["returns"])
        if not len(returns):
            continue
        episodes = np.arange(1, len(returns) + 1)
        ax.plot(episodes, returns, color=colour, alpha=0.25, lw=0.8)
        if len(returns) >= PAPER_WINDOW:
            mean = np.convolve(returns, np.ones(PAPER_WINDOW) / PAPER_WINDOW, mode="valid")
            ax.plot(episodes[PAPER_WINDOW - 1 :], mean, color=colour, lw=2, label=f"{name}: mean of 10 tracks")
        if r["eval"]["train_episodes"]:
            ax.plot(r["eval"]["train_episodes"], r["eval"]["episode_reward"], "o--", color=colour, ms=4,
                    label=f"{name}: evaluation (distribution mean)")  # fmt: skip
    ax.axhline(SOLVE, color="k", ls=":", lw=1, label="solved: 900")
    ax.set_xlabel("training track (episode)")
    ax.set_ylabel("return")
    ax.set_title("CarRacing: HRTC (Beta, 5 static intents) vs PPO (Beta), same encoder")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _machine() -> str:
    import torch

    return (
        f"{platform.platform()}\npython {platform.python_version()}, torch {torch.__version__}, "
        f"cpus {os.cpu_count()}, torch threads per run 1, 2 env workers per run\n"
        f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="wall-time budget of the runs (run together)")
    parser.add_argument("--steps", type=int, default=250_000, help="decision budget (the task's default)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "carracing")
    parser.add_argument("--report-only", action="store_true", help="summarise existing runs in --out")
    parser.add_argument("--note", action="append", default=[], help="a note for table.md (repeatable; kept by "
                        "later --report-only calls)")  # fmt: skip
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    command = "python scripts/bench_carracing.py " + " ".join(sys.argv[1:])
    if not args.report_only:
        run_all(args)
    runs = {name: summarise(name, args.out / "runs" / name, args.seed, args.minutes) for name in RUNS}
    previous = args.out / "results.json"
    notes = json.loads(previous.read_text()).get("notes", []) if args.report_only and previous.exists() else []
    results = {"seed": args.seed, "minutes": args.minutes, "runs": runs, "notes": notes + args.note}
    write_report(results, args, command)
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()
