"""Where a learned lunarlander policy gains and loses against the hand blend, episode by episode.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/versus_hand.py CHECKPOINT [...] [--episodes 100]

On the same episodes (the evaluation seeds of seed 1, as the benchmark's references): each checkpoint's deterministic
returns (Beta means) beside the hand blend's (centring + descent + touchdown at 1), the episodes each wins by more
than 5, the failed episodes (return < 100: crashes), and the mean over the episodes both land (>= 100 for both).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env, checkpoint_returns  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import eval_seeds  # noqa: E402
from hrtc.references import FixedWeights, evaluate_rules  # noqa: E402

HAND = {"centring": 1.0, "descent": 1.0, "touchdown": 1.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    seeds = eval_seeds(1, args.episodes)
    env = checkpoint_env(load_policy(args.checkpoints[0]).meta)
    hand = evaluate_rules(env, {"hand": FixedWeights(HAND)}, seeds)["hand"]
    print(f"hand blend: mean {hand.mean():.1f}, failed (< 100) {int((hand < 100).sum())} of {len(seeds)}")
    for path in args.checkpoints:
        returns = checkpoint_returns(path, seeds)
        both = (returns >= 100) & (hand >= 100)
        gain = returns - hand
        print(f"{path}: mean {returns.mean():.1f}; wins {int((gain > 5).sum())}, losses {int((gain < -5).sum())}; "
              f"failed (< 100) {int((returns < 100).sum())}; where both land: {returns[both].mean():.1f} against "
              f"{hand[both].mean():.1f}")  # fmt: skip


if __name__ == "__main__":
    main()
