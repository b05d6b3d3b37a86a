"""The cost of the Rerun recording, side by side: the same training run with ``logger.mode=off`` and with the
default recording (``save``: evaluation traces, frames, training metrics), interleaved.

    python scripts/bench_recording.py [--task cartpole_swingup] [--steps 50000] [--pairs 3]

Runs pairs in alternating order (off/on, on/off, ...) so slow phases of a noisy machine hit both alike, and reports
each pair's ratio of wall times (the whole ``scripts/train.py`` process, and the training loop alone) and of CPU
time (the process and its env workers: robust to other jobs on a shared machine), their medians,
the recording's size, and writes ``results.json``, ``table.md``, ``command.txt`` and ``machine.txt`` into ``--out``.
The target: recording on takes at most 1.10x the wall time of recording off.
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def run(task: str, steps: int, logger: str, run_dir: Path) -> dict:
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), f"task={task}", f"steps={steps}", "progress=false",
           f"logger.mode={logger}", f"hydra.run.dir={run_dir}"]  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)  # train.py and its env workers, once reaped
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    loop = float(re.search(r"done: \d+ steps in (\d+) s", out.stdout).group(1))
    size = sum(p.stat().st_size for p in run_dir.glob("recording*.rrd"))
    return {"wall_seconds": wall, "cpu_seconds": cpu, "loop_seconds": loop, "recording_bytes": size,
            "run_dir": str(run_dir)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="cartpole_swingup")
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/cartpole_swingup/recording_cost")
    parser.add_argument("--runs", type=Path, default=ROOT / "runs/bench_recording")
    args = parser.parse_args()
    pairs = []
    for i in range(args.pairs):
        order = ["off", "save"] if i % 2 == 0 else ["save", "off"]
        result = {mode: run(args.task, args.steps, mode, args.runs / f"pair{i}-{mode}") for mode in order}
        ratio = result["save"]["wall_seconds"] / result["off"]["wall_seconds"]
        loop_ratio = result["save"]["loop_seconds"] / max(result["off"]["loop_seconds"], 1.0)
        cpu_ratio = result["save"]["cpu_seconds"] / result["off"]["cpu_seconds"]
        pairs.append({"order": order, **result, "ratio": ratio, "loop_ratio": loop_ratio, "cpu_ratio": cpu_ratio})
        print(f"pair {i} ({'/'.join(order)}): off {result['off']['wall_seconds']:.1f} s, "
              f"save {result['save']['wall_seconds']:.1f} s, ratio {ratio:.3f}", flush=True)  # fmt: skip
    ratios = [p["ratio"] for p in pairs]
    size_mb = float(np.median([p["save"]["recording_bytes"] for p in pairs]) / 1e6)
    summary = {"task": args.task, "steps": args.steps, "pairs": pairs, "median_ratio": float(np.median(ratios)),
               "median_loop_ratio": float(np.median([p["loop_ratio"] for p in pairs])),
               "median_cpu_ratio": float(np.median([p["cpu_ratio"] for p in pairs])),
               "median_recording_mb": size_mb}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(summary, indent=2))
    lines = [f"# Cost of the Rerun recording: {args.task}, {args.steps} env steps, default settings", "",
             "| pair | order | off (s) | recording (s) | wall ratio | loop ratio | CPU ratio | recording size (MB) |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for i, p in enumerate(pairs):
        lines.append(f"| {i} | {'/'.join(p['order'])} | {p['off']['wall_seconds']:.1f} | "
                     f"{p['save']['wall_seconds']:.1f} | {p['ratio']:.3f} | {p['loop_ratio']:.3f} | "
                     f"{p['cpu_ratio']:.3f} | "
                     f"{p['save']['recording_bytes'] / 1e6:.1f} |")  # fmt: skip
    lines += ["", f"**Median ratio (whole process): {summary['median_ratio']:.3f}** (target <= 1.10); training loop "
              f"alone {summary['median_loop_ratio']:.3f}; CPU time (train.py and its workers) "
              f"{summary['median_cpu_ratio']:.3f}; recording {size_mb:.1f} MB."]  # fmt: skip
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    (args.out / "command.txt").write_text(" ".join(["python", *sys.argv]) + "\n")
    from hrtc.benchmark.report import machine_info

    (args.out / "machine.txt").write_text(machine_info())
    print("\n".join(lines))


if __name__ == "__main__":
    main()
