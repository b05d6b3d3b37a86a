"""Benchmark for panda_reach: success on random targets never seen in training, for HRTC (Beta), PPO (Beta) on raw
joint velocities at the same env-step budget, each skill alone, and a hand-written handover rule for reference.

    python scripts/bench_panda_reach.py [--targets 1000] [--steps 150000] [--seed 1] [--runs runs/bench_panda_reach]
        [--workers 2] [--out benchmarks/results/panda_reach]

Training runs are the real CLI (``scripts/train.py task=panda_reach``) in a subprocess, skipped when ``--runs`` already
holds a run that reached ``--steps``; the learned policies are evaluated from their ``best.pt`` (chosen on the
trainer's own evaluation seeds, disjoint from the test seeds; ``--checkpoint last``: ``last.pt``) with the
distribution's mean.

Test episodes reset with seeds 2_000_000 + i (training resets use 1000 seed + i and continue from there; the
trainer's evaluations use 1_000_000 + ...): the same 1000 targets for every method. An episode counts as a success
when the end effector comes within 1 cm of the target at any step of its 3 s; it ends there (the reach is done), so
"collision" means the arm touched the wall or the table before reaching (or in the whole episode if it never did).
Writes results.json (everything, per target family too), table.md, command.txt and machine.txt into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TASK = "panda_reach"
TEST_SEED = 2_000_000
FIXED = {  # weights in the task's skill order (reach, posture, avoid, hold)
    "reach alone (IK)": [1.0, 0.0, 0.0, 0.0],
    "posture alone": [0.0, 1.0, 0.0, 0.0],
    "avoid alone": [0.0, 0.0, 1.0, 0.0],
    "hold alone": [0.0, 0.0, 0.0, 1.0],
    "uniform blend (1/4 each)": [0.25, 0.25, 0.25, 0.25],
    "untrained HRTC (every weight at the initial Beta mean, 0.5)": [0.5, 0.5, 0.5, 0.5],
    "constant blend reach + avoid (1, 1)": [1.0, 0.0, 1.0, 0.0],
}
SCRIPTED = "handover rule (hand-written)"


def train_run(algo: str, seed: int, steps: int, run_dir: Path) -> dict[str, Any]:
    """Train with the CLI unless ``run_dir`` already reached ``steps``; returns its eval curve and throughput."""
    from hrtc.benchmark.runs import last_eval_step

    if last_eval_step(run_dir) < steps:
        cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), f"task={TASK}", f"algo={algo}", "dist=beta",
               f"seed={seed}", f"steps={steps}", "progress=false", f"hydra.run.dir={run_dir}"]  # fmt: skip
        tic = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        print(f"  trained {algo}: {time.perf_counter() - tic:.0f} s", flush=True)
    evals, train = pd.read_csv(run_dir / "eval.csv"), pd.read_csv(run_dir / "train.csv")
    return {
        "run_dir": str(run_dir),
        "curve": {"step": evals["step"].tolist(), "episode_reward": evals["episode_reward"].tolist()},
        "best_eval": float(evals["episode_reward"].max()),
        "steps": int(evals["step"].iloc[-1]),
        "sps_median": float(train["charts/SPS"].median()),
        "wall_seconds": float(evals["wall_seconds"].iloc[-1]),
    }


# --------------------------------------------------------------------------------------------------- evaluation
def _deciders(method: str, checkpoint: str | None) -> tuple[Any, Callable[[np.ndarray, Any], np.ndarray], int]:
    """(env, decide(obs, env) -> env action, env steps per decision) for ``method``."""
    from hrtc.checkpoint import load_policy
    from hrtc.cli import task_config
    from hrtc.environments import make_env
    from hrtc.policy import to_action

    skills = task_config(TASK)["skills"]
    if checkpoint is not None:
        import torch

        torch.set_num_threads(1)
        policy, normalizer, meta = load_policy(checkpoint)
        every = int(meta["decision_every"])
        # Built to step one env step at a time (the decision is held for ``every`` steps by evaluate_chunk), so
        # that success and collisions are seen at every env step, not only at the decision's last one.
        env = make_env(TASK, meta["algo"], meta["skills_cfg"], meta["action_filter"], meta["env_kwargs"], 1)

        def decide(obs: np.ndarray, env: Any) -> np.ndarray:
            x = obs[None].astype(np.float32)
            x = normalizer(x, False) if normalizer is not None else x
            with torch.no_grad():
                u = policy.distribution(torch.as_tensor(x)).mode().numpy()[0]
            return to_action(u, env.action_space.low, env.action_space.high, meta["dist"]).astype(np.float32)

        return env, decide, every
    if method == SCRIPTED:
        env = make_env(TASK, "hrtc", skills)
        base = env.unwrapped

        def decide(obs: np.ndarray, env: Any) -> np.ndarray:
            # Over the wall with the avoidance skill until the hand is above a target behind it, then the reach.
            state = base.skill_state()
            above = np.linalg.norm(state["ee_pos"][:2] - state["target_pos"][:2]) < 0.03
            go_over = base._behind_wall(state["target_pos"]) and not above
            return np.array([0.0, 0.0, 1.0, 0.0] if go_over else [1.0, 0.0, 0.0, 0.0])

        return env, decide, 1
    # Only the skills with a non-zero weight: the others would add exactly nothing to the blend, at their cost.
    chosen = {name: w for name, w in zip(skills, FIXED[method], strict=True) if w > 0}
    env = make_env(TASK, "hrtc", {name: skills[name] for name in chosen})
    weights = np.asarray(list(chosen.values()), dtype=np.float64)
    return env, (lambda obs, env: weights), 1


def evaluate_chunk(method: str, checkpoint: str | None, seeds: Sequence[int]) -> list[dict[str, float]]:
    """One row per test episode: family, success, time to reach (s), collision, closest distance (m)."""
    env, decide, every = _deciders(method, checkpoint)
    base = env.unwrapped
    rows = []
    for seed in seeds:
        obs, info = env.reset(seed=int(seed))
        family, collided, reached, closest, steps = info.get("family", base.family), False, None, np.inf, 0
        done, action = False, None
        while not done:
            if steps % every == 0:  # the meta-policy's decision rate; skills and fixed weights act every step
                action = decide(obs, env)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            collided |= bool(info["collision"])
            closest = min(closest, float(info["distance"]))
            if info["success"]:
                reached = steps * base.dt
            done = terminated or truncated or reached is not None
        rows.append({"seed": int(seed), "family": int(family), "success": reached is not None,
                     "time_to_reach": reached if reached is not None else float("nan"), "collision": collided,
                     "closest": closest})  # fmt: skip
    env.close()
    return rows


def summarise(rows: list[dict[str, float]]) -> dict[str, Any]:
    df = pd.DataFrame(rows)

    def stats(d: pd.DataFrame) -> dict[str, float]:
        return {
            "targets": len(d),
            "success": float(d["success"].mean()),
            "collision": float(d["collision"].mean()),
            "success_without_collision": float((d["success"] & ~d["collision"]).mean()),
            "mean_time_to_reach_s": float(d["time_to_reach"].mean()) if d["success"].any() else float("nan"),
            "median_closest_mm": float(d["closest"].median() * 1e3),
        }

    from envs.panda_reach import FAMILIES

    return {"all": stats(df), **{name: stats(df[df["family"] == i]) for i, name in enumerate(FAMILIES)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--targets", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=150_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--runs", type=Path, default=ROOT / "runs" / "bench_panda_reach")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "panda_reach")
    parser.add_argument("--methods", nargs="*", default=None, help="evaluate only these (names as in table.md)")
    parser.add_argument("--checkpoint", choices=("best", "last"), default="best", help="the learned runs' "
                        "checkpoint: best.pt (chosen on the trainer's evaluations) or last.pt")  # fmt: skip
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    learned = {"hrtc": "HRTC (Beta), learned", "ppo": "PPO (Beta) on raw joint velocities"}
    methods: dict[str, str | None] = {
        **{
            name: str(args.runs / f"{algo}_s{args.seed}" / "checkpoints" / f"{args.checkpoint}.pt")
            for algo, name in learned.items()
        },
        **{name: None for name in FIXED},
        SCRIPTED: None,
    }
    if args.methods:
        unknown = set(args.methods) - set(methods)
        if unknown:
            parser.error(f"unknown methods {sorted(unknown)}; valid: {list(methods)}")
        methods = {k: v for k, v in methods.items() if k in args.methods}
    training = {algo: train_run(algo, args.seed, args.steps, args.runs / f"{algo}_s{args.seed}")
                for algo, name in learned.items() if name in methods}  # fmt: skip
    seeds = [TEST_SEED + i for i in range(args.targets)]
    chunks = [seeds[i :: args.workers] for i in range(args.workers)]
    results: dict[str, Any] = {}
    previous = args.out / "results.json"
    if args.methods and previous.exists():
        results = json.loads(previous.read_text()).get("methods", {})
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for name, checkpoint in methods.items():
            tic = time.perf_counter()
            parts = pool.map(evaluate_chunk, [name] * len(chunks), [checkpoint] * len(chunks), chunks)
            rows = sorted((r for part in parts for r in part), key=lambda r: r["seed"])
            results[name] = {"summary": summarise(rows), "episodes": rows, "checkpoint": checkpoint}
            s = results[name]["summary"]["all"]
            partial = {"targets": args.targets, "test_seed": TEST_SEED, "methods": results}
            (args.out / "results.json").write_text(json.dumps(partial, indent=1))  # kept after every method
            took = time.perf_counter() - tic
            print(f"{name}: success {s['success']:.3f}, collisions {s['collision']:.3f}, "
                  f"time {s['mean_time_to_reach_s']:.2f} s ({took:.0f} s)", flush=True)  # fmt: skip

    everything = {"targets": args.targets, "test_seed": TEST_SEED, "training": training, "methods": results}
    (args.out / "results.json").write_text(json.dumps(everything, indent=1))
    (args.out / "table.md").write_text(table(results, training, args))
    (args.out / "command.txt").write_text("python scripts/bench_panda_reach.py " + " ".join(sys.argv[1:]) + "\n")
    import torch

    (args.out / "machine.txt").write_text(
        f"{platform.platform()}; python {platform.python_version()}; {os.cpu_count()} cores; torch "
        f"{torch.__version__}; {platform.machine()}; date {time.strftime('%Y-%m-%d')}\n"
    )
    print((args.out / "table.md").read_text())


def table(results: dict[str, Any], training: dict[str, Any], args: argparse.Namespace) -> str:
    lines = [
        f"# panda_reach: {args.targets} random targets never seen in training",
        "",
        f"Success: the end effector within 1 cm of the target within the 3 s episode. Collisions: the arm touched "
        f"the wall or the table before reaching. Time: mean over the successful episodes. Learned policies: "
        f"{args.steps} env steps, seed {args.seed}, `{args.checkpoint}.pt`, deterministic (the Beta mean).",
        "",
        "| method | success | collisions | success without collision | mean time to reach (s) |"
        " success free / limit / behind |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        s = r["summary"]
        a = s["all"]
        lines.append(
            f"| {name} | {a['success']:.1%} | {a['collision']:.1%} | {a['success_without_collision']:.1%} | "
            f"{a['mean_time_to_reach_s']:.2f} | {s['free']['success']:.1%} / {s['limit']['success']:.1%} / "
            f"{s['behind']['success']:.1%} |"
        )
    lines += ["", "| training run | env steps | best eval return | wall (s) | env steps/s |", "|---|---|---|---|---|"]
    for algo, t in training.items():
        lines.append(
            f"| {algo} | {t['steps']} | {t['best_eval']:.1f} | {t['wall_seconds']:.0f} | {t['sps_median']:.0f} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
