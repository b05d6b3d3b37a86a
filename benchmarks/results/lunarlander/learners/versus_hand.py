"""Where a learned lunarlander policy gains and loses against the hand blend, episode by episode.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/versus_hand.py CHECKPOINT [...] [--episodes 100]
        [--seed 1]

On the same episodes (the evaluation seeds of ``--seed``; 1, the benchmark's references', by default; a run's final
policy is evaluated on its own run seed's): each checkpoint's deterministic returns (Beta means) beside the hand
blend's (centring + descent + touchdown at 1), the episodes each wins by more than 5, the failed episodes (return <
100: crashes), the mean over the episodes both land (>= 100 for both), and the hand blend's return on each episode
the checkpoint fails.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env, checkpoint_returns  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import eval_seeds  # noqa: E402
from hrtc.references import evaluate_rules  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hand import declared_hand_blend  # noqa: E402  (this folder's)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1, help="whose evaluation seeds (a run seed)")
    args = parser.parse_args()
    seeds = eval_seeds(args.seed, args.episodes)
    meta = load_policy(args.checkpoints[0]).meta
    env = checkpoint_env(meta)
    name, rule = declared_hand_blend(meta["skills"])
    hand = evaluate_rules(env, {name: rule}, seeds)[name]
    print(f"hand blend: mean {hand.mean():.1f}, failed (< 100) {int((hand < 100).sum())} of {len(seeds)}")
    for path in args.checkpoints:
        returns = checkpoint_returns(path, seeds)
        both = (returns >= 100) & (hand >= 100)
        gain = returns - hand
        print(f"{path}: mean {returns.mean():.1f}; wins {int((gain > 5).sum())}, losses {int((gain < -5).sum())}; "
              f"failed (< 100) {int((returns < 100).sum())}; where both land: {returns[both].mean():.1f} against "
              f"{hand[both].mean():.1f}")  # fmt: skip
        for seed, own, theirs in zip(seeds, returns, hand, strict=True):
            if own < 100:
                print(f"  failed episode seed {seed}: {own:.0f}; the hand blend {theirs:.0f}")


if __name__ == "__main__":
    main()
