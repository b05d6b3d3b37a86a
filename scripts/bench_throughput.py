"""Training throughput of HRTC against PPO on raw actions, side by side: interleaved repetitions on one machine.

    python scripts/bench_throughput.py [--task cartpole_swingup] [--steps 20000] [--repeats 3]

Each configuration runs ``scripts/train.py`` for ``--steps`` env steps with evaluation off (one evaluation at step 0
is all), in the order A B C A B C ... so that slow phases of a noisy machine hit every configuration alike. Reports
the median training-loop env steps/s (``charts/SPS`` of train.csv) and each configuration's ratio to PPO (Beta).
Writes ``throughput.json`` and ``throughput.md`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]

CONFIGS = {
    "ppo_beta": ["algo=ppo", "dist=beta"],
    "hrtc_beta (decision every 5 steps, the task's setting)": ["algo=hrtc", "dist=beta"],
    "hrtc_beta (decision every step)": ["algo=hrtc", "dist=beta", "algo.decision_every=1"],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="cartpole_swingup")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/cartpole_swingup_core")
    parser.add_argument("--runs", type=Path, default=ROOT / "runs/bench_throughput")
    args = parser.parse_args()
    sps: dict[str, list[float]] = {name: [] for name in CONFIGS}
    for rep in range(args.repeats):
        for i, (name, overrides) in enumerate(CONFIGS.items()):
            run_dir = args.runs / f"{i}-rep{rep}"
            cmd = [sys.executable, str(ROOT / "scripts/train.py"), f"task={args.task}", f"steps={args.steps}",
                   f"eval_every={10 * args.steps}", "eval_episodes=1", "progress=false", "ppo.num_steps=250",
                   f"checkpoint_every={10 * args.steps}", f"hydra.run.dir={run_dir}", *overrides]  # fmt: skip
            subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            value = float(pd.read_csv(run_dir / "train.csv")["charts/SPS"].median())
            sps[name].append(value)
            print(f"rep {rep} {name}: {value:.0f} env steps/s", flush=True)
    reference = np.median(sps["ppo_beta"])
    lines = [
        f"# Training throughput on {args.task}: {args.steps} env steps a run, {args.repeats} interleaved repetitions",
        "",
        "Same rollout size in decisions for all (250 per env, 2 envs in worker processes); env steps/s of the"
        " training loop (rollout and update), median of per-update values, then median over repetitions.",
        "",
        "| configuration | env steps/s per repetition | median | ratio to ppo_beta |",
        "|---|---|---|---|",
    ]
    for name, values in sps.items():
        lines.append(f"| {name} | {', '.join(f'{v:.0f}' for v in values)} | {np.median(values):.0f} "
                     f"| {np.median(values) / reference:.2f} |")  # fmt: skip
    lines += ["", f"Command: python scripts/bench_throughput.py {' '.join(sys.argv[1:])}"]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.md").write_text("\n".join(lines) + "\n")
    (args.out / "throughput.json").write_text(json.dumps({"steps": args.steps, "sps": sps}, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
