"""Paired reading of ``_auto`` and ``_auto_mirror`` over seeds 1-20 from the committed results (this folder: seeds
1-10; ``../learners_default_seeds11_20``: 11-20): the first confirmed 800, falls below 700 after it and after the
first 3-episode 800, the final policies, paired Wilcoxon tests (output: ``mirror_pairs.txt``).

usage (from the repository root): python benchmarks/results/cartpole_swingup/learners_ensemble/mirror_pairs.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.stats import wilcoxon

AUTO, MIRROR = "hrtc_beta_sac_ln_tau02_auto", "hrtc_beta_sac_ln_tau02_auto_mirror"
ROOT = Path(__file__).resolve().parent.parent


def load() -> tuple[dict, dict]:
    runs, summary = {}, {}
    for folder in ("learners_ensemble", "learners_default_seeds11_20"):
        runs.update(json.loads((ROOT / folder / "results.json").read_text())["runs"])
        summary.update(json.loads((ROOT / folder / "summary.json").read_text())["runs"])
    return runs, summary


def read(runs: dict, summary: dict, algo: str, seed: int) -> dict[str, float]:
    key = f"{algo}/seed{seed}"
    curve, solved = runs[key]["curve"], summary[key]["solved_step"]
    evals = dict(zip(curve["step"], curve["episode_reward"], strict=True))
    first3 = next(step for step in sorted(evals) if evals[step] >= 800)
    return {"solved": solved, "solved_wall": summary[key]["solved_wall"], "first3": first3,
            "after_solved": min(v for step, v in evals.items() if step > solved),
            "after_first3": min(v for step, v in evals.items() if step > first3),
            "final": float(np.mean(runs[key]["final_returns"])), "wall": runs[key]["wall_seconds"]}  # fmt: skip


def main() -> None:
    runs, summary = load()
    for seeds in (range(1, 11), range(11, 21), range(1, 21)):
        rows = {algo: [read(runs, summary, algo, s) for s in seeds] for algo in (AUTO, MIRROR)}
        print(f"\n== seeds {seeds[0]}-{seeds[-1]}")
        for algo, got in rows.items():
            falls = [(s, round(r["after_solved"])) for s, r in zip(seeds, got, strict=True) if r["after_solved"] < 700]
            falls3 = [(s, round(r["after_first3"])) for s, r in zip(seeds, got, strict=True) if r["after_first3"] < 700]
            finals, walls = [r["final"] for r in got], [r["wall"] for r in got]
            print(f"{algo}: first 800 (10 episodes) median {np.median([r['solved'] for r in got]):.0f} env steps, "
                  f"wall to it median {np.median([r['solved_wall'] for r in got]):.0f} s; first 3-episode 800 median "
                  f"{np.median([r['first3'] for r in got]):.0f}; below 700 after the confirmed 800: {len(falls)} "
                  f"{falls}, after the first 3-episode 800: {len(falls3)} {falls3}; finals median "
                  f"{np.median(finals):.1f} [IQR {np.percentile(finals, 25):.1f}, {np.percentile(finals, 75):.1f}], "
                  f"lowest {min(finals):.1f}; wall per run median {np.median(walls):.0f} s")  # fmt: skip
        auto, mirror = ([r["solved"] for r in rows[a]] for a in (AUTO, MIRROR))
        print(f"  first 800: the mirror sooner on {sum(m < a for m, a in zip(mirror, auto, strict=True))}, later on "
              f"{sum(m > a for m, a in zip(mirror, auto, strict=True))}; paired Wilcoxon p = "
              f"{wilcoxon(mirror, auto).pvalue:.3f}")  # fmt: skip
        auto, mirror = ([r["final"] for r in rows[a]] for a in (AUTO, MIRROR))
        print(f"  finals: the mirror higher on {sum(m > a for m, a in zip(mirror, auto, strict=True))}; paired "
              f"Wilcoxon p = {wilcoxon(mirror, auto).pvalue:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
