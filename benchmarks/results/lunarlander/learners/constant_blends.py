"""Every corner blend of a task's skills (each weight 0 or 1) and the untrained blend, held constant over episodes.

    PYTHONPATH=. python benchmarks/results/lunarlander/learners/constant_blends.py [--task lunarlander] [--episodes 30]

Prints a markdown table, best first: the blend (weights in the order of the task's skills), the mean return over the
episodes and how many returned below ``--failed`` (lunarlander: a crash). The episodes' seeds (900,000 on) are never
used by training or evaluation. What it answers: how many constant blends land every start, and how good the best is,
i.e. what a search over constant blends (``sac.start_search``) can find.
"""

import argparse
import itertools
import sys
import time

import numpy as np
from omegaconf import OmegaConf

from hrtc.config import ROOT_CONF
from hrtc.environments import make_env
from hrtc.episodes import run_episodes
from hrtc.references import FixedWeights, rule_decider


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="lunarlander")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--failed", type=float, default=100.0, help="a return below this counts as failed")
    args = parser.parse_args()
    cfg = OmegaConf.to_container(OmegaConf.load(ROOT_CONF / "task" / f"{args.task}.yaml"))
    skills, every = cfg["task"]["skills"], int(cfg.get("algo", {}).get("decision_every", 1))
    names = list(skills)
    env = make_env(args.task, "hrtc", skills, decision_every=every)
    seeds = list(range(900_000, 900_000 + args.episodes))
    rows, tic = [], time.perf_counter()
    for bits in [(0.5,) * len(names), *itertools.product([0.0, 1.0], repeat=len(names))]:
        if not any(bits):
            continue
        returns = run_episodes(env, rule_decider(env, FixedWeights(dict(zip(names, bits, strict=True)))), seeds)
        label = "".join("s" if b == 0.5 else str(int(b)) for b in bits)
        rows.append((float(np.mean(returns)), int((returns < args.failed).sum()), label))
    print(f"{len(rows)} blends x {args.episodes} episodes in {time.perf_counter() - tic:.0f} s", file=sys.stderr)
    print(f"Weights in the order {', '.join(names)} (s: 0.5, the untrained blend); {args.episodes} episodes each, "
          f"seeds {seeds[0]}-{seeds[-1]}.\n")  # fmt: skip
    print(f"| blend | mean return | returns below {args.failed:g} |\n|---|---|---|")
    for mean, failed, label in sorted(rows, reverse=True):
        print(f"| {label} | {mean:.1f} | {failed} |")


if __name__ == "__main__":
    main()
