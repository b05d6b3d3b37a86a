"""The tree learned with SAC: each run's final policy and the references over the same skills, on 10 episodes.

    python benchmarks/results/cartpole_swingup/tree_transfer/sac/final.py RUN_DIR [RUN_DIR...] [--episodes 10]

The references (each child alone, the untrained blend, the task's fixed blend) and every run's ``last.pt`` act on
the evaluation seeds of seed 1 (``hrtc.episodes.eval_seeds``), which no training run used. Prints a markdown table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[5]))

from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.cli import task_config  # noqa: E402
from hrtc.environments import make_env  # noqa: E402
from hrtc.episodes import eval_seeds, mode_decider, run_episodes  # noqa: E402
from hrtc.references import evaluate_rules, reference_rules  # noqa: E402

if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    task = task_config("cartpole_swingup_tree")
    env = make_env("cartpole_swingup", "hrtc", task["skills"], decision_every=5)
    seeds = eval_seeds(1, args.episodes)
    print(f"| policy | mean return over {args.episodes} episodes | std |\n|---|---|---|")
    for run in args.runs:
        loaded = load_policy(Path(run) / "checkpoints" / "last.pt")
        returns = run_episodes(env, mode_decider(loaded.policy, loaded.normalizer, env.action_space, "beta"), seeds)
        print(f"| {Path(run).name} last.pt (learner=sac, 100k) | {returns.mean():.1f} | {returns.std():.1f} |")
    rules = reference_rules(env.skill_names, task.get("references"))
    for name, returns in evaluate_rules(env, rules, seeds).items():
        print(f"| {name} | {returns.mean():.1f} | {returns.std():.1f} |")
