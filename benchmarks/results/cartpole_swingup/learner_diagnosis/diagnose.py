"""Why PPO over Beta weights stalls below the hand rule: what the trained meta-policy's weights look like.

    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py CHECKPOINT [CHECKPOINT...] [--episodes 10]
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --soft-rules [--episodes 10]

For each checkpoint, on the evaluation seeds of its seed: the return with the Beta means (what is evaluated) and with
sampled weights (what PPO optimises), the share of decisions whose weights are "pinned" (the dominant weight >= 0.9 and
every other <= 0.1: what the switching rule needs, see soft switches in table.md), and the median concentration
alpha + beta. ``--soft-rules`` scores cartpole_swingup's switching rule with softer weights than 0 and 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.environments import make_env  # noqa: E402
from hrtc.episodes import Decision, eval_seeds, run_episodes  # noqa: E402
from hrtc.normalize import normalize_obs  # noqa: E402
from hrtc.policy import to_action  # noqa: E402


def diagnose(path: str, episodes: int) -> dict[str, float]:
    policy, normalizer, meta = load_policy(path)
    env = checkpoint_env(meta)  # its weight span too: samples on [-m, 1 + m], the weights clipped to [0, 1]
    space = env.action_space
    seeds = eval_seeds(1, episodes)
    log: dict[str, list] = {"w": [], "conc": []}

    def decider(rule: str):
        def decide(obs: np.ndarray) -> Decision:
            nobs = normalize_obs(normalizer, obs[None])
            with torch.no_grad():
                d = policy.distribution(torch.as_tensor(nobs))
                if rule == "mode":  # the Beta's peak (alpha - 1) / (alpha + beta - 2); the mean where it is flat
                    peak = (d.alpha - 1) / (d.alpha + d.beta - 2).clamp_min(1e-6)
                    u = torch.where(d.alpha + d.beta > 2 + 1e-6, peak, d.mode()).numpy()[0]
                else:
                    u = (d.sample() if rule == "sample" else d.mode()).numpy()[0]
            action = to_action(u, space.low, space.high, "beta")
            if rule == "mean":
                log["w"].append(np.clip(action, 0.0, 1.0))  # the weights the action filter applies
                log["conc"].append((d.alpha + d.beta).numpy()[0])
            return Decision(nobs[0], u, action.astype(np.float32))

        return decide

    torch.manual_seed(0)
    mean_returns = run_episodes(env, decider("mean"), seeds)
    sampled_returns = run_episodes(env, decider("sample"), seeds)
    mode_returns = run_episodes(env, decider("mode"), seeds)
    w, conc = np.array(log["w"]), np.array(log["conc"])
    top = np.sort(w, axis=1)
    pinned = (top[:, -1] >= 0.9) & (top[:, :-1] <= 0.1).all(axis=1)
    return {"mean weights return": mean_returns.mean(), "sampled weights return": sampled_returns.mean(),
            "Beta-mode weights return": mode_returns.mean(),
            "pinned share": pinned.mean(), "dominant weight (median)": float(np.median(top[:, -1])),
            "runner-up weight (median)": float(np.median(top[:, -2])),
            "alpha+beta (median)": float(np.median(conc)), "alpha+beta (90th pct)": float(np.percentile(conc, 90))}


def soft_rules(episodes: int, action_filter: str = "sum") -> None:
    """The switching rule with the active skill at ``hi`` and the inactive ones at ``lo`` (all, or only hold and
    tracker at 0)."""
    from hrtc.cli import task_config
    from hrtc.references import SwitchRule, evaluate_rules

    task = task_config("cartpole_swingup")
    env = make_env("cartpole_swingup", "hrtc", task["skills"], action_filter, decision_every=5)
    rules = {}
    for hi, lo in ((1.0, 0.0), (0.9, 0.1), (0.8, 0.2), (0.7, 0.3), (0.6, 0.4)):
        rest = {"tracker": lo, "hold": lo}
        rules[f"{hi} / {lo}"] = SwitchRule("pole_angle", 0.5, {"swingup": hi, "balance": lo, **rest},
                                           {"balance": hi, "swingup": lo, **rest})  # fmt: skip
        rules[f"{hi} / 0"] = SwitchRule("pole_angle", 0.5, {"swingup": hi}, {"balance": hi})
    for name, returns in evaluate_rules(env, rules, eval_seeds(1, episodes)).items():
        print(f"active / inactive {name}: {returns.mean():.1f} +- {returns.std():.1f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("checkpoints", nargs="*")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--soft-rules", action="store_true")
    parser.add_argument("--action-filter", default="sum", choices=("sum", "convex"))
    args = parser.parse_args()
    if args.soft_rules:
        soft_rules(args.episodes, args.action_filter)
    for ckpt in args.checkpoints:
        stats = diagnose(ckpt, args.episodes)
        print(ckpt, " | ".join(f"{k} {v:.3g}" for k, v in stats.items()))
