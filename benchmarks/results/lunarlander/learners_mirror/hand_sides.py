"""The hand blend's returns and failed episodes by the initial lateral push, over many starts.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners_mirror/hand_sides.py CHECKPOINT [--episodes 400]

The hand blend (centring + descent + touchdown at 1) is a constant blend of mirror-equivariant skills, so it is itself
exactly mirror-equivariant: a difference between its left and right pushes would be the task's, not a policy's.
CHECKPOINT only gives the composed env (any lunarlander run's). Reset seeds 5000 on, deterministic episodes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

import envs  # noqa: E402
from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.references import evaluate_rules  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "learners"))
from hand import declared_hand_blend  # noqa: E402  (../learners)

BINS = ((-9.0, -0.7), (-0.7, -0.4), (-0.4, 0.4), (0.4, 0.7), (0.7, 9.0))  # vx0, gymnasium's scaled units


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=400)
    args = parser.parse_args()
    seeds = list(range(5000, 5000 + args.episodes))
    meta = load_policy(args.checkpoint).meta
    env = checkpoint_env(meta)
    name, rule = declared_hand_blend(meta["skills"])
    hand = evaluate_rules(env, {name: rule}, seeds)[name]
    raw = envs.make("lunarlander")
    vx0 = np.array([raw.reset(seed=s)[0][2] for s in seeds])
    failed = hand < 100
    print(f"hand blend over {len(seeds)} starts (reset seeds {seeds[0]}-{seeds[-1]}): mean {hand.mean():.1f}, "
          f"failed {int(failed.sum())}")  # fmt: skip
    for low, high in BINS:
        picked = (vx0 >= low) & (vx0 < high)
        print(f"  vx0 in [{low}, {high}): {int(picked.sum())} starts, failed {int(failed[picked].sum())}, "
              f"mean {hand[picked].mean():.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
