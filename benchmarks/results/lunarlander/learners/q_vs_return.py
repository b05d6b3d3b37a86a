"""Do a SAC run's critics foresee its final policy's crashes? Q(s, w) of the checkpoint's twin critics against the
return that followed, on the policy's own deterministic episodes, for the failed (return < 100) and the landed ones.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/q_vs_return.py CHECKPOINT [--episodes 100] [--sampled]

CHECKPOINT: a benchmark run's RUN_DIR/checkpoints/last.pt (its config.yaml, one folder up, gives the critics' shape).

For every decision t of every episode (the evaluation seeds of the run's seed, as the benchmark's final policy):
``Q(s_t, w_t)`` = the min of the two critics at the weights the policy applied (its Beta mean), against
``G_t = sum_j gamma_d^j r_{t+j}`` (gamma_d = sac.gamma ** decision_every, the critics' own discount; r the decision's
summed reward). The critics learn the soft value of the *trained* policy's samples, so Q also holds the future
entropy bonus (printed: temperature x target entropy / (1 - gamma_d)) and the gap between the sampled and the
deterministic policy. Then, at the same states, Q at the hand blend's weights (centring, descent, touchdown at 1;
the rest 0), which lands every one of its 100 episodes on seed 1's evaluation seeds: does the critic rank it below
the policy's own blend where the policy crashes? Last, how the critics fit the run's own replay buffer (every
decision of the run, oldest first) at its terminal transitions, crashes (reward < -50) and landings (> 50), in the
first and the second half of the run: their target is the reward itself.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.benchmark.metrics import checkpoint_env  # noqa: E402
from hrtc.checkpoint import load_checkpoint, load_policy  # noqa: E402
from hrtc.episodes import Decision, eval_seeds, mode_decider  # noqa: E402
from hrtc.policy import to_action  # noqa: E402
from hrtc.sac import TwinQ  # noqa: E402

HAND = {"centring": 1.0, "descent": 1.0, "touchdown": 1.0}


def discounted(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """``G_t = r_t + gamma G_{t+1}`` for every t of one episode (the episode's end bootstraps nothing)."""
    out, g = np.zeros(len(rewards)), 0.0
    for t in range(len(rewards) - 1, -1, -1):
        g = rewards[t] + gamma * g
        out[t] = g
    return out


def buffer_fit(buffer: dict, critics: TwinQ) -> None:
    """The critics against the stored terminal transitions' rewards, by kind and by half of the run."""
    obs, samples = buffer["obs"], buffer["samples"]
    rewards, terminal = buffer["rewards"].numpy(), buffer["terminated"].numpy().astype(bool)
    with torch.no_grad():
        q = critics(obs, samples).min(0).values.numpy()
    n = len(rewards)
    print(f"replay buffer: {n} decisions, {int(terminal.sum())} terminal")
    print("| terminal transitions | half of the run | n | reward, mean | Q, mean |")
    print("|---|---|---|---|---|")
    kinds = (("crash (r < -50)", terminal & (rewards < -50)), ("landing (r > 50)", terminal & (rewards > 50)))
    for kind, picked in kinds:
        for half, part in (("first", slice(0, n // 2)), ("second", slice(n // 2, n))):
            idx = np.flatnonzero(picked[part]) + (part.start or 0)
            if len(idx):
                print(f"| {kind} | {half} | {len(idx)} | {rewards[idx].mean():.1f} | {q[idx].mean():.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--sampled", action="store_true",
                        help="act as in training: the trained policy, its weights sampled")  # fmt: skip
    args = parser.parse_args()
    torch.set_num_threads(1)
    path = Path(args.checkpoint)
    cfg = yaml.safe_load((path.parent.parent / "config.yaml").read_text())
    sac, seed = cfg["sac"], int(cfg["seed"])
    loaded = load_policy(path)
    state = load_checkpoint(path)
    # float32 here, whatever the run trained in (bfloat16 only speeds up the products)
    critics = TwinQ(int(loaded.meta["obs_dim"]), int(loaded.meta["out_dim"]), sac["q_hidden"], n=sac["n_critics"],
                    layer_norm=sac["q_layer_norm"])  # fmt: skip
    critics.load_state_dict(state["optimizer"]["critics"])
    critics.eval()
    temperature = float(state["optimizer"]["log_temperature"].exp())
    skills = list(loaded.meta["skills"])
    margin = float(loaded.meta.get("weight_margin", 0.0))
    hand_w = np.array([HAND.get(name, 0.0) for name in skills])
    hand_u = torch.as_tensor((hand_w + margin) / (1.0 + 2.0 * margin), dtype=torch.float32)  # Beta space of [-m, 1+m]
    gamma_d = float(sac["gamma"]) ** int(loaded.meta["decision_every"])
    env = checkpoint_env(loaded.meta)
    decide = mode_decider(loaded.policy, loaded.normalizer, env.action_space, loaded.meta["dist"])
    if args.sampled:
        trained = load_policy(path).policy
        trained.load_state_dict(state["optimizer"].get("trained_policy", state["policy"]))
        torch.manual_seed(seed)

        @torch.no_grad()
        def decide(obs: np.ndarray) -> Decision:  # the trainer's act(): a Beta sample, mapped onto the action space
            u = trained.distribution(torch.as_tensor(obs, dtype=torch.float32)[None]).sample().numpy()[0]
            return Decision(obs, u, to_action(u, env.action_space.low, env.action_space.high, "beta"))

    rows = []
    for episode_seed in eval_seeds(seed, args.episodes):
        obs, _ = env.reset(seed=int(episode_seed))
        observations, samples, rewards, done = [], [], [], False
        while not done:
            decision = decide(obs)
            observations.append(decision.obs)
            samples.append(decision.weights)
            obs, reward, terminated, truncated, _ = env.step(decision.action)
            rewards.append(float(reward))
            done = terminated or truncated
        o = torch.as_tensor(np.stack(observations), dtype=torch.float32)
        with torch.no_grad():
            q = critics(o, torch.as_tensor(np.stack(samples), dtype=torch.float32)).min(0).values.numpy()
            q_hand = critics(o, hand_u.expand(len(o), -1)).min(0).values.numpy()
            v = loaded.policy.value(o).numpy().reshape(-1)
        rewards = np.asarray(rewards)
        rows.append({"seed": episode_seed, "return": rewards.sum(), "q": q, "q_hand": q_hand, "v": v,
                     "g": discounted(rewards, gamma_d)})  # fmt: skip
    env.close()
    returns = np.array([r["return"] for r in rows])
    how = " (sampled, the trained policy)" if args.sampled else ""
    print(f"{path}{how}: mean {returns.mean():.1f} over {len(rows)} episodes, "
          f"failed (< 100) {int((returns < 100).sum())}")  # fmt: skip
    print(f"temperature {temperature:.4f}; the entropy bonus at the target entropy, summed over the horizon: "
          f"{temperature * sac['target_entropy_per_weight'] * len(skills) / (1.0 - gamma_d):.1f}")  # fmt: skip
    print("| episodes | n | return | G_0 | Q(s_0, policy) | V(s_0) | Q(s_0, hand) | Q - G over all decisions | "
          "Q - G, last 10 decisions | decisions where Q(hand) > Q(policy) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, picked in (("failed", returns < 100), ("landed", returns >= 100)):
        group = [r for r, p in zip(rows, picked, strict=True) if p]
        if not group:
            continue
        err = np.concatenate([r["q"] - r["g"] for r in group])
        err_end = np.concatenate([(r["q"] - r["g"])[-10:] for r in group])
        hand_better = np.concatenate([r["q_hand"] > r["q"] for r in group])
        print(f"| {label} | {len(group)} | {np.mean([r['return'] for r in group]):.1f} | "
              f"{np.mean([r['g'][0] for r in group]):.1f} | {np.mean([r['q'][0] for r in group]):.1f} | "
              f"{np.mean([r['v'][0] for r in group]):.1f} | {np.mean([r['q_hand'][0] for r in group]):.1f} | "
              f"{err.mean():+.1f} (mean abs {np.abs(err).mean():.1f}) | {err_end.mean():+.1f} | "
              f"{100 * hand_better.mean():.0f} % |")  # fmt: skip
    buffer_fit(state["optimizer"]["buffer"], critics)
    failed = [r for r in rows if r["return"] < 100]
    for r in failed:
        print(f"  seed {r['seed']}: return {r['return']:.0f}, {len(r['q'])} decisions; Q at decisions 0, -10, -5, -1: "
              f"{r['q'][0]:.0f} {r['q'][max(-10, -len(r['q']))]:.0f} {r['q'][max(-5, -len(r['q']))]:.0f} "
              f"{r['q'][-1]:.0f}; G: {r['g'][0]:.0f} {r['g'][max(-10, -len(r['g']))]:.0f} "
              f"{r['g'][max(-5, -len(r['g']))]:.0f} {r['g'][-1]:.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
