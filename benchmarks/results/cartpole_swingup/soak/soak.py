"""A long run with the recording on: resident memory and recording size sampled through it (issue 17, item 7).

    python benchmarks/results/cartpole_swingup/soak/soak.py [--steps 1000000] [--every 10] \\
        [--out benchmarks/results/cartpole_swingup/soak] [train.py overrides...]

Starts ``scripts/train.py task=cartpole_swingup`` in a fresh run directory, and every ``--every`` seconds samples the
resident memory of the run's process tree (the trainer and its vector-env workers, summed; each one's too), the size
of every ``.rrd`` file in the run directory and the env step the run has logged (the last row of train.csv). Writes
``soak.csv`` (one row per sample), ``soak.png`` (memory and recording size against env steps) and ``summary.json``
(fits of both: memory slope per 100k steps after the first 10 %, recording bytes per env step) into ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[4]


def last_step(run_dir: Path) -> int:
    """The env step of the newest train.csv row (0 before the first)."""
    path = run_dir / "train.csv"
    if not path.exists():
        return 0
    with path.open() as f:
        rows = f.read().strip().splitlines()
    return int(float(rows[-1].split(",")[0])) if len(rows) > 1 else 0


def sample(proc: psutil.Process, run_dir: Path) -> dict[str, float]:
    tree = [proc, *proc.children(recursive=True)]
    rss = []
    for p in tree:
        try:
            rss.append(p.memory_info().rss)
        except psutil.NoSuchProcess:
            pass
    rrd = sum(f.stat().st_size for f in run_dir.glob("*.rrd"))
    return {"env_step": last_step(run_dir), "rss_total_mb": sum(rss) / 2**20, "rss_trainer_mb": rss[0] / 2**20,
            "processes": len(rss), "rrd_mb": rrd / 2**20}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--every", type=float, default=10.0)
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/cartpole_swingup/soak"))
    parser.add_argument("--run-dir", default="/tmp/soak_run")
    args, overrides = parser.parse_known_args()
    out, run_dir = Path(args.out), Path(args.run_dir)
    if run_dir.exists() and any(run_dir.iterdir()):
        sys.exit(f"error: {run_dir} is not empty; pass another --run-dir")
    out.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "scripts/train.py", "task=cartpole_swingup", f"steps={args.steps}", "progress=false",
               f"hydra.run.dir={run_dir}", *overrides]
    child = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=open(out / "train.log", "w"))
    proc, start, rows = psutil.Process(child.pid), time.time(), []
    with (out / "soak.csv").open("w", newline="") as f:
        writer = None
        while child.poll() is None:
            try:
                row = {"wall_s": round(time.time() - start, 1), **sample(proc, run_dir)}
            except psutil.NoSuchProcess:
                break
            rows.append(row)
            writer = writer or csv.DictWriter(f, fieldnames=list(row))
            if f.tell() == 0:
                writer.writeheader()
            writer.writerow(row)
            f.flush()
            time.sleep(args.every)
    rows.append({"wall_s": round(time.time() - start, 1), "env_step": last_step(run_dir), "rss_total_mb": float("nan"),
                 "rss_trainer_mb": float("nan"), "processes": 0,
                 "rrd_mb": sum(p.stat().st_size for p in run_dir.glob("*.rrd")) / 2**20})
    summarize(rows, out, command, child.returncode)


def summarize(rows: list[dict], out: Path, command: list[str], returncode: int | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([r["env_step"] for r in rows], float)
    rss = np.array([r["rss_total_mb"] for r in rows], float)
    rrd = np.array([r["rrd_mb"] for r in rows], float)
    live = np.isfinite(rss) & (steps >= 0.1 * steps.max())
    mem_slope = float(np.polyfit(steps[live], rss[live], 1)[0] * 1e5) if live.sum() > 2 else float("nan")
    grown = steps > 0
    rrd_per_step = float(np.polyfit(steps[grown], rrd[grown], 1)[0] * 2**20) if grown.sum() > 2 else float("nan")
    summary = {"command": " ".join(command[1:]), "returncode": returncode, "env_steps": int(steps.max()),
               "wall_s": rows[-1]["wall_s"], "rss_total_mb_first": float(rss[np.isfinite(rss)][0]),
               "rss_total_mb_max": float(np.nanmax(rss)), "rss_total_mb_at_10pct": float(rss[live][0]) if live.any()
               else float("nan"), "rss_slope_mb_per_100k_steps_after_10pct": mem_slope,
               "rrd_mb_final": float(rrd[-1]), "rrd_bytes_per_env_step": rrd_per_step}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    fig, (a, b) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    a.plot(steps, rss, label="run (trainer + workers)")
    a.plot(steps, [r["rss_trainer_mb"] for r in rows], label="trainer")
    a.set_ylabel("resident memory (MiB)")
    a.legend()
    b.plot(steps, rrd)
    b.set_ylabel("recording .rrd (MiB)")
    b.set_xlabel("env steps")
    fig.suptitle(f"soak: {summary['command']}", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "soak.png", dpi=100)
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
