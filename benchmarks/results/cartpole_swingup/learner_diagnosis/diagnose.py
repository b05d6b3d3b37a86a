"""Why PPO over Beta weights stalls below the hand rule: what the trained meta-policy's weights look like.

    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py CHECKPOINT [CHECKPOINT...] [--episodes 10]
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --soft-rules [--episodes 10]
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --by-angle CHECKPOINT [--episodes 3]
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --critic-gradients SAC_LAST_CHECKPOINT
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --critic-returns SAC_LAST_CHECKPOINT [...]
    python benchmarks/results/cartpole_swingup/learner_diagnosis/diagnose.py --recording RUN_DIR --steps 20000 22500

For each checkpoint, on the evaluation seeds of its seed: the return with the Beta means (what is evaluated) and with
sampled weights (what PPO optimises), the share of decisions whose weights are "pinned" (the dominant weight >= 0.9 and
every other <= 0.1: what the switching rule needs, see soft switches in table.md), and the median concentration
alpha + beta. ``--soft-rules`` scores cartpole_swingup's switching rule with softer weights than 0 and 1.
``--by-angle``: the applied weights (Beta means, clipped) averaged over the decisions in each band of |pole angle|
(from the observation's cos and sin), beside the switching rule's (swingup alone above 0.5 rad, balance alone below).
``--recording``: the same bands from a run's Rerun recording alone, for its evaluations at ``--steps``.
``--critic-gradients``: a SAC run's ``last.pt`` (it holds the critics and the replay buffer): the median |dQ/dw_k| of
the critics' min at the policy's mean weights, per unit of applied weight, on the buffer's last 5,000 states, near
upright and away from it. ``hold`` proposes zero force, so with the sum filter its weight changes nothing: its
gradient measures the critics' gradient noise.
``--critic-returns``: a SAC run's ``last.pt``: its critics' Q at the stored weights against the discounted returns
the buffer's own episodes got, on its newest 2,500 decisions whose return is complete.
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
    return {
        "mean weights return": mean_returns.mean(),
        "sampled weights return": sampled_returns.mean(),
        "Beta-mode weights return": mode_returns.mean(),
        "pinned share": pinned.mean(),
        "dominant weight (median)": float(np.median(top[:, -1])),
        "runner-up weight (median)": float(np.median(top[:, -2])),
        "alpha+beta (median)": float(np.median(conc)),
        "alpha+beta (90th pct)": float(np.percentile(conc, 90)),
    }


ANGLE_BANDS = (0.0, 0.2, 0.5, 1.0, 2.0, 3.2)


def print_bands(angle: np.ndarray, weights: np.ndarray, indent: str = "  ",
                bands: tuple[float, ...] = ANGLE_BANDS) -> None:  # fmt: skip
    """The mean of ``weights`` (N, K) over the decisions in each band of ``angle`` (N,), one line per non-empty band."""
    for lo, hi in zip(bands[:-1], bands[1:], strict=True):
        band = (angle >= lo) & (angle < hi)
        if band.any():
            means = " ".join(f"{v:.2f}" for v in weights[band].mean(0))
            print(f"{indent}|angle| {lo:.1f}-{hi:.1f}: {int(band.sum()):4d} decisions, weights {means}")


def margin_of(meta: dict) -> float:
    """The checkpoint's weight span margin (checkpoints of the option's prototype record only the action bounds)."""
    return float(meta.get("weight_margin", -min(meta.get("action_low") or [0.0])))


def by_angle(path: str, episodes: int) -> None:
    policy, normalizer, meta = load_policy(path)
    env = checkpoint_env({**meta, "weight_margin": margin_of(meta)})
    space = env.action_space
    rows = []

    def decide(obs: np.ndarray) -> Decision:
        nobs = normalize_obs(normalizer, obs[None])
        with torch.no_grad():
            u = policy.distribution(torch.as_tensor(nobs)).mode().numpy()[0]  # the Beta mean
        action = to_action(u, space.low, space.high, "beta")
        rows.append((abs(np.arctan2(obs[2], obs[1])), *np.clip(action, 0.0, 1.0)))  # obs: x, cos, sin, x', angle'
        return Decision(nobs[0], u, action.astype(np.float32))

    returns = run_episodes(env, decide, eval_seeds(1, episodes))
    table = np.array(rows)
    print(f"{path}: {' '.join(meta.get('skills', []))}, returns {np.round(returns, 1).tolist()}")
    print_bands(table[:, 0], table[:, 1:])


def recording_by_angle(run_dir: str, steps: list[int]) -> None:
    from hrtc.review import load

    review = load(run_dir)
    print(f"{run_dir}: {' '.join(review.skill_names)} (key state {review.key_state})")
    for step in steps:
        episodes = review.episodes[review.episodes.global_step == step]
        decisions = review.steps[review.steps.episode.isin(episodes.episode)]
        weights, angle = np.stack(decisions.weights.values), np.abs(decisions.key.values)
        print(f"  {step} env steps: returns {episodes['return'].round(0).tolist()}")
        print_bands(angle, weights, indent="    ")


def load_critics(path: str) -> tuple[torch.nn.Module, dict]:
    """A SAC run's critics (sizes read from the saved weights, LayerNorm or not) and its learner's saved state."""
    from hrtc.checkpoint import load_checkpoint
    from hrtc.sac import TwinQ

    state = load_checkpoint(path)["optimizer"]  # a SAC run saves its learner's state under this key
    first = {name: v for name, v in state["critics"].items() if name.startswith("critics.0.")}
    hidden = [v.shape[0] for name, v in first.items() if name.endswith(".weight") and v.dim() == 2][:-1]
    layer_norm = any(name.endswith(".weight") and v.dim() == 1 for name, v in first.items())  # LayerNorm's gains
    n = len({name.split(".")[1] for name in state["critics"]})
    buffer = state["buffer"]
    critics = TwinQ(buffer["obs"].shape[1], buffer["samples"].shape[1], hidden, n=n, layer_norm=layer_norm)
    critics.load_state_dict(state["critics"])
    return critics.eval(), state


def critic_gradients(path: str) -> None:
    policy, _, meta = load_policy(path)
    critics, state = load_critics(path)
    obs = state["buffer"]["obs"][-5000:]
    m = margin_of(meta)
    with torch.no_grad():
        u = policy.distribution(obs).mode().clone()  # the Beta means, in (0, 1)
    u.requires_grad_(True)
    (grad,) = torch.autograd.grad(critics(obs, u).min(0).values.sum(), u)
    per_weight = (grad / (1 + 2 * m)).abs()  # dQ per unit of the weight the action filter applies
    applied = (-m + (1 + 2 * m) * u.detach()).clamp(0.0, 1.0)
    angle = torch.atan2(obs[:, 2], obs[:, 1]).abs()
    print(f"{path}: skills {meta.get('skills')}")
    for name, mask in (("|angle| < 0.5", angle < 0.5), ("|angle| >= 0.5", angle >= 0.5)):
        print(
            f"  {name} ({int(mask.sum())} states): median |dQ/dw| "
            + " ".join(f"{v:.2f}" for v in per_weight[mask].median(0).values.tolist())
            + " | share of weights inside (0, 1): "
            + " ".join(f"{v:.2f}" for v in ((applied > 0) & (applied < 1))[mask].float().mean(0).tolist())
        )


def discounted_returns(rewards: np.ndarray, obs: np.ndarray, next_obs: np.ndarray, gamma: float) -> np.ndarray:
    """The discounted return every stored decision actually got, from the buffer alone (a Monte Carlo estimate), NaN
    where fewer than the decisions that carry 95 % of the weight follow in its episode. The buffer holds the decisions
    of ``n`` envs interleaved; ``n`` is the smallest lag at which a row's ``next_obs`` is the ``obs`` of the row that
    lag later, and an episode ends where that chain breaks (a time limit: cartpole_swingup ends no other way)."""
    size = len(rewards)
    lag = next((n for n in range(1, 17) if np.mean(np.all(next_obs[: size - n] == obs[n:], axis=1)) > 0.9), None)
    if lag is None:
        raise SystemExit("the buffer's rows do not chain into episodes (no lag of 1-16 envs fits)")
    tail = int(np.ceil(np.log(0.05) / np.log(gamma)))
    returns = np.full(size, np.nan)
    for env in range(lag):
        rows = np.arange(env, size, lag)
        chained = np.all(next_obs[rows[:-1]] == obs[rows[1:]], axis=1)
        starts = np.concatenate([[0], np.flatnonzero(~chained) + 1, [len(rows)]])
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            g, acc = np.zeros(b - a), 0.0
            for t in range(b - a - 1, -1, -1):
                acc = rewards[rows[a + t]] + gamma * acc
                g[t] = acc
            complete = max(b - a - tail, 0)  # a time limit or the newest decision cuts the sum: drop its tail
            returns[rows[a : a + complete]] = g[:complete]
    return returns


def critic_returns(path: str, last: int = 2500) -> None:
    """How far a SAC run's critics are from the returns the replayed episodes got: on the buffer's newest ``last``
    decisions with a complete discounted return, the critics' min Q(s, w) at the stored weights against that return.
    A ratio well below 1 means the critics still see only a few decisions ahead (their values grow from 0 by one
    bootstrapped decision per target-network lag), so the actor follows a short-sighted objective."""
    critics, state = load_critics(path)
    buffer = state["buffer"]
    discount = buffer["discount"].numpy()
    if not np.allclose(discount, discount[0]):
        raise SystemExit(f"{path}: multi-decision targets (sac.n_step > 1) are not read here")
    obs, next_obs = buffer["obs"].numpy(), buffer["next_obs"].numpy()
    returns = discounted_returns(buffer["rewards"].numpy(), obs, next_obs, float(discount[0]))
    rows = np.flatnonzero(~np.isnan(returns))[-last:]
    with torch.no_grad():
        q = critics(buffer["obs"][rows], buffer["samples"][rows]).min(0).values.numpy()
    g = returns[rows]
    print(f"{path}: {len(rows)} decisions, gamma {discount[0]:.3f} per decision: mean Q {q.mean():.1f}, mean return "
          f"{g.mean():.1f}, ratio {q.mean() / g.mean():.2f}, correlation {np.corrcoef(q, g)[0, 1]:.2f}")


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
    parser.add_argument("--by-angle", action="store_true")
    parser.add_argument("--critic-gradients", action="store_true")
    parser.add_argument("--critic-returns", action="store_true")
    parser.add_argument("--recording", help="a run directory: weights by |angle| band from its recording")
    parser.add_argument("--steps", type=int, nargs="*", default=[], help="the evaluations (env steps) to read")
    parser.add_argument("--action-filter", default="sum", choices=("sum", "convex"))
    args = parser.parse_args()
    if args.recording:
        recording_by_angle(args.recording, args.steps)
    if args.soft_rules:
        soft_rules(args.episodes, args.action_filter)
    for ckpt in args.checkpoints:
        if args.critic_returns:
            critic_returns(ckpt)
            continue
        if args.by_angle or args.critic_gradients:
            (by_angle(ckpt, args.episodes) if args.by_angle else critic_gradients(ckpt))
            continue
        stats = diagnose(ckpt, args.episodes)
        print(ckpt, " | ".join(f"{k} {v:.3g}" for k, v in stats.items()))
