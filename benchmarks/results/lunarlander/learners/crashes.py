"""What a learned lunarlander policy's failed episodes (return < 100) have in common, against the ones it lands.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/crashes.py CHECKPOINT [--episodes 100] [--seed 1]

On the evaluation seeds of ``--seed`` (the benchmark's final policy uses each run seed's own), deterministic episodes
(Beta means): for the failed and the landed episodes, the initial push (|vx| and vy of the first observation, in
gymnasium's scaled units), the mean applied weights over the first 3 s (30 decisions) and over the episode, and the
episode's length in decisions; then each failed episode's end (x, y, angle).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import eval_seeds, mode_decider, run_episodes  # noqa: E402


class EpisodeWatch(gym.Wrapper):
    """Per episode: its seed, first and last observation, and the weights applied at each decision (ComposedEnv
    clips the sampled span to [0, 1])."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.rows: list[dict] = []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.rows.append({"seed": kwargs.get("seed"), "first": obs.copy(), "weights": []})
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.rows[-1]["weights"].append(np.clip(action, 0.0, 1.0))
        self.rows[-1]["end"] = obs[[0, 1, 4]]
        return obs, reward, terminated, truncated, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(1)
    loaded = load_policy(args.checkpoint)
    env = EpisodeWatch(checkpoint_env(loaded.meta))
    decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])
    returns = run_episodes(env, decide, eval_seeds(args.seed, args.episodes))
    env.close()
    rows = []
    for row, total in zip(env.rows, returns, strict=True):
        w = np.asarray(row["weights"])
        rows.append({"seed": row["seed"], "return": float(total), "vx0": row["first"][2], "vy0": row["first"][3],
                     "w3": w[:30].mean(0), "w": w.mean(0), "decisions": len(w), "end": row["end"]})  # fmt: skip
    returns = np.array([r["return"] for r in rows])
    print(f"{args.checkpoint}: mean {returns.mean():.1f}, failed (< 100) {int((returns < 100).sum())} of {len(rows)}")
    print("weights in the order", ", ".join(loaded.meta["skills"]))
    for label, picked in (("failed", returns < 100), ("landed", returns >= 100)):
        group = [r for r, p in zip(rows, picked, strict=True) if p]
        if not group:
            continue
        print(f"{label}: {len(group)} episodes; |vx0| {np.mean([abs(r['vx0']) for r in group]):.2f}, vy0 "
              f"{np.mean([r['vy0'] for r in group]):.2f}; weights over the first 3 s "
              f"{np.round(np.mean([r['w3'] for r in group], 0), 2)}, over the episode "
              f"{np.round(np.mean([r['w'] for r in group], 0), 2)}; {np.mean([r['decisions'] for r in group]):.0f} "
              "decisions")  # fmt: skip
    for r in rows:
        if r["return"] < 100:
            x, y, angle = r["end"]
            print(f"  seed {r['seed']}: return {r['return']:.0f}, vx0 {r['vx0']:.2f}, ends after {r['decisions']} "
                  f"decisions at x {x:.2f}, y {y:.2f}, angle {angle:.2f} rad")  # fmt: skip


if __name__ == "__main__":
    main()
