"""Benchmark for learned skills, skill trees, decision rates and transfer on the cart-pole (issue 7).

    python scripts/bench_tree.py [--phase pretrain tree transfer rate report] [--seeds 1 2 3] [--steps 50000]

Phases (each training run is the real ``Trainer``; a finished run directory is reused, so phases can be rerun):
- ``pretrain``: skills trained alone on their own rewards, copied to ``benchmarks/results/tree_transfer/skills/``:
  ``swing_energy.pt`` (HRTC on cartpole_energy), ``balance_upright.pt`` (HRTC on cartpole_upright),
  and ``swingup_source.pt`` (HRTC on cartpole_swingup, the meta-policy that ``transfer`` fine-tunes). It also trains
  our PPO on raw actions on cartpole_balance (``balance_ppo``), reported but not shipped: it did not learn in 50k.
- ``tree`` (a): the two-level tree ``cartpole_swingup_tree`` (root -> two learned meta-policies -> their skills).
- ``transfer`` (b): fine-tuning ``swingup_source.pt`` on ``cartpole_swingup_long`` (pole 1.5x longer) against HRTC
  from scratch there. The reuse of skills learned on other tasks is the tree of (a), set against our PPO from
  scratch on cartpole_swingup (the committed core benchmark's runs of the same seeds, not rerun).
- ``rate`` (c): cartpole_swingup at ``decision_every`` 1, 2 and 5, seeds interleaved so wall times compare side by
  side.
- ``ratewall``: wall time of k = 1, 2, 5 side by side: 10k-step runs alternating k1, k2, k5, twice.
- ``extend``: the tree runs of (a) continued to ``--steps`` (e.g. 100000) from their last checkpoint.
- ``extend_transfer``: the runs of (b) (fine-tuned and from scratch) continued to ``--steps`` likewise.
- ``scratch_ppo``: our PPO from scratch on cartpole_swingup to ``--steps`` (the core benchmark's settings), the
  reference for the extended tree runs.
- ``report``: table.md, results.json, curves.png, tree.txt, tree_weights.png/csv, command.txt and machine.txt.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OUT = ROOT / "benchmarks" / "results" / "tree_transfer"
SKILLS_DIR = OUT / "skills"
RUNS = ROOT / "runs" / "bench_tree"
PHASES = ("pretrain", "tree", "transfer", "rate", "ratewall", "extend", "extend_transfer", "scratch_ppo", "report")
RATES = (1, 2, 5)
PRETRAIN_STEPS = 20_000
THRESHOLD = 800.0  # the cart-pole swing-up tasks' solve_threshold
# A second, lower bar, added after the runs showed 800 out of reach within 50k steps for most of them (reported
# alongside, never instead).
LOWER_THRESHOLD = 600.0


def compose(task: str, overrides: list[str]) -> dict:
    """The resolved config of ``scripts/train.py task=<task> <overrides>``, as plain containers."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    GlobalHydra.instance().clear()
    with initialize_config_module("hrtc.conf", version_base=None):
        cfg = hydra_compose("config", overrides=[f"task={task}", *overrides])
    GlobalHydra.instance().clear()
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]


def train(run_dir: Path, config: str, overrides: list[str], init_from: Path | None = None, **fields) -> dict:
    """Train task config ``config`` with ``overrides`` (or reuse a finished run in ``run_dir``); ``fields`` replace
    RunConfig fields after composition. Returns its curve and timings."""
    from dataclasses import replace

    from hrtc.checkpoint import load_policy_weights
    from hrtc.config import RunConfig
    from hrtc.trainer import Trainer

    # No Rerun recording: its cost is not what this benchmark measures.
    cfg = RunConfig.from_mapping(compose(config, ["progress=false", "logger.mode=off", *overrides]))
    cfg = replace(cfg, **fields) if fields else cfg
    done = run_dir / "done.json"
    previous = json.loads(done.read_text()) if done.exists() else None
    if previous is None or previous["steps"] < cfg.steps:
        resume = previous is not None  # a finished run asked for more steps continues from its last checkpoint
        if not resume:
            shutil.rmtree(run_dir, ignore_errors=True)  # a half-finished run starts over
        trainer = Trainer(cfg, run_dir, resume=resume)
        if init_from is not None and not resume:
            load_policy_weights(trainer, init_from)
        tic = time.perf_counter()
        result = trainer.train()
        result["process_seconds"] = time.perf_counter() - tic + (previous["process_seconds"] if resume else 0.0)
        done.write_text(json.dumps(result))
        print(f"  {run_dir.relative_to(ROOT)}: {result['process_seconds']:.0f} s, final {result['final_eval']:.0f},"
              f" best {result['best_eval']:.0f}", flush=True)  # fmt: skip
    result = json.loads(done.read_text())
    evals, rows = pd.read_csv(run_dir / "eval.csv"), pd.read_csv(run_dir / "train.csv")
    threshold = cfg.solve_threshold
    return {
        "task": cfg.task,
        "curve": {"step": evals["step"].tolist(), "episode_reward": evals["episode_reward"].tolist()},
        "initial": float(evals["episode_reward"].iloc[0]),
        "final": float(evals["episode_reward"].iloc[-1]),
        "best": float(evals["episode_reward"].max()),
        "threshold": threshold,
        "steps_to_threshold": _steps_to(evals, threshold),
        "sps_median": float(rows["charts/SPS"].median()),
        "wall_seconds": float(result["process_seconds"]),
        "checkpoint": str((run_dir / "checkpoints" / "best.pt").relative_to(ROOT)),
    }


def _steps_to(evals: pd.DataFrame, threshold: float | None) -> int | None:
    if threshold is None:
        return None
    hit = evals.loc[evals["episode_reward"] >= threshold, "step"]
    return int(hit.iloc[0]) if len(hit) else None


# --------------------------------------------------------------------------------------------------- phases
def pretrain(steps: int) -> dict:
    """Skills trained alone, each on its own reward (seed 1), copied into the results folder."""
    from hrtc.ppo import PPOConfig

    SKILLS_DIR.mkdir(parents=True, exist_ok=True)
    runs = {
        "swing_energy": train(RUNS / "pretrain" / "swing_energy", "cartpole_energy", [f"steps={PRETRAIN_STEPS}"]),
        "balance_upright": train(
            RUNS / "pretrain" / "balance_upright", "cartpole_upright", [f"steps={PRETRAIN_STEPS}"]
        ),  # fmt: skip
        # Our PPO on raw actions with the root defaults (those suit it), on dm_control's balance reward.
        "balance_ppo": train(
            RUNS / "pretrain" / "balance_ppo",
            "cartpole_swingup",
            [f"steps={steps}", "algo=ppo"],
            task="cartpole_balance",
            skills={},
            ppo=PPOConfig(),
        ),  # fmt: skip
        # The source of fine-tuning: the shipped cartpole_swingup config, seed 1 (also the rate phase's k=5 seed 1).
        "swingup_source": train(RUNS / "rate" / "k5" / "seed1", "cartpole_swingup", [f"steps={steps}", "seed=1"]),
    }
    for name in ("swing_energy", "balance_upright", "swingup_source"):  # balance_ppo did not learn: not shipped
        shutil.copyfile(ROOT / runs[name]["checkpoint"], SKILLS_DIR / f"{name}.pt")
    return runs


def tree(seeds: list[int], steps: int) -> dict:
    return {"tree": {f"seed{s}": train(RUNS / "tree" / f"seed{s}", "cartpole_swingup_tree",
                                       [f"steps={steps}", f"seed={s}"]) for s in seeds}}  # fmt: skip


def extend(seeds: list[int], steps: int) -> dict:
    """The tree runs of (a) continued to ``steps`` (their first 50k steps unchanged)."""
    return {"tree_extended": {f"seed{s}": train(RUNS / "tree" / f"seed{s}", "cartpole_swingup_tree",
                                                [f"steps={steps}", f"seed={s}"]) for s in seeds}}  # fmt: skip


def transfer(seeds: list[int], steps: int, suffix: str = "") -> dict:
    """(b): fine-tuned against from scratch; ``suffix`` names the groups of runs continued to a longer budget."""
    source = SKILLS_DIR / "swingup_source.pt"
    out: dict[str, dict] = {f"finetune_long{suffix}": {}, f"scratch_long{suffix}": {}}
    for s in seeds:
        common = [f"steps={steps}", f"seed={s}"]
        task = "cartpole_swingup_long"
        out[f"finetune_long{suffix}"][f"seed{s}"] = train(RUNS / "finetune_long" / f"seed{s}", task, common, source)
        out[f"scratch_long{suffix}"][f"seed{s}"] = train(RUNS / "scratch_long" / f"seed{s}", task, common)
    return out


def scratch_ppo(seeds: list[int], steps: int) -> dict:
    """Our PPO on raw actions from scratch on cartpole_swingup with the core benchmark's settings (root defaults:
    lr 3e-4 annealed, gamma 0.99, 2 x 500 env steps an update), to ``steps``: the reference of the extended tree."""
    overrides = ["algo=ppo", "dist=beta", "ppo.learning_rate=3e-4", "ppo.anneal_lr=true", "ppo.num_steps=500",
                 "ppo.gamma=0.99", f"steps={steps}"]  # fmt: skip
    return {"ppo_scratch_extended": {f"seed{s}": train(RUNS / "ppo_scratch" / f"seed{s}", "cartpole_swingup",
                                                       [*overrides, f"seed={s}"]) for s in seeds}}  # fmt: skip


def core_ppo(seeds: list[int]) -> dict:
    """Our PPO from scratch on cartpole_swingup (raw actions, root defaults, 50k steps, the same evaluation seeds):
    the committed runs of benchmarks/results/cartpole_swingup_core, not rerun here."""
    core = json.loads((ROOT / "benchmarks" / "results" / "cartpole_swingup_core" / "results.json").read_text())
    out = {}
    for s in seeds:
        run = core["runs"]["ppo_beta"][str(s)]
        # Its wall time and throughput were measured on another day's machine load: left out (nan).
        out[f"seed{s}"] = {**run, "task": "cartpole_swingup", "threshold": core["threshold"], "wall_seconds": np.nan,
                           "sps_median": np.nan, "initial": run["curve"]["episode_reward"][0],
                           "source": "cartpole_swingup_core"}  # fmt: skip
    return out


def rate(seeds: list[int], steps: int) -> dict:
    out: dict[str, dict] = {f"k{k}": {} for k in RATES}
    for s in seeds:  # interleaved: every rate of one seed before the next seed, so machine load hits all alike
        for k in RATES:
            out[f"k{k}"][f"seed{s}"] = train(RUNS / "rate" / f"k{k}" / f"seed{s}", "cartpole_swingup",
                                             [f"steps={steps}", f"seed={s}", f"algo.decision_every={k}"])  # fmt: skip
    return out


def rate_wall(reps: int = 2, steps: int = 10_000) -> dict:
    """Side-by-side wall time of k = 1, 2, 5: short runs (one evaluation episode at the start and the end)
    alternating k1, k2, k5, k1, k2, k5, so the machine's load falls on every rate alike."""
    out: dict[str, dict] = {f"k{k}": {} for k in RATES}
    for r in range(reps):
        for k in RATES:
            out[f"k{k}"][f"rep{r}"] = train(RUNS / "rate_wall" / f"k{k}-rep{r}", "cartpole_swingup",
                                            [f"steps={steps}", "seed=1", f"algo.decision_every={k}", "eval_episodes=1",
                                             f"eval_every={10 * steps}", f"checkpoint_every={10 * steps}"])  # fmt: skip
    return out


def tree_trace(checkpoint: Path, seed: int = 1_000_000) -> pd.DataFrame:
    """One deterministic episode (the Beta mean) of a trained tree: every node's effective weight per decision."""
    import torch

    from hrtc.environments import make_env
    from hrtc.tree import effective_weights
    from skills.learned import load_policy

    policy, normalizer, meta = load_policy(checkpoint)
    env = make_env(meta["task"], "hrtc", meta["skills_cfg"], meta["action_filter"], meta["env_kwargs"],
                   meta["decision_every"])  # fmt: skip
    rows: list[dict] = []
    obs, _ = env.reset(seed=seed)
    total, done = 0.0, False
    with torch.no_grad():
        while not done:
            x = obs[None].astype(np.float32)
            x = normalizer(x) if normalizer is not None else x
            weights = policy.distribution(torch.as_tensor(x)).mode().numpy()[0]
            obs, reward, terminated, truncated, info = env.step(weights)
            total += float(reward)
            done = terminated or truncated
            angle = float(env.unwrapped.skill_state()["pole_angle"][0])
            rows.append({"env_step": info["env_steps"], "pole_angle": angle,
                         **effective_weights(env.skill_names, info["weights"], info["skills"])})  # fmt: skip
    frame = pd.DataFrame(rows)
    frame.attrs["return"] = total
    return frame


# --------------------------------------------------------------------------------------------------- report
def report(results: dict, seeds: list[int], steps: int) -> None:
    from hrtc.benchmark.report import machine_info

    OUT.mkdir(parents=True, exist_ok=True)
    lines = [f"# Learned skills, skill trees, decision rates and transfer (seeds {seeds}, {steps} env steps; "
             "*_extended runs: the budgets in their rows)", ""]  # fmt: skip
    lines += ["Evaluation return: mean of 3 deterministic episodes (the Beta mean) on seeds disjoint from training, "
              "every 5,000 env steps. Steps to threshold: the first evaluation at or above it.", ""]  # fmt: skip

    if "pretrain" in results:
        lines += ["## Skills trained alone on their own rewards", "",
                  "| skill | task (its own reward) | algo | env steps | return at start | best return |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        algos = {"swing_energy": "HRTC {swingup, hold}", "balance_upright": "HRTC {LinearMPC, hold}",
                 "balance_ppo": "PPO (raw actions)", "swingup_source": "HRTC (4 skills)"}  # fmt: skip
        for name, run in results["pretrain"].items():
            lines.append(f"| {name} | {run['task']} | {algos.get(name, '')} | {run['curve']['step'][-1]} "
                         f"| {run['initial']:.0f} | {run['best']:.0f} |")  # fmt: skip
        lines.append("")

    def block(title: str, groups: dict[str, dict], *ratios: tuple[str, str]) -> None:
        nonlocal lines
        thresholds = (THRESHOLD, LOWER_THRESHOLD)
        lines += [f"## {title}", "", "| run | task | return at 0 | final per seed | best per seed "
                  "| mean over the run | steps to 800 per seed | steps to 600 per seed | wall s (median) "
                  "| train env steps/s (median) |", "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        medians: dict[str, list[float]] = {}
        budgets: dict[str, int] = {}
        for name, runs in groups.items():
            if not runs:
                continue
            vals = list(runs.values())
            hits = [[_first_at(r["curve"], th) for r in vals] for th in thresholds]
            medians[name] = [_median([np.inf if h is None else h for h in hs]) for hs in hits]
            budget = budgets[name] = max(r["curve"]["step"][-1] for r in vals)
            cells = [", ".join("-" if h is None else str(h) for h in hs) + f" (median {_fmt_steps(m, budget)})"
                     for hs, m in zip(hits, medians[name], strict=True)]  # fmt: skip
            lines.append(
                f"| {name} | {vals[0]['task']} | {_join(r['initial'] for r in vals)} "
                f"| {_join(r['final'] for r in vals)} | {_join(r['best'] for r in vals)} "
                f"| {_join(np.mean(r['curve']['episode_reward']) for r in vals)} | {cells[0]} | {cells[1]} "
                f"| {np.median([r['wall_seconds'] for r in vals]):.0f} "
                f"| {np.median([r['sps_median'] for r in vals]):.0f} |"
            )
        for ratio_of in (r for r in ratios if r[0] in medians and r[1] in medians):
            for i, th in enumerate(thresholds):
                a, b = medians[ratio_of[0]][i], medians[ratio_of[1]][i]
                if np.isfinite(b) and np.isfinite(a):
                    text = f"{a / b:.2f}" if b > 0 else "n/a (the second at 0)"
                elif np.isfinite(a):
                    within = budgets[ratio_of[1]]
                    text = f"< {a / within:.2f} ({ratio_of[1]} did not reach {th:.0f} within {within} steps)"
                else:
                    text = f"not defined: {ratio_of[0]} did not reach {th:.0f} within {budgets[ratio_of[0]]} steps"
                lines.append(f"- median steps to {th:.0f}, {ratio_of[0]} / {ratio_of[1]}: **{text}**")
        lines.append("")

    if "tree" in results:
        lines += ["## (a) Two-level tree on cartpole_swingup", "", "```text", _tree_text(), "```", ""]
        # For reference: the flat library of the shipped cartpole_swingup config, same settings (the rate phase's k=5).
        flat = {"flat_hrtc": results["rate"]["k5"]} if "rate" in results and "k5" in results["rate"] else {}
        block("(a) results", {"tree": results["tree"]["tree"], **results.get("extend", {}), **flat})
    if "transfer" in results:
        t = {**results["transfer"], **results.get("extend_transfer", {})}
        names = ("finetune_long", "scratch_long", "finetune_long_extended", "scratch_long_extended")
        block("(b) Fine-tuning a trained meta-policy on a 1.5x longer pole, against training from scratch",
              {name: t[name] for name in names if name in t}, ("finetune_long", "scratch_long"),
              ("finetune_long_extended", "scratch_long_extended"))  # fmt: skip
    if "tree" in results:
        block("(b) Skills learned on other tasks (the tree's nodes) reused in cartpole_swingup, vs PPO from scratch",
              {"tree": results["tree"]["tree"], "ppo_scratch": core_ppo(seeds), **results.get("extend", {}),
               **results.get("scratch_ppo", {})}, ("tree", "ppo_scratch"),
              ("tree_extended", "ppo_scratch_extended"))  # fmt: skip
    if "rate" in results:
        block("(c) Decision rate: the meta-policy decides every k env steps (skills act every step)", results["rate"])
        base = results["rate"].get("k1")
        if base:
            lines += ["Wall time of whole 50k runs (training and evaluation), relative to k = 1, per seed. Not a fair "
                      "comparison: the k = 5 run of seed 1 ran an hour before the others, under a different load "
                      "(see the side-by-side table below):", ""]  # fmt: skip
            for k in RATES:
                runs = results["rate"][f"k{k}"]
                ratios = [runs[s]["wall_seconds"] / base[s]["wall_seconds"] for s in runs if s in base]
                lines.append(f"- k = {k}: {', '.join(f'{r:.2f}' for r in ratios)} (median {np.median(ratios):.2f})")
            lines.append("")
    if "ratewall" in results:
        walls = results["ratewall"]
        lines += ["Side by side (phase ratewall: 10,000-step runs of seed 1 alternating k = 1, 2, 5, twice; one "
                  "evaluation episode at start and end):", "",
                  "| k | wall s per run | relative to k = 1 (same repetition) | train env steps/s (median) |",
                  "|---|---|---|---|"]  # fmt: skip
        for k in RATES:
            runs = walls[f"k{k}"]
            rel = [runs[r]["wall_seconds"] / walls["k1"][r]["wall_seconds"] for r in runs]
            sps = _join(v["sps_median"] for v in runs.values())
            lines.append(f"| {k} | {_join(v['wall_seconds'] for v in runs.values())} "
                         f"| {', '.join(f'{x:.2f}' for x in rel)} | {sps} |")  # fmt: skip
        lines.append("")
    trace_png = OUT / "tree_weights.png"
    if "tree" in results:
        best = max(results["tree"]["tree"].values(), key=lambda r: r["best"])
        frame = tree_trace(ROOT / best["checkpoint"])
        frame.to_csv(OUT / "tree_weights.csv", index=False)
        _plot_trace(frame, trace_png, best["checkpoint"])
        lines += [f"Effective weights of every node over one evaluation episode of the best tree run "
                  f"(return {frame.attrs['return']:.0f}): tree_weights.png, tree_weights.csv.", ""]  # fmt: skip
    lines += ["Notes:", "- Every run: 2 environment worker processes (async), torch 1 thread, on a machine shared "
              "with other jobs (load average 10 to 40 on 2 cores during these runs); wall times compare only between "
              "runs back to back (the ratewall phase alternates its runs).",
              "- ppo_scratch: the committed runs of benchmarks/results/cartpole_swingup_core (same code path, root PPO "
              "defaults, the same evaluation seeds), not rerun; their wall time and env steps/s (measured on a far "
              "less loaded machine) are left out.",
              "- mean over the run: the mean of every evaluation from step 0 to the end (threshold-free).",
              "- *_extended: tree_extended (phase extend), finetune_long_extended and scratch_long_extended (phase "
              "extend_transfer) are the same run directories continued from their last checkpoint to the budget in "
              "their rows (their first steps unchanged); ppo_scratch_extended (phase scratch_ppo) is new runs with the "
              "core benchmark's PPO settings. The last of them ran at a load average of 3 to 6, so their wall s and "
              "env steps/s do not compare with the rows above."]  # fmt: skip
    (OUT / "table.md").write_text("\n".join(lines) + "\n")
    (OUT / "results.json").write_text(json.dumps(results, indent=1))
    (OUT / "machine.txt").write_text(machine_info())
    _plot_curves(results, seeds, OUT / "curves.png")
    print("\n".join(lines))


def _tree_text() -> str:
    from hrtc.cli import task_config
    from hrtc.composition import build_library
    from hrtc.tree import format_tree, skill_tree

    text = format_tree(skill_tree(build_library(task_config("cartpole_swingup_tree")["skills"]), "meta",
                                  "meta-policy (hrtc-beta, decides every 5 steps)"))  # fmt: skip
    (OUT / "tree.txt").write_text(text + "\n")
    return text.replace(str(ROOT) + "/", "")


def _first_at(curve: dict, threshold: float) -> int | None:
    hit = [s for s, r in zip(curve["step"], curve["episode_reward"], strict=True) if r >= threshold]
    return int(hit[0]) if hit else None


def _join(values) -> str:
    return ", ".join(f"{v:.0f}" for v in values)


def _median(values: list[float]) -> float:
    values = sorted(values)
    n = len(values)
    return float(values[n // 2]) if n % 2 else float(np.mean(values[n // 2 - 1 : n // 2 + 1]))


def _fmt_steps(value: float, steps: int) -> str:
    return f"{value:.0f}" if np.isfinite(value) else f"not reached (> {steps})"


def _plot_curves(results: dict, seeds: list[int], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker.FuncFormatter below)

    tree_runs = results.get("tree", {}).get("tree", {})
    flat = {"flat_hrtc": results["rate"]["k5"]} if "k5" in results.get("rate", {}) else {}
    # (b): the longest runs of each group (an *_extended group holds the same runs continued, from step 0).
    transfer = {**results.get("transfer", {}), **results.get("extend_transfer", {})}
    longest = lambda name: transfer.get(f"{name}_extended") or transfer.get(name, {})  # noqa: E731
    extended = {**results.get("extend", {}), **results.get("scratch_ppo", {})}
    reuse = ({"tree_extended": extended["tree_extended"], "ppo_scratch_extended": extended["ppo_scratch_extended"]}
             if {"tree_extended", "ppo_scratch_extended"} <= set(extended)
             else {"tree": tree_runs, "ppo_scratch": core_ppo(seeds)})  # fmt: skip
    panels = [("(a) tree", {"tree": tree_runs, **results.get("extend", {}), **flat}),
              ("(b) fine-tune vs scratch, long pole", {k: longest(k) for k in ("finetune_long", "scratch_long")}),
              ("(b) reused learned skills (tree) vs PPO", reuse),
              ("(c) decision rate", results.get("rate", {}))]  # fmt: skip
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.2), sharey=True)
    for ax, (title, groups) in zip(axes, panels, strict=True):
        for i, (name, runs) in enumerate(groups.items()):
            if not runs:
                continue
            curves = [pd.Series(r["curve"]["episode_reward"], index=r["curve"]["step"]) for r in runs.values()]
            frame = pd.concat(curves, axis=1).sort_index().interpolate(limit_area="inside")
            ax.plot(frame.index, frame.median(axis=1), color=f"C{i}", label=f"{name} (median of {len(curves)})")
            ax.fill_between(frame.index, frame.min(axis=1), frame.max(axis=1), color=f"C{i}", alpha=0.15)
        ax.axhline(800, color="k", ls="--", lw=1)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("env steps")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x / 1000:.0f}k"))
        ax.legend(fontsize=7, loc="lower right")
    axes[0].set_ylabel("evaluation return")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_trace(frame: pd.DataFrame, path: Path, checkpoint: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = [c for c in frame.columns if c not in ("env_step", "pole_angle")]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(3, 1))
    for i, col in enumerate(cols):
        ax.plot(frame["env_step"], frame[col], lw=1.6 - 0.5 * col.count("/"), color=f"C{i}", label=col,
                ls="-" if "/" not in col else "--")  # fmt: skip
    ax.set_ylabel("effective weight")
    ax.set_title(f"effective weight of every node (child x parent), one episode of {checkpoint}", fontsize=9)
    ax.legend(fontsize=7, ncol=3)
    ax2.plot(frame["env_step"], frame["pole_angle"], color="k", lw=1)
    ax2.set_ylabel("pole angle, rad")
    ax2.set_xlabel("env step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--phase", nargs="+", choices=PHASES, default=list(PHASES))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--steps", type=int, default=50_000)
    args = parser.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    OUT.mkdir(parents=True, exist_ok=True)
    with (OUT / "command.txt").open("a") as log:  # every invocation, in order: the phases run separately
        log.write("nice -n 5 python scripts/bench_tree.py " + " ".join(sys.argv[1:]) + "\n")
    cache = RUNS / "results.json"
    results = json.loads(cache.read_text()) if cache.exists() else {}
    todo: dict[str, Callable[[], dict]] = {
        "pretrain": lambda: pretrain(args.steps),
        "tree": lambda: tree(args.seeds, args.steps),
        "transfer": lambda: transfer(args.seeds, args.steps),
        "rate": lambda: rate(args.seeds, args.steps),
        "extend": lambda: extend(args.seeds, args.steps),
        "extend_transfer": lambda: transfer(args.seeds, args.steps, suffix="_extended"),
        "scratch_ppo": lambda: scratch_ppo(args.seeds, args.steps),
        "ratewall": lambda: rate_wall(),
    }
    for phase in args.phase:
        if phase in todo:
            print(f"phase {phase}", flush=True)
            new = todo[phase]()
            if phase == "pretrain":
                results[phase] = new
            else:  # {group: {seedN: run}}: merge, so that seeds can be run by separate invocations
                for group, runs in new.items():
                    results.setdefault(phase, {}).setdefault(group, {}).update(runs)
            cache.parent.mkdir(parents=True, exist_ok=True)
            cache.write_text(json.dumps(results))
    if "report" in args.phase:
        report(results, args.seeds, args.steps)


if __name__ == "__main__":
    main()
