"""Do a SAC checkpoint's critics know what its own blend is worth, and would they rather have the switching rule's?

    PYTHONPATH=. python benchmarks/results/cartpole_swingup/learner_diagnosis/critic_probe.py CHECKPOINT [EPISODES]

The checkpoint's Beta-mean policy (the evaluation's) plays EPISODES unseen episodes (reset seeds 7,000,000 + k, as
failed_episodes.py; 10 by default). At every decision it visits: Q_min(s, its own samples) and Q_min(s, the samples
that give the weights of the task's declared switching rule, ``task.references`` in cartpole_swingup.yaml), beside
the discounted return-to-go that episode actually got from there (gamma per env step as the task's, 0.99). Printed
by |pole angle| band, for the failed episodes (return < 700) and the others apart: the mean of Q(policy) - Q(rule),
the share of states where the critics rate the rule higher, Q(policy) against the return-to-go, and the applied
weights. Q is SAC's soft value (the entropy bonus included), so it matches the return-to-go only roughly; what it
shows is whether the critics tell the failing episodes' states from the good ones'.
"""

import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from diagnose import load_critics, margin_of  # noqa: E402  (this folder's)

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.cli import task_config  # noqa: E402
from hrtc.episodes import mode_decider  # noqa: E402
from hrtc.references import reference_rules  # noqa: E402

BANDS = (0.0, 0.3, 1.0, 2.0, 3.2)
GAMMA = 0.99  # per env step, the task's sac.gamma


def play(loaded: Any, episodes: int) -> dict[str, np.ndarray]:
    """Every decision of the Beta-mean policy's episodes: obs, samples, applied weights, the switching rule's weights,
    episode, return-to-go; and each episode's return. ``loaded``: :func:`hrtc.checkpoint.load_policy`'s."""
    env = checkpoint_env(loaded.meta)
    act = mode_decider(loaded.policy, loaded.normalizer, env.action_space, "beta")
    names = list(loaded.meta["skills"])
    declared = reference_rules(names, task_config("cartpole_swingup")["references"])
    rule = next(r for name, r in declared.items() if name.startswith("switching rule"))
    per_decision = GAMMA ** int(loaded.meta.get("decision_every", 5))
    obs_log, u_log, applied, ruled, episode, to_go, returns = [], [], [], [], [], [], []
    for k in range(episodes):
        obs, _ = env.reset(seed=7_000_000 + k)
        done, rewards = False, []
        while not done:
            decision = act(obs)
            obs_log.append(np.asarray(obs, np.float32))
            u_log.append(decision.weights)
            applied.append(np.clip(decision.action, 0.0, 1.0))  # the weights the action filter applies
            chosen = rule(env.unwrapped.skill_state())
            ruled.append([float(chosen.get(n, 0.0)) for n in names])
            episode.append(k)
            obs, reward, terminated, truncated, _ = env.step(decision.action)
            rewards.append(float(reward))
            done = terminated or truncated
        returns.append(sum(rewards))
        acc, backwards = 0.0, []
        for reward in rewards[::-1]:
            acc = reward + per_decision * acc
            backwards.append(acc)
        to_go.extend(backwards[::-1])
    env.close()
    return {"obs": np.array(obs_log), "u": np.array(u_log, np.float32), "applied": np.array(applied),
            "rule": np.array(ruled, np.float32), "episode": np.array(episode), "to_go": np.array(to_go),
            "returns": np.array(returns)}  # fmt: skip


def main(path: str, episodes: int) -> None:
    torch.set_num_threads(1)
    loaded = load_policy(path)
    names, m = list(loaded.meta["skills"]), margin_of(loaded.meta)
    critics, _ = load_critics(path)
    run = play(loaded, episodes)
    obs, u = torch.as_tensor(run["obs"]), torch.as_tensor(run["u"])
    angle = np.abs(np.arctan2(run["obs"][:, 2], run["obs"][:, 1]))
    rule = torch.as_tensor((run["rule"] + m) / (1 + 2 * m))  # the samples that give the rule's weights
    with torch.no_grad():
        q_policy = critics(obs, u).min(0).values.numpy()
        q_rule = critics(obs, rule).min(0).values.numpy()
    applied = run["applied"]
    returns = run["returns"]
    print(f"{path}: {names}; returns mean {returns.mean():.1f}, {int((returns < 700).sum())} of {episodes} below 700")
    for label, chosen in (("failed (< 700)", returns < 700), ("good (>= 700)", returns >= 700)):
        in_group = np.isin(run["episode"], np.flatnonzero(chosen))
        if not in_group.any():
            continue
        print(f" {label}: {int(chosen.sum())} episodes, {int(in_group.sum())} decisions")
        for low, high in zip(BANDS[:-1], BANDS[1:], strict=False):
            mask = in_group & (angle >= low) & (angle < high)
            if not mask.any():
                continue
            gap = q_policy[mask] - q_rule[mask]
            weights = " ".join(f"{n} {v:.2f}" for n, v in zip(names, applied[mask].mean(0), strict=True))
            print(f"  |angle| {low:.1f}-{high:.1f} ({int(mask.sum())}): Q(policy) - Q(rule) {gap.mean():+.2f}, the "
                  f"rule rated higher on {np.mean(gap < 0):.0%}; Q(policy) {q_policy[mask].mean():.1f} against the "
                  f"return-to-go {run['to_go'][mask].mean():.1f}; weights {weights}")  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 10)
