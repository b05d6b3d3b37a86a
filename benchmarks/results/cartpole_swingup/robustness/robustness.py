"""How much each controller loses on changed cart-pole physics (issue 17, part 5).

    python benchmarks/results/cartpole_swingup/robustness/robustness.py --hrtc-sac RUN... --hrtc-ppo RUN... \\
        --ppo RUN... [--episodes 10]

Every policy's final checkpoint (``<run>/checkpoints/last.pt``), each skill alone, the untrained blend and the hand
switching rule act on nominal cartpole_swingup and with the pole's mass x1.5 and x3 and its length x1.25 and x1.5,
on evaluation seeds of seed 500 (1,500,000 + k: used by no training run or evaluation). Writes table.md and
results.json beside this file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from hrtc.checkpoint import load_policy  # noqa: E402
from hrtc.cli import task_config  # noqa: E402
from hrtc.environments import make_env  # noqa: E402
from hrtc.episodes import eval_seeds, evaluate  # noqa: E402
from hrtc.references import evaluate_rules, reference_rules  # noqa: E402

CONDITIONS = {"nominal": ("cartpole_swingup", {}),
              "pole mass x1.5": ("cartpole_swingup_heavy", {"pole_mass_scale": 1.5}),
              "pole mass x3": ("cartpole_swingup_heavy", {"pole_mass_scale": 3.0}),
              "pole length x1.25": ("cartpole_swingup_long", {"pole_length_scale": 1.25}),
              "pole length x1.5": ("cartpole_swingup_long", {"pole_length_scale": 1.5})}  # fmt: skip


def policy_returns(run: str, task: str, env_kwargs: dict, seeds: list[int]) -> list[float]:
    policy, normalizer, meta = load_policy(Path(run) / "checkpoints" / "last.pt")
    env = make_env(task, meta["algo"], meta["skills_cfg"], meta["action_filter"], env_kwargs,
                   int(meta["decision_every"]))  # fmt: skip
    return evaluate(policy, normalizer, env, seeds, meta["dist"]).tolist()


def main() -> None:
    parser = argparse.ArgumentParser()
    for name in ("--hrtc-sac", "--hrtc-ppo", "--ppo"):
        parser.add_argument(name, nargs="*", default=[])
    parser.add_argument("--episodes", type=int, default=10)
    args = parser.parse_args()
    seeds = eval_seeds(500, args.episodes)
    skills = task_config("cartpole_swingup")
    rules = reference_rules(tuple(skills["skills"]), skills["references"])  # each skill alone, untrained, the rule
    methods = {"HRTC Beta, SAC": args.hrtc_sac, "HRTC Beta, PPO (the paper's)": args.hrtc_ppo,
               "PPO Beta on raw actions": args.ppo}  # fmt: skip
    results: dict[str, dict[str, list[float]]] = {}
    for condition, (task, kwargs) in CONDITIONS.items():
        row = {}
        for method, runs in methods.items():
            if runs:  # each seed's mean, then over seeds
                row[method] = [float(np.mean(policy_returns(r, task, kwargs, seeds))) for r in runs]
        env = make_env(task, "hrtc", skills["skills"], env_kwargs=kwargs, decision_every=5)
        row.update({k: [float(np.mean(v))] for k, v in evaluate_rules(env, rules, seeds).items()})
        results[condition] = row
        print(condition, {k: round(float(np.mean(v)), 1) for k, v in row.items()}, flush=True)
    out = Path(__file__).resolve().parent
    (out / "results.json").write_text(json.dumps({"episodes": args.episodes, "seeds": seeds, "results": results,
                                                  "runs": methods}, indent=1))  # fmt: skip
    names = list(next(iter(results.values())))
    note = ("Mean return (learned policies: the mean over their training seeds [min, max]); in parentheses the share "
            "of its own nominal return kept. HRTC: seeds 1-3 of the 10-seed learner benchmark (50k env steps, "
            "last.pt); PPO Beta on raw actions: one seed, 100k env steps. The skills keep their nominal model.")
    lines = [f"# cartpole_swingup on changed physics ({args.episodes} episodes per policy, seeds 1,500,000+)", "", note,
             "", "| condition | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]  # fmt: skip
    nominal = {k: np.mean(v) for k, v in results["nominal"].items()}
    for condition, row in results.items():
        cells = []
        for k in names:
            v = row[k]
            spread = f" [{min(v):.0f}, {max(v):.0f}]" if len(v) > 1 else ""
            kept = f"{np.mean(v) / nominal[k]:.0%}" if nominal[k] > 0 else "—"  # a skill scoring 0 keeps nothing
            cells.append(f"{np.mean(v):.0f}{spread} ({kept})")
        lines.append(f"| {condition} | " + " | ".join(cells) + " |")
    (out / "table.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
