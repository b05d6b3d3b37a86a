"""A checkpoint's returns when its meta-policy acts with the Beta mean (the paper's evaluation), the Beta mode
((alpha - 1) / (alpha + beta - 2)), or a sampled weight vector, on the same unseen episodes (reset seeds
7,000,000 + k, used by no training or evaluation run). The Beta's value in (0, 1) maps onto the checkpoint's weight
span as in training (``to_action``; section 5's table ran on the paper's span, where it is the weight itself).

    python benchmarks/results/cartpole_swingup/learner_diagnosis/act_modes.py EPISODES CHECKPOINT [CHECKPOINT ...]
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


def main(episodes: int, paths: list[str]) -> None:
    torch.set_num_threads(1)
    seeds = [7_000_000 + k for k in range(episodes)]
    for path in paths:
        loaded = load_policy(path)
        env = checkpoint_env(loaded.meta)
        space = env.action_space  # the weight span: [-m, 1 + m] per weight, clipped to [0, 1] by the action filter
        returns = {}
        for how in ("mean", "mode", "sample"):

            @torch.no_grad()
            def decide(obs: np.ndarray, how: str = how, policy=loaded.policy, space=space) -> Decision:
                d = policy.distribution(torch.as_tensor(obs[None], dtype=torch.float32))
                a, b = d.alpha[0], d.beta[0]
                if how == "mean":
                    w = a / (a + b)
                elif how == "mode":
                    w = (a - 1) / (a + b - 2).clamp(min=1e-6)
                else:
                    w = torch.distributions.Beta(a, b).sample()
                w = w.numpy()
                return Decision(obs, w, to_action(w, space.low, space.high, "beta").astype(np.float32))

            returns[how] = run_episodes(env, decide, seeds)
        env.close()
        print(path, "  ".join(f"{k} {v.mean():.0f} (min {v.min():.0f})" for k, v in returns.items()), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2:])
