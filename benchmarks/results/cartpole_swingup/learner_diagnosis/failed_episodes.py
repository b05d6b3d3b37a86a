"""A checkpoint's Beta-mean policy (the evaluation's) on unseen episodes (reset seeds 7,000,000 + k, as act_modes.py):
every episode's return, and for the three lowest and the highest the decision of the first near-upright pole
(|angle| < 0.3 rad), the decisions spent there, the cart's range and the mean applied weights (clipped to [0, 1]) by
|pole angle| band.

    python benchmarks/results/cartpole_swingup/learner_diagnosis/failed_episodes.py CHECKPOINT [EPISODES]
"""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from diagnose import print_bands  # noqa: E402  (this folder's)

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import Decision, mode_decider, run_episodes  # noqa: E402

BANDS = (0.0, 0.3, 1.0, 2.0, 3.2)


def describe(label: str, ret: float, t: np.ndarray, k: int) -> None:
    """t: per decision (cart x, pole angle, applied weights...)."""
    angle = np.abs(t[:, 1])
    up = np.flatnonzero(angle < 0.3)
    first = int(up[0]) if len(up) else None
    print(f" {label} episode {k}, return {ret:.0f}: first |angle| < 0.3 at decision {first}, {len(up)} of {len(t)} "
          f"decisions there, cart x in [{t[:, 0].min():.2f}, {t[:, 0].max():.2f}]")  # fmt: skip
    print_bands(angle, t[:, 2:], indent="   ", bands=BANDS)


def main(path: str, episodes: int) -> None:
    torch.set_num_threads(1)
    loaded = load_policy(path)
    env = checkpoint_env(loaded.meta)
    act = mode_decider(loaded.policy, loaded.normalizer, env.action_space, "beta")
    rows: list[tuple] = []

    def decide(obs: np.ndarray) -> Decision:  # obs: x, cos, sin, x', angle'
        decision = act(obs)
        rows.append((obs[0], np.arctan2(obs[2], obs[1]), *np.clip(decision.action, 0.0, 1.0)))
        return decision

    returns, trajectories = [], []
    for k in range(episodes):
        rows.clear()
        returns.append(float(run_episodes(env, decide, [7_000_000 + k])[0]))
        trajectories.append(np.array(rows))
    env.close()
    r = np.array(returns)
    print(f"{path}: {loaded.meta.get('skills', [])}; mean {r.mean():.1f}, min {r.min():.1f}, "
          f"{int((r < 700).sum())} of {episodes} below 700")  # fmt: skip
    print(" returns:", " ".join(f"{x:.0f}" for x in r))
    for k in np.argsort(r)[:3]:
        describe("low", r[k], trajectories[k], int(k))
    best = int(np.argmax(r))
    describe("best", r[best], trajectories[best], best)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 20)
