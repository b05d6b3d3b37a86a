"""Benchmark for the paper's LunarLander (§4, Fig. 3): HRTC (Beta) on ``lunarlander`` against each skill alone, fixed
blends, our PPO (Beta and Normal) on raw actions and stable-baselines3 PPO and SAC, at one env-step budget.

    python scripts/bench_lunarlander.py [--seeds 1 2 3] [--steps 100000] [--sac-seeds 1]
        [--only hrtc_beta ppo_beta ...] [--out benchmarks/results/lunarlander]

The goal (issue 4): HRTC (Beta) reaches a mean return of at least 200 over 100 evaluation episodes within 100,000 env
steps, median over seeds. Protocol, the same for every learner:

- periodic evaluation every ``--eval-every`` env steps: the mean of ``--eval-episodes`` deterministic episodes (the
  Beta mean for HRTC, SB3's ``deterministic=True``) on seeds ``1_000_000 + 1000 seed + k`` (the trainer's
  ``eval_seeds``). It draws the curve and picks ``best``. **steps-to-200**: the first periodic evaluation at or
  above 200.
- final evaluation: the policy after the budget (``final``) and the best periodic one (``best``; HRTC/PPO keep it
  as ``best.pt``, SB3 as a saved copy) each run ``--final-episodes`` (100) deterministic episodes on seeds
  ``2_000_000 + 1000 seed + k``, disjoint from the periodic ones that selected ``best``.

Each HRTC/PPO run is the real CLI (``scripts/train.py``) in a subprocess. Results are cached per run (rerunning
resumes where it stopped); ``--report-only`` rewrites table.md and curves.png from results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TASK = "lunarlander"
FINAL_SEED_BASE = 2_000_000


def _task_config() -> dict:
    from hrtc.cli import task_config

    return task_config(TASK)


THRESHOLD = float(_task_config()["solve_threshold"])  # 200


def final_seeds(seed: int, episodes: int) -> list[int]:
    """Seeds of the final 100-episode evaluation: disjoint from training and from the periodic evaluations."""
    return [FINAL_SEED_BASE + 1_000 * seed + k for k in range(episodes)]


def _steps_to(steps: list[int], rewards: list[float], threshold: float) -> int | None:
    for step, reward in zip(steps, rewards, strict=True):
        if reward >= threshold:
            return int(step)
    return None


def _summary(returns: list[float]) -> dict:
    array = np.asarray(returns, dtype=np.float64)
    return {"mean": float(array.mean()), "std": float(array.std()), "episodes": len(array), "returns": array.tolist()}


# --------------------------------------------------------------------------------------------------- our trainer
def checkpoint_returns(path: Path, seeds: list[int]) -> list[float]:
    """Deterministic returns of a trainer checkpoint (HRTC or PPO) on ``seeds``."""
    import torch

    from hrtc.checkpoint import load_policy
    from hrtc.environments import make_env
    from hrtc.episodes import evaluate

    torch.set_num_threads(1)
    loaded = load_policy(path)
    meta = loaded.meta
    env = make_env(TASK, meta["algo"], meta["skills_cfg"], meta["action_filter"], meta["env_kwargs"],
                   meta["decision_every"])  # fmt: skip
    try:
        return evaluate(loaded.policy, loaded.normalizer, env, seeds, meta["dist"]).tolist()
    finally:
        env.close()


def train_run(name: str, overrides: list[str], run_dir: Path, seed: int, args: argparse.Namespace) -> dict:
    """Run scripts/train.py (unless its results are cached); evaluate its final and best checkpoints."""
    cache = run_dir / "bench.json"
    if cache.exists():
        return json.loads(cache.read_text())
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), f"task={TASK}", f"steps={args.steps}",
           f"eval_every={args.eval_every}", f"eval_episodes={args.eval_episodes}", f"seed={seed}", "progress=false",
           f"hydra.run.dir={run_dir}", *overrides]  # fmt: skip
    tic = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    train_seconds = time.perf_counter() - tic
    evals, train = pd.read_csv(run_dir / "eval.csv"), pd.read_csv(run_dir / "train.csv")
    steps, rewards = evals["step"].astype(int).tolist(), evals["episode_reward"].astype(float).tolist()
    seeds = final_seeds(seed, args.final_episodes)
    result = {
        "curve": {"step": steps, "episode_reward": rewards},
        "steps_to_threshold": _steps_to(steps, rewards, THRESHOLD),
        "final": _summary(checkpoint_returns(run_dir / "checkpoints" / "last.pt", seeds)),
        "best": _summary(checkpoint_returns(run_dir / "checkpoints" / "best.pt", seeds)),
        "best_step": int(evals.loc[evals["episode_reward"].idxmax(), "step"]),
        "env_steps": int(steps[-1]),
        "sps_median": float(train["charts/SPS"].median()),
        "wall_seconds": train_seconds,
        "command": " ".join(cmd[1:]),
    }
    cache.write_text(json.dumps(result))
    print(f"  {name} seed {seed}: {train_seconds:.0f} s, final {result['final']['mean']:.1f}, "
          f"best {result['best']['mean']:.1f}, steps to 200: {result['steps_to_threshold']}", flush=True)  # fmt: skip
    return result


# --------------------------------------------------------------------------------------------------- fixed blends
def fixed_weights(weights: np.ndarray, seeds: list[int]) -> list[float]:
    """Returns of the composed task under constant skill weights (a skill alone, or a fixed blend)."""
    from hrtc.environments import make_env
    from hrtc.episodes import Decision, run_episodes

    cfg = _task_config()
    env = make_env(TASK, "hrtc", cfg["skills"], env_kwargs=cfg.get("env_kwargs"))
    action = np.asarray(weights, dtype=np.float32)
    return run_episodes(env, lambda obs: Decision(obs, action, action), seeds).tolist()


def gymnasium_heuristic(seeds: list[int]) -> list[float]:
    """gymnasium's own landing heuristic (the one the skills decompose), for reference."""
    from gymnasium.envs.box2d.lunar_lander import heuristic

    import envs

    env = envs.make(TASK)
    returns = []
    for s in seeds:
        obs, _ = env.reset(seed=s)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(heuristic(env, obs).astype(np.float32))
            total += reward
            done = terminated or truncated
        returns.append(total)
    return returns


# --------------------------------------------------------------------------------------------------- SB3
def sb3_run(algo: str, seed: int, args: argparse.Namespace, minutes: float | None = None) -> dict:
    """stable-baselines3 PPO or SAC, default hyperparameters (SAC: MLP 256x256, 1 gradient step per env step), on the
    same task adapter with the same evaluation protocol. ``minutes`` caps the training wall time (checked at each
    periodic evaluation): a capped run reports the steps it reached (``env_steps``) and ``capped: true``."""
    cache = args.out / f"sb3_{algo}_seed{seed}.json"
    if cache.exists():
        return json.loads(cache.read_text())
    import torch
    from stable_baselines3 import PPO, SAC

    import envs
    from hrtc.episodes import eval_seeds

    torch.set_num_threads(1)
    env, eval_env = envs.make(TASK), envs.make(TASK)
    env.reset(seed=seed)
    model = (PPO if algo == "ppo" else SAC)("MlpPolicy", env, seed=seed, device="cpu", verbose=0)

    def returns(seeds: list[int], policy) -> list[float]:
        out = []
        for s in seeds:
            obs, _ = eval_env.reset(seed=s)
            total, done = 0.0, False
            while not done:
                action, _ = policy.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, _ = eval_env.step(action)
                total += reward
                done = terminated or truncated
            out.append(total)
        return out

    best_path = args.runs / f"sb3_{algo}" / f"seed{seed}" / "best.zip"
    best_path.parent.mkdir(parents=True, exist_ok=True)
    curve: dict[str, list] = {
        "step": [0],
        "episode_reward": [float(np.mean(returns(eval_seeds(seed, args.eval_episodes), model)))],
    }
    model.save(best_path)
    tic, train_seconds = time.perf_counter(), 0.0
    partial = args.out / f"sb3_{algo}_seed{seed}.partial.json"  # the curve so far, for a run that is stopped
    capped = False
    while model.num_timesteps < args.steps:
        if minutes is not None and time.perf_counter() - tic > 60.0 * minutes:
            capped = True
            break
        t0 = time.perf_counter()
        model.learn(min(args.eval_every, args.steps - model.num_timesteps), reset_num_timesteps=False)
        train_seconds += time.perf_counter() - t0
        mean = float(np.mean(returns(eval_seeds(seed, args.eval_episodes), model)))
        if mean > max(curve["episode_reward"]):
            model.save(best_path)
        curve["step"].append(int(model.num_timesteps))
        curve["episode_reward"].append(mean)
        partial.write_text(json.dumps({"curve": curve, "train_seconds": train_seconds}))
        print(f"    sb3_{algo} seed {seed}: {model.num_timesteps} steps, eval {mean:.1f}", flush=True)
    seeds = final_seeds(seed, args.final_episodes)
    best = (PPO if algo == "ppo" else SAC).load(best_path, device="cpu")
    result = {
        "curve": curve,
        "steps_to_threshold": _steps_to(curve["step"], curve["episode_reward"], THRESHOLD),
        "final": _summary(returns(seeds, model)),
        "best": _summary(returns(seeds, best)),
        "best_step": int(curve["step"][int(np.argmax(curve["episode_reward"]))]),
        "env_steps": int(model.num_timesteps),
        "sps_median": model.num_timesteps / train_seconds,
        "wall_seconds": time.perf_counter() - tic,
        "capped": capped,
    }
    cache.write_text(json.dumps(result))
    print(
        f"  sb3_{algo} seed {seed}: final {result['final']['mean']:.1f}, best {result['best']['mean']:.1f}", flush=True
    )
    return result


def sb3_partial(algo: str, seed: int, args: argparse.Namespace) -> dict | None:
    """An SB3 run stopped before its end (the machine could not afford it): its periodic evaluations only. ``final``
    and ``best`` are then the last and the best periodic evaluation (``eval_episodes`` episodes, not 100)."""
    path = args.out / f"sb3_{algo}_seed{seed}.partial.json"
    if not path.exists():
        return None
    saved = json.loads(path.read_text())
    curve = saved["curve"]
    rewards = curve["episode_reward"]
    periodic = {"episodes": args.eval_episodes, "std": float("nan"), "returns": []}
    return {
        "curve": curve,
        "steps_to_threshold": _steps_to(curve["step"], rewards, THRESHOLD),
        "final": {**periodic, "mean": float(rewards[-1])},
        "best": {**periodic, "mean": float(max(rewards))},
        "best_step": int(curve["step"][int(np.argmax(rewards))]),
        "env_steps": int(curve["step"][-1]),
        "sps_median": curve["step"][-1] / max(saved["train_seconds"], 1e-9),
        "partial": True,
    }


# --------------------------------------------------------------------------------------------------- main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--sac-seeds", type=int, nargs="*", default=[1], help="SB3 SAC is slow on CPU (~50 steps/s)")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--sac-minutes", type=float, default=None, help="cap SB3 SAC's training wall time per seed")
    parser.add_argument("--eval-every", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--final-episodes", type=int, default=100)
    parser.add_argument("--only", nargs="*", default=None, help="run only these methods (e.g. sb3_sac hrtc_beta)")
    parser.add_argument("--overrides", nargs="*", default=[], help="extra train.py overrides for the HRTC runs")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/lunarlander")
    parser.add_argument("--runs", type=Path, default=ROOT / "runs/bench_lunarlander", help="run dirs (not committed)")
    parser.add_argument("--note", action="append", default=[], help="a note for table.md (repeatable)")
    parser.add_argument("--no-train", action="store_true", help="assemble the report from finished runs only; an "
                        "SB3 run that was stopped enters with its periodic evaluations (marked partial)")  # fmt: skip
    parser.add_argument("--report-only", action="store_true", help="rewrite table.md and curves.png from results.json")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results_path = args.out / "results.json"
    results: dict = json.loads(results_path.read_text()) if results_path.exists() else {}
    if args.report_only:
        write_report(results, args.out)
        return
    results.update({"task": TASK, "threshold": THRESHOLD, "steps": args.steps, "eval_every": args.eval_every,
                    "eval_episodes": args.eval_episodes, "final_episodes": args.final_episodes})  # fmt: skip
    results.setdefault("runs", {})
    wanted = lambda name: args.only is None or name in args.only  # noqa: E731

    # PPO on raw actions runs with the root config's PPO settings (CleanRL-like: lr 3e-4 annealed, 1024-step
    # rollouts, gamma 0.99), which suit it better than the task's HRTC-tuned ones.
    ppo_defaults = ["ppo.learning_rate=3e-4", "ppo.anneal_lr=true", "ppo.num_steps=512", "ppo.gamma=0.99"]
    variants = {
        "hrtc_beta": ["algo=hrtc", "dist=beta", *args.overrides],
        "hrtc_normal": ["algo=hrtc", "dist=normal", *args.overrides],
        "ppo_beta": ["algo=ppo", "dist=beta", *ppo_defaults],
        "ppo_normal": ["algo=ppo", "dist=normal", *ppo_defaults],
    }
    for name, overrides in variants.items():
        if not wanted(name):
            continue
        for seed in args.seeds:
            print(f"{name} seed {seed}", flush=True)
            if args.no_train and not (args.runs / name / f"seed{seed}" / "bench.json").exists():
                continue
            run = train_run(name, overrides, args.runs / name / f"seed{seed}", seed, args)
            results["runs"].setdefault(name, {})[str(seed)] = run
            results_path.write_text(json.dumps(results, indent=1))
    for algo, seeds in (("ppo", args.seeds), ("sac", args.sac_seeds)):
        if not wanted(f"sb3_{algo}"):
            continue
        for seed in seeds:
            print(f"sb3_{algo} seed {seed}", flush=True)
            minutes = args.sac_minutes if algo == "sac" else None
            if args.no_train and not (args.out / f"sb3_{algo}_seed{seed}.json").exists():
                run = sb3_partial(algo, seed, args)
                if run is None:
                    continue
            else:
                run = sb3_run(algo, seed, args, minutes)
            results["runs"].setdefault(f"sb3_{algo}", {})[str(seed)] = run
            results_path.write_text(json.dumps(results, indent=1))

    fixed_cache = args.out / "fixed.json"
    if wanted("fixed") and fixed_cache.exists():
        results["fixed"] = json.loads(fixed_cache.read_text())
    elif wanted("fixed"):
        names = list(_task_config()["skills"])
        index = {n: i for i, n in enumerate(names)}
        fixed = {f"{n} alone": np.eye(len(names))[i] for i, n in enumerate(names)}
        fixed["uniform blend (1/K each)"] = np.full(len(names), 1 / len(names))
        fixed["uniform blend (0.5 each: HRTC's initial Beta mean)"] = np.full(len(names), 0.5)
        hand = np.zeros(len(names))
        hand[[index["centring"], index["descent"], index["touchdown"]]] = 1.0
        fixed["hand blend (centring + descent + touchdown, 1 each)"] = hand
        seeds = final_seeds(0, args.final_episodes)
        results["fixed"] = {k: _summary(fixed_weights(w, seeds)) for k, w in fixed.items()}
        results["fixed"]["gymnasium's heuristic (reference, not a skill)"] = _summary(gymnasium_heuristic(seeds))
        fixed_cache.write_text(json.dumps(results["fixed"]))
        results_path.write_text(json.dumps(results, indent=1))
    # Every invocation that fed these results, in order (runs are cached: a later one reuses earlier runs).
    with (args.out / "command.txt").open("a") as handle:
        handle.write("python scripts/bench_lunarlander.py " + shlex.join(sys.argv[1:]) + "\n")
    (args.out / "machine.txt").write_text(_machine())
    results["notes"] = NOTES + args.note
    results_path.write_text(json.dumps(results, indent=1))
    write_report(results, args.out)


# --------------------------------------------------------------------------------------------------- report
NOTES = [
    "hrtc_*: the task's settings (hrtc/conf/task/lunarlander.yaml); the meta-policy's observation is the task's 8-d "
    "observation, its action the 6 skill weights, evaluated with the Beta mean.",
    "ppo_beta / ppo_normal: our PPO on the raw 2-d action with the root defaults (lr 3e-4 annealed, 2 x 512-step "
    "rollouts, gamma 0.99), the same networks (64x64).",
    "sb3_ppo / sb3_sac: stable-baselines3 2.9.2 with default hyperparameters, 1 env; SB3 PPO collects 2,048-step "
    "rollouts, so its evaluations fall on multiples of 2,048 (its last after 100,352 steps).",
    "Fixed blends run the composed task with constant weights (no learning), on the final-evaluation seeds of seed 0.",
    "Reference (rl-baselines3-zoo, one seed, LunarLanderContinuous): PPO 271 after 1M steps, SAC 260 after 500k.",
]


def _median_steps(hits: list) -> str:
    # A seed that never reached the threshold counts as above the budget.
    values = sorted(np.inf if h is None else h for h in hits)
    n = len(values)
    med = values[n // 2] if n % 2 else (values[n // 2 - 1] + values[n // 2]) / 2
    return "not reached" if not np.isfinite(med) else f"{med:.0f}"


ORDER = ("hrtc_beta", "hrtc_normal", "ppo_beta", "ppo_normal", "sb3_ppo", "sb3_sac")


def _ordered(runs: dict) -> list[tuple[str, dict]]:
    """Methods in the table's order, each with its runs sorted by seed."""
    names = sorted(runs, key=lambda n: ORDER.index(n) if n in ORDER else len(ORDER))
    return [(n, dict(sorted(runs[n].items(), key=lambda kv: int(kv[0])))) for n in names]


def write_report(results: dict, out: Path) -> None:
    final_n, eval_n = results.get("final_episodes", 100), results.get("eval_episodes", 10)
    lines = [
        f"# {TASK}: {results['steps']:,} env steps, threshold {THRESHOLD:.0f}",
        "",
        f"Final and best: mean return over {final_n} deterministic evaluation episodes (Beta mean for HRTC) on seeds "
        "disjoint from training and from the periodic evaluations. Steps to 200: the first periodic evaluation "
        f"(every {results.get('eval_every', 10_000):,} env steps, {eval_n} episodes) at or above 200.",
        "",
        "| method | seeds | final (100 ep.) per seed | **median final** | best (100 ep.) per seed | median best "
        "| steps to 200 per seed | median steps to 200 | train env steps/s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, runs in _ordered(results.get("runs", {})):
        capped = [f"{r['env_steps']:,}" for r in runs.values() if r.get("capped")]
        if capped:
            name = f"{name} (time-capped at {', '.join(capped)} env steps)"
        partial = [f"{r['env_steps']:,}" for r in runs.values() if r.get("partial")]
        if partial:
            name = (f"{name} (**stopped at {', '.join(partial)} env steps**; final and best are "
                    f"{eval_n}-episode periodic evaluations)")  # fmt: skip
        finals = [r["final"]["mean"] for r in runs.values()]
        bests = [r["best"]["mean"] for r in runs.values()]
        hits = [r["steps_to_threshold"] for r in runs.values()]
        lines.append(
            f"| {name} | {len(runs)} | {', '.join(f'{f:.0f}' for f in finals)} | **{np.median(finals):.0f}** "
            f"| {', '.join(f'{b:.0f}' for b in bests)} | {np.median(bests):.0f} "
            f"| {', '.join('-' if h is None else f'{h:,}' for h in hits)} | {_median_steps(hits)} "
            f"| {np.median([r['sps_median'] for r in runs.values()]):.0f} |"
        )
    for name, summary in results.get("fixed", {}).items():
        lines.append(f"| {name} (no training) | | {summary['mean']:.0f} ± {summary['std']:.0f} over "
                     f"{summary['episodes']} episodes | {summary['mean']:.0f} | | | | | |")  # fmt: skip
    notes = results.get("notes", [])
    if notes:
        lines += ["", "Notes:", *[f"- {n}" for n in notes]]
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if results.get("runs"):
        _plot(results, out / "curves.png")


def _plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 5))
    for i, (name, runs) in enumerate(_ordered(results["runs"])):
        curves = [pd.Series(r["curve"]["episode_reward"], index=r["curve"]["step"]) for r in runs.values()]
        frame = pd.concat(curves, axis=1).sort_index().interpolate(limit_area="inside")
        color = f"C{i}"
        ax.plot(frame.index, frame.median(axis=1), color=color, label=f"{name} (median of {len(curves)})")
        ax.fill_between(frame.index, frame.min(axis=1), frame.max(axis=1), color=color, alpha=0.15)
    fixed = {k: v for k, v in results.get("fixed", {}).items() if "alone" not in k}
    greys = plt.get_cmap("Greys")(np.linspace(0.35, 0.9, max(len(fixed), 1)))
    for shade, (name, summary) in zip(greys, fixed.items(), strict=False):
        ax.axhline(summary["mean"], color=shade, ls=":", lw=1.2, label=f"{name}: {summary['mean']:.0f}")
    ax.axhline(THRESHOLD, color="k", ls="--", lw=1, label=f"threshold {THRESHOLD:.0f}")
    ax.set_ylim(bottom=-400)
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"evaluation return ({results.get('eval_episodes', 10)} episodes)")
    ax.set_title(f"{TASK}: median and min-max band over seeds")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _machine() -> str:
    import torch

    return (
        f"{platform.platform()}; python {platform.python_version()}; {os.cpu_count()} cores (shared with other jobs); "
        f"torch {torch.__version__}; {platform.processor() or platform.machine()}; date {time.strftime('%Y-%m-%d')}\n"
    )


if __name__ == "__main__":
    main()
