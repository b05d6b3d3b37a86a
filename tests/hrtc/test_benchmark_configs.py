"""The benchmark configs (hrtc/conf/benchmark/): each composes and validates into its runs; a bad one is one
``error:`` line; each metric plug-in runs end to end on a tiny budget (1 seed, references on a few episodes) and its
results.json and table.md are read back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hrtc.benchmark.main import benchmark_names, check, parse, specs_of
from hrtc.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[2]
STUDIES = {
    "cartpole_swingup_core": ("cartpole_swingup", "cartpole_swingup/core", 30),
    "cartpole_swingup_learners": ("cartpole_swingup", "cartpole_swingup/learners_margin", 50),
    "cartpole_swingup_ensemble": ("cartpole_swingup", "cartpole_swingup/learners_ensemble", 180),
    "cartpole_swingup_throughput": ("cartpole_swingup", "cartpole_swingup/throughput", 9),
    "cartpole_swingup_tree_pretrain": ("cartpole_swingup", "cartpole_swingup/tree_transfer/pretrain", 4),
    "cartpole_swingup_tree": ("cartpole_swingup", "cartpole_swingup/tree_transfer", 15),
    "cartpole_swingup_decision_rate_wall": ("cartpole_swingup", "cartpole_swingup/tree_transfer/decision_rate_wall", 6),
    "lunarlander": ("lunarlander", "lunarlander/core", 15),
    "lunarlander_learners": ("lunarlander", "lunarlander/learners", 25),
    "panda_reach": ("panda_reach", "panda_reach", 3),
    "pendulum_swingup": ("pendulum_swingup", "pendulum_swingup/learners", 20),
    "carracing": ("carracing", "carracing/sitting_45min", 2),
    "carracing_table1": ("carracing_paper", "carracing/table1", 12),
}


def test_every_committed_study_has_a_config() -> None:
    assert sorted(benchmark_names()) == sorted(STUDIES)


@pytest.mark.parametrize("name", sorted(STUDIES))
def test_benchmark_config_composes_into_its_runs(name: str, tmp_path: Path) -> None:
    task, out, runs = STUDIES[name]
    args = check(parse([f"benchmark={name}"]))
    assert args["task"] == task and Path(args["out"]) == Path("benchmarks/results") / out
    # The command that regenerates the committed results stands in their command.txt (the tree study's phases: in
    # the study's own folder, whose results they fed).
    folder = ROOT / "benchmarks" / "results" / out
    recorded = folder / "command.txt" if folder.exists() else folder.parent / "command.txt"
    assert f"python scripts/benchmark.py benchmark={name}" in recorded.read_text()
    specs = specs_of(args, 800.0, 3, 3, 5000, tmp_path)
    assert len(specs) == runs and len({s.key for s in specs}) == runs
    for spec in specs:  # every override list is one the trainer or SB3 takes as it is
        assert all("=" in o for o in spec.overrides)


def test_variants_reach_the_trainer_overrides(tmp_path: Path) -> None:
    from hrtc.benchmark.runs import trainer_overrides

    specs = {s.algo: s for s in specs_of(check(parse(["benchmark=cartpole_swingup_core"])), 800, 3, 3, 5000, tmp_path)}
    own = trainer_overrides(specs["ppo_beta_task_settings"])
    assert "algo=ppo" in own and own[-1] == "ppo.num_steps=625" and "ppo.learning_rate=0.0003" not in own
    root = trainer_overrides(specs["ppo_beta"])
    assert "ppo.learning_rate=0.0003" in root and root[-1] == "ppo.num_steps=500"
    tree = {s.algo: s for s in specs_of(check(parse(["benchmark=cartpole_swingup_tree"])), 800, 3, 3, 5000, tmp_path)}
    assert tree["tree"].task == "cartpole_swingup_tree" and tree["tree"].steps == 250_000
    assert [s.seed for s in tree.values() if s.algo.startswith("decide")] == [1, 1, 1]


def _bench(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(ROOT / "scripts" / "benchmark.py"), f"out={tmp_path / 'out'}",
           f"runs_dir={tmp_path / 'runs'}", "backend=process", "progress=false", *args]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)


@pytest.mark.parametrize(
    "args,expected",
    [
        (
            ["benchmark=nope"],
            "error: unknown benchmark 'nope'; valid benchmarks: carracing, carracing_table1, cartpole_swingup_core",
        ),
        (["benchmark=lunarlander", "variants.sb3_sac.colour=1"], "error: unknown key 'colour' in variants.sb3_sac"),
        (["benchmark=lunarlander", "variants.x.base=sac"], "error: unknown variants.x.base 'sac'; valid"),
        (["benchmark=panda_reach", "metric.targets=3"], "error: unknown key 'targets' in metric; the success metric"),
        (["benchmark=panda_reach", "metric.name=speed"], "error: unknown metric.name 'speed'; valid metric.names"),
        (["benchmark=panda_reach", "algos=[sb3_ppo]"], "error: the success metric measures trainer runs only"),
        (["benchmark=cartpole_swingup_tree", "compare=[[tree]]"], "error: compare must be a list of [a, b] pairs"),
        (["benchmark=carracing", "wall_minutes=0"], "error: wall_minutes must be in [0.01, None], got 0"),
    ],
)
def test_a_bad_benchmark_config_is_one_error_line(tmp_path: Path, args: list[str], expected: str) -> None:
    proc = _bench(tmp_path, *args)
    assert proc.returncode == 2 and proc.stderr.startswith(expected) and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def _read(tmp_path: Path) -> tuple[dict, str]:
    out = tmp_path / "out"
    return json.loads((out / "results.json").read_text()), (out / "table.md").read_text()


def test_final_and_best_over_their_own_seeds_end_to_end(tmp_path: Path) -> None:
    """LunarLander's protocol: the final and the best evaluated policy on seeds 2,000,000 + 1000 seed + k; the
    references there too, gymnasium's heuristic acting on the task itself."""
    proc = _bench(tmp_path, "benchmark=lunarlander", "algos=[hrtc_beta,sb3_a2c]", "seeds=[1]", "budget=200",
                  "eval_every=100", "eval_episodes=1", "solve_episodes=1", "final_episodes=2",
                  "reference_episodes=1", "cpus=2")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results, table = _read(tmp_path)
    for run in results["runs"].values():
        assert run["final_seed_base"] == 2_000_000 and len(run["final_returns"]) == len(run["best_returns"]) == 2
        assert run["train_sps"] > 0
    assert "## The final and the best evaluated policy over 2 episodes" in table and "| sb3_a2c | 1 |" in table
    refs = results["references"]
    assert refs["gymnasium's heuristic (reference, not a skill)"][0] > 200 > refs["hover alone"][0]
    assert "seeds 2,000,000 + 1000 seed + k of seed 0" in table and "Notes:" in table


# slow (about 20 s): trains a panda run; the harness itself is covered by test_final_and_best_over_their_own_seeds
@pytest.mark.slow
def test_success_on_unseen_targets_end_to_end(tmp_path: Path) -> None:
    proc = _bench(tmp_path, "benchmark=panda_reach", "algos=[hrtc_beta]", "seeds=[1]", "budget=320",
                  "eval_every=320", "eval_episodes=1", "metric.episodes=2", "cpus=1",
                  "rules={}", "references=true")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results, table = _read(tmp_path)
    run = results["runs"]["hrtc_beta/seed1"]
    for which in ("best", "last"):
        rows = run["success"][which]["episodes"]
        assert [r["seed"] for r in rows] == [2_000_000, 2_000_001]
        assert set(run["success"][which]["summary"]) == {"all", "free", "limit", "behind"}
    refs = results["references"]
    assert refs["handover rule (avoid over the wall, then reach)"]["summary"]["all"]["targets"] == 2
    assert "| hrtc_beta, seed 1, best.pt | 2 |" in table and "## References over the same skills" in table


# slow (about 30 s): CarRacing training; reading its episode log is tested in tests/envs/test_carracing.py
@pytest.mark.slow
def test_training_episodes_for_a_wall_time_budget_end_to_end(tmp_path: Path) -> None:
    proc = _bench(tmp_path, "benchmark=carracing", "algos=[hrtc_beta]", "budget=100000", "wall_minutes=0.4",
                  "eval_every=100000", "eval_episodes=1", "cpus=1", "cpus_per_run=1")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results, table = _read(tmp_path)
    run = results["runs"]["hrtc_beta/seed1"]
    log = run["episodes_log"]
    assert run["env_steps"] < 100_000 and log["frames"] > 0 and len(log["returns"]) >= 1
    assert "## Training episodes" in table and "| hrtc_beta seed 1 |" in table
    assert (tmp_path / "out" / "episodes.png").stat().st_size > 5_000


# slow (about 20 s): trains a child, then the tree over it
@pytest.mark.slow
def test_transfer_from_a_checkpoint_and_the_tree_trace_end_to_end(tmp_path: Path) -> None:
    budgets = [f"variants.{v}.budget=250" for v in ("tree", "finetune_long", "scratch_long")]
    proc = _bench(tmp_path, "benchmark=cartpole_swingup_tree", "algos=[tree,finetune_long,scratch_long]", "seeds=[1]",
                  *budgets, "eval_every=250", "eval_episodes=1", "thresholds=[300]", "cpus=2")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    results, table = _read(tmp_path)
    finetuned, scratch = results["runs"]["finetune_long/seed1"], results["runs"]["scratch_long/seed1"]
    assert any(o.startswith("init_from=") for o in finetuned["overrides"])
    # The fine-tuned policy starts from the pretrained one: at step 0 it differs from a fresh one.
    assert finetuned["curve"]["episode_reward"][0] != scratch["curve"]["episode_reward"][0]
    assert "- median steps to 300, finetune_long / scratch_long: **" in table
    assert "| tree | cartpole_swingup_tree |" in table and "swing: hrtc-beta policy from cartpole_energy" in table
    assert (tmp_path / "out" / "tree_weights.csv").read_text().startswith("env_step,pole_angle,")


# slow (about 30 s idle): two benchmark processes, the first killed mid-run
@pytest.mark.slow
def test_a_killed_benchmark_run_resumes_from_its_last_evaluation(tmp_path: Path) -> None:
    import os
    import signal
    import time

    args = ["benchmark=lunarlander", "algos=[hrtc_beta]", "seeds=[1]", "budget=4000", "eval_every=500",
            "eval_episodes=1", "solve_episodes=1", "final_episodes=0", "references=false", "cpus=1"]  # fmt: skip
    cmd = [sys.executable, str(ROOT / "scripts" / "benchmark.py"), f"out={tmp_path / 'out'}",
           f"runs_dir={tmp_path / 'runs'}", "backend=process", "progress=false", *args]  # fmt: skip
    run_dir = tmp_path / "runs" / "hrtc_beta" / "seed1"
    first = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and first.poll() is None:
        curve = run_dir / "curve.json"
        if curve.exists() and len(json.loads(curve.read_text() or "{}").get("step", [])) >= 3:
            break
        time.sleep(0.2)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    assert not (tmp_path / "out" / "results.json").exists() or "hrtc_beta/seed1" not in _read(tmp_path)[0]["runs"]
    killed_at = load_checkpoint(run_dir / "checkpoints" / "last.pt")["global_step"]
    assert 500 <= killed_at < 4000
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = _read(tmp_path)[0]["runs"]["hrtc_beta/seed1"]
    steps = run["curve"]["step"]
    # The first sitting's evaluations (from step 0) continue without a gap or a repeat to the budget.
    assert steps[0] == 0 and steps[-1] >= 4000 and np.all(np.diff(steps) == steps[1])
    assert load_checkpoint(run_dir / "checkpoints" / "last.pt")["global_step"] >= 4000
    assert run["wall_seconds"] >= run["curve"]["wall_seconds"][-1]  # both sittings
