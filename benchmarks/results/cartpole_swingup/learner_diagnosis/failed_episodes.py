"""A checkpoint's Beta-mean policy on unseen episodes (reset seeds 7,000,000 + k, as act_modes.py): every episode's
return, and for the three lowest and the highest the decision of the first near-upright pole (|angle| < 0.3 rad), the
decisions spent there, the cart's range and the mean applied weights (clipped to [0, 1]) by |pole angle| band.

    python benchmarks/results/cartpole_swingup/learner_diagnosis/failed_episodes.py CHECKPOINT [EPISODES]
"""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.episodes import Decision, run_episodes  # noqa: E402
from hrtc.policy import to_action  # noqa: E402

BANDS = ((0.0, 0.3), (0.3, 1.0), (1.0, 2.0), (2.0, 3.2))


def describe(label: str, ret: float, t: np.ndarray, k: int) -> None:
    """t: per decision (cart x, pole angle, weights..., alpha + beta mean)."""
    angle = np.abs(t[:, 1])
    up = np.flatnonzero(angle < 0.3)
    first = int(up[0]) if len(up) else None
    print(f" {label} episode {k}, return {ret:.0f}: first |angle| < 0.3 at decision {first}, {len(up)} of {len(t)} "
          f"decisions there, cart x in [{t[:, 0].min():.2f}, {t[:, 0].max():.2f}]")  # fmt: skip
    for lo, hi in BANDS:
        m = (angle >= lo) & (angle < hi)
        if m.any():
            weights, conc = np.round(t[m, 2:-1].mean(0), 2).tolist(), t[m, -1].mean()
            print(f"   |angle| {lo}-{hi} rad: {m.sum():3d} decisions, weights {weights}, alpha + beta {conc:.1f}")


def main(path: str, episodes: int) -> None:
    torch.set_num_threads(1)
    loaded = load_policy(path)
    env = checkpoint_env(loaded.meta)
    space = env.action_space
    rows: list[tuple] = []

    @torch.no_grad()
    def decide(obs: np.ndarray) -> Decision:  # obs: x, cos, sin, x', angle'
        d = loaded.policy.distribution(torch.as_tensor(obs[None], dtype=torch.float32))
        a, b = d.alpha[0], d.beta[0]
        w = (a / (a + b)).numpy()
        action = to_action(w, space.low, space.high, "beta").astype(np.float32)
        rows.append((obs[0], np.arctan2(obs[2], obs[1]), *np.clip(action, 0.0, 1.0), float((a + b).mean())))
        return Decision(obs, w, action)

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
