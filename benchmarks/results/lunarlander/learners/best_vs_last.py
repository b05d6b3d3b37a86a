"""The best evaluated snapshot against the last one, on the final policy's own 100 episodes (issue 14).

Each lunarlander run keeps ``checkpoints/best.pt``: the policy of its highest 10-episode evaluation. The benchmark's
final policy is ``last.pt`` (its returns are in ``results.json`` as ``final_returns``). This plays ``best.pt`` on the
same 100 final episode seeds (:func:`hrtc.benchmark.runs.final_seeds`) and prints, per run, both means and their
episodes below 100, then the medians over the runs given. With ``final_seed_base`` None (lunarlander_learners) the
first 10 of those seeds are the evaluations' own, the ones ``best.pt`` was chosen on, so the means over the other 90
are printed too: only they compare the two snapshots without the choice's bias::

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/best_vs_last.py RESULTS.json ROW [SEED ...]

``RESULTS.json`` is a benchmark's results (its ``runs`` name each run's ``run_dir``, which must still hold the
checkpoints); ``ROW`` the algorithm's name there. With ``--json OUT`` the per-episode returns are written to OUT.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from hrtc.benchmark.metrics import checkpoint_returns
    from hrtc.benchmark.runs import episode_seeds
    from hrtc.episodes import eval_seeds

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("row")
    parser.add_argument("seeds", type=int, nargs="*", help="run seeds (default: every run of ROW in RESULTS)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    results = json.loads(args.results.read_text())
    runs = {int(key.rsplit("seed", 1)[1]): run for key, run in results["runs"].items()
            if key.split("/")[0] == args.row}  # fmt: skip
    if not runs:
        print(f"best_vs_last: no runs of {args.row!r} in {args.results}", file=sys.stderr)
        return 2
    seeds = args.seeds or sorted(runs)
    rows, dump = [], {}
    print(
        "| seed | best evaluation (10 episodes) at env step | best.pt, 100 episodes (below 100) "
        "| last.pt, 100 episodes (below 100) | best.pt, the 90 unseen | last.pt, the same 90 |"
    )
    print("|---|---|---|---|---|---|")
    for seed in seeds:
        run = runs[seed]
        best = Path(run["run_dir"]) / "checkpoints" / "best.pt"
        if not best.exists():
            print(f"best_vs_last: seed {seed}: no {best}", file=sys.stderr)
            return 2
        final_seeds = episode_seeds(run.get("final_seed_base"), seed, int(run["final_episodes"]))
        last = np.asarray(run["final_returns"], dtype=float)
        got = checkpoint_returns(best, final_seeds)
        curve = run["curve"]
        at = int(np.argmax(curve["episode_reward"]))  # the first evaluation that reached the maximum saved best.pt
        evaluated = eval_seeds(seed, int(run["eval_episodes"]))  # the seeds best.pt was chosen on
        unseen = slice(len(evaluated) if final_seeds[: len(evaluated)] == evaluated else 0, None)
        rows.append((got.mean(), int((got < 100).sum()), last.mean(), int((last < 100).sum()),
                     got[unseen].mean(), int((got[unseen] < 100).sum()), last[unseen].mean(),
                     int((last[unseen] < 100).sum())))  # fmt: skip
        dump[seed] = {"best": got.tolist(), "last": last.tolist(), "best_step": curve["step"][at]}
        r = rows[-1]
        print(
            f"| {seed} | {curve['episode_reward'][at]:.1f} at {curve['step'][at]:,} | {r[0]:.1f} ({r[1]}) "
            f"| {r[2]:.1f} ({r[3]}) | {r[4]:.1f} ({r[5]}) | {r[6]:.1f} ({r[7]}) |",
            flush=True,
        )
    t = np.asarray(rows)
    print(
        f"\nmedians over {len(rows)} runs (episodes below 100 summed): 100 episodes: best.pt {np.median(t[:, 0]):.1f}"
        f" ({int(t[:, 1].sum())}), last.pt {np.median(t[:, 2]):.1f} ({int(t[:, 3].sum())}); the unseen ones: best.pt "
        f"{np.median(t[:, 4]):.1f} ({int(t[:, 5].sum())}), last.pt {np.median(t[:, 6]):.1f} ({int(t[:, 7].sum())})"
    )
    if args.json:
        args.json.write_text(json.dumps(dump, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
