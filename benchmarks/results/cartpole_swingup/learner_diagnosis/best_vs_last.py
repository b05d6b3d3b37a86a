"""A benchmark run's best.pt (the policy its evaluations picked) against its last.pt (the final policy), each on the
same 10 fresh episodes: seeds 2,000,000 + 1000 seed + k, disjoint from training and from the evaluations that picked
best.pt, so the selection's own luck does not count.

    PYTHONPATH=. python benchmarks/results/cartpole_swingup/learner_diagnosis/best_vs_last.py RUNS_DIR ALGO [OUT.json]

RUNS_DIR/ALGO/seed<N>/checkpoints/{best,last}.pt for every seed found there (the benchmark's runs_dir layout)."""

import json
import sys
from pathlib import Path

import numpy as np

from hrtc.benchmark.metrics import checkpoint_returns
from hrtc.benchmark.runs import episode_seeds


def main(runs_dir: str, algo: str, out: str | None = None) -> None:
    rows = {}
    seeds = sorted(int(p.name[4:]) for p in (Path(runs_dir) / algo).glob("seed*"))
    for seed in seeds:
        ckpt = Path(runs_dir) / algo / f"seed{seed}" / "checkpoints"
        episodes = episode_seeds(2_000_000, seed, 10)
        best, last = (float(np.mean(checkpoint_returns(ckpt / f"{n}.pt", episodes))) for n in ("best", "last"))
        rows[seed] = {"best": best, "last": last}
        print(f"seed {seed}: best.pt {best:.1f}, last.pt {last:.1f}", flush=True)
    for key in ("best", "last"):
        values = [r[key] for r in rows.values()]
        print(f"{key}.pt: median {np.median(values):.1f} [min {min(values):.1f}, max {max(values):.1f}]")
    if out:
        Path(out).write_text(json.dumps({"algo": algo, "episodes": 10, "seed_base": 2_000_000, "runs": rows}, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:])
