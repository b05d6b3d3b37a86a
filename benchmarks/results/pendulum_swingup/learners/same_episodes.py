"""The pendulum's episodes differ a lot (the start angle sets how long the swing-up takes: the NMPC alone scores 668 to
1000 on the ten of seed 1), so a learner is compared with the references on the *same* episodes: each rule over the
skills on the final-evaluation episodes of every run seed 1-5 (the table's references use seed 1's only), beside
each learner's final policy on those episodes (from results.json).

    python benchmarks/results/pendulum_swingup/learners/same_episodes.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[3]))

from hrtc.benchmark.main import check, parse, references  # noqa: E402
from hrtc.cli import task_config  # noqa: E402

if __name__ == "__main__":
    args = check(parse(["benchmark=pendulum_swingup"]))
    task = {"name": "pendulum_swingup", **task_config("pendulum_swingup")}
    results = json.loads((HERE / "results.json").read_text())
    seeds = results["seeds"]
    rows: dict[str, list[float]] = {}
    for seed in seeds:  # a path that does not exist: nothing stored is reused
        for name, returns in references(task, {**args, "reference_seed": seed}, HERE / "none.json", [seed]).items():
            rows.setdefault(name, []).append(float(np.mean(returns)))
    for algo in results["algos"]:
        rows[algo] = [float(np.mean(results["runs"][f"{algo}/seed{s}"]["final_returns"])) for s in seeds]
    print("| | " + " | ".join(f"seed {s}" for s in seeds) + f" | mean over the {10 * len(seeds)} episodes |")
    print("|---|" + "---|" * (len(seeds) + 1))
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:.1f}" for v in values) + f" | {np.mean(values):.1f} |")
