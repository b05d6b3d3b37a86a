"""The benchmark harness: statistics on known data, solve and collapse rules on constructed curves, and the real
entry point end to end on a tiny budget through a local Ray (and once through the process pool)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hrtc.benchmark.report import (
    Outcome,
    SolveRule,
    bootstrap_ci,
    fastest_counts,
    find_collapse,
    first_solve,
    headline,
    iqm,
    outcome,
    summarize,
)
from hrtc.benchmark.runs import CURVE_KEYS, RunSpec, confirm_solve, confirm_true_solve
from hrtc.episodes import eval_seeds

ROOT = Path(__file__).resolve().parents[2]


# --------------------------------------------------------------------------------------------------- statistics
def test_iqm_of_known_data() -> None:
    assert iqm([1, 2, 3, 4, 5, 6, 7, 8]) == pytest.approx(4.5)  # drops 1, 2 and 7, 8
    assert iqm([100, 1, 2, 3, 4]) == pytest.approx(3.0)  # n=5: one dropped at each end, order does not matter
    assert iqm([7.0]) == 7.0
    rng = np.random.default_rng(0)
    x = rng.normal(size=41)
    scipy_stats = pytest.importorskip("scipy.stats")
    assert iqm(x) == pytest.approx(scipy_stats.trim_mean(x, 0.25))


def test_iqm_is_robust_to_one_outlier_and_censoring() -> None:
    base = [10.0, 11.0, 12.0, 13.0, 14.0]
    assert iqm([*base[:-1], 1e9]) == pytest.approx(iqm(base))  # the largest value never enters
    assert iqm([*base[:-1], math.inf]) == pytest.approx(12.0)  # one unsolved run of five: still finite
    assert math.isinf(iqm([10.0, 11.0, 12.0, math.inf, math.inf]))  # two of five: the middle reaches it


def test_bootstrap_ci_contains_the_estimate_and_shrinks_with_data() -> None:
    rng = np.random.default_rng(1)
    small, large = rng.exponential(1000, size=8), rng.exponential(1000, size=200)
    for stat in (iqm, np.median):
        for x in (small, large):
            lo, hi = bootstrap_ci(x, stat, resamples=2000)
            assert lo <= stat(x) <= hi
        width = np.subtract(*bootstrap_ci(small, stat, resamples=2000)[::-1])
        assert np.subtract(*bootstrap_ci(large, stat, resamples=2000)[::-1]) < width
    assert bootstrap_ci([5.0] * 6, iqm) == (5.0, 5.0)


def test_bootstrap_ci_keeps_censored_bounds_infinite_not_nan() -> None:
    lo, hi = bootstrap_ci([1000.0, 2000.0, math.inf, math.inf, 3000.0], np.median)
    assert math.isfinite(lo) and math.isinf(hi)


def test_summary_mean_and_std_over_solved_runs_only() -> None:
    s = summarize([1000.0, 3000.0, math.inf], collapses=1)
    assert (s.solved, s.collapses) == (2, 1)
    assert s.mean == pytest.approx(2000.0) and s.std == pytest.approx(np.std([1000, 3000], ddof=1))
    assert s.median == 3000.0


# --------------------------------------------------------------------------------------------------- solve rules
def test_first_solve_and_collapse_on_a_constructed_curve() -> None:
    curve = [0, 500, 810, 790, 780, 770, 820]
    assert first_solve(curve, 800) == 2
    assert find_collapse(curve, 800, window=3) == 5  # 790, 780, 770: the third one below completes the window
    assert find_collapse(curve, 800, window=4) is None  # recovered at 820 before four
    assert find_collapse([0, 810, 790, 805, 790, 795, 801], 800, window=3) is None  # dips never last three
    assert find_collapse([0, 100, 790, 780, 770], 800, window=1) is None  # never solved: nothing to collapse from
    assert find_collapse([900, 100], 800, window=1) == 1


def test_outcome_reads_steps_episodes_and_wall_time_at_the_solving_evaluation() -> None:
    result = {
        "curve": {
            "step": [0, 5000, 10000, 15000, 20000],
            "episode_reward": [10.0, 400.0, 850.0, 700.0, 690.0],
            "episodes": [0, 5, 10, 15, 20],
            "wall_seconds": [1.0, 5.0, 9.0, 13.0, 17.0],
        }
    }
    o = outcome(result, SolveRule(800.0, 3, collapse_window=2))
    assert (o.solved_step, o.solved_episode, o.solved_wall) == (10000, 10, 9.0)
    assert o.collapse_step == 20000 and o.collapsed
    assert (o.final, o.best) == (690.0, 850.0)
    assert not outcome(result, SolveRule(900.0, 3)).solved


def test_screened_solve_rule_confirms_once_and_decides_on_the_long_mean() -> None:
    # LunarLander's rule: 200 over 100 episodes; evaluations run 10, a passing one runs the other 90 at once.
    spec = RunSpec("lunarlander", "sb3_a2c", 1, 100, 10, 10, "unused", 1, solve_threshold=200.0, solve_episodes=100)
    calls: list[list[int]] = []

    def returns_of(seeds: list[int]) -> np.ndarray:
        calls.append(list(seeds))
        return np.full(len(seeds), 195.0 if len(calls) == 1 else 200.0)

    curve: dict[str, list] = {k: [] for k in CURVE_KEYS}
    for screen in (150.0, 240.0, 210.0, 230.0):
        curve["episode_reward"].append(screen)
        curve["solve_reward"].append(confirm_solve(spec, curve, returns_of))
    # 150 fails the screen; 240 passes but (10 x 240 + 90 x 195) / 100 = 199.5 does not confirm; 210 confirms
    # (10 x 210 + 90 x 200) / 100 = 201; after that no more confirmation runs.
    assert curve["solve_reward"] == [None, pytest.approx(199.5), pytest.approx(201.0), None]
    assert calls == [eval_seeds(1, 100)[10:]] * 2
    result = {"curve": {**curve, "step": [0, 10, 20, 30], "episodes": [0, 1, 2, 3], "wall_seconds": [0, 1, 2, 3]}}
    assert outcome(result, SolveRule(200.0, 100)).solved_step == 20  # not 10, where only the screen passed


def test_rule_c_screens_the_true_return_and_confirms_once_on_all_tracks() -> None:
    # CarRacing's rule (c): evaluations of 3 tracks; one whose *true* mean reaches 900 runs 7 more tracks at once.
    spec = RunSpec("carracing_paper", "hrtc_beta", 2, 100, 10, 3, "unused", 1, solve_threshold=900.0,
                   true_solve_episodes=10)  # fmt: skip
    assert not spec.confirms  # the shaped evaluations' own rule is untouched
    calls: list[list[int]] = []

    def true_returns_of(seeds: list[int]) -> np.ndarray:
        calls.append(list(seeds))
        return np.full(len(seeds), 850.0 if len(calls) == 1 else 910.0)

    curve: dict[str, list] = {k: [] for k in CURVE_KEYS}
    # shaped returns above 900 everywhere: only the true ones screen. None: an evaluation that did not record it.
    for shaped, true in ((1000.0, None), (1000.0, 880.0), (1000.0, 920.0), (1000.0, 905.0), (1000.0, 990.0)):
        curve["episode_reward"].append(shaped)
        curve["true_reward"].append(true)
        curve["true_solve_reward"].append(confirm_true_solve(spec, curve, true_returns_of))
    # 920 passes the screen, but (3 x 920 + 7 x 850) / 10 = 871 does not confirm; 905 does: (3 x 905 + 7 x 910) / 10.
    assert curve["true_solve_reward"] == [None, None, pytest.approx(871.0), pytest.approx(908.5), None]
    assert calls == [eval_seeds(2, 10)[3:]] * 2
    # Without the setting (or with no more tracks than an evaluation runs) nothing is run.
    for n in (0, 3):
        quiet = RunSpec("carracing_paper", "hrtc_beta", 2, 100, 10, 3, "unused", 1, solve_threshold=900.0,
                        true_solve_episodes=n)  # fmt: skip
        assert confirm_true_solve(quiet, {"true_reward": [990.0], "true_solve_reward": []}, true_returns_of) is None
    assert len(calls) == 2


def test_fastest_counts_share_ties_and_skip_unsolved_seeds() -> None:
    costs = {"a": {1: 100.0, 2: 300.0, 3: math.inf}, "b": {1: 200.0, 2: 300.0, 3: math.inf}}
    assert fastest_counts(costs) == {"a": 2, "b": 1}


def _outcomes(steps: dict[str, list[float | None]]) -> dict[str, dict[int, Outcome]]:
    return {
        algo: {i + 1: Outcome(s, None if s is None else int(s // 1000), None, None, 0.0, 0.0) for i, s in enumerate(xs)}
        for algo, xs in steps.items()
    }


def test_headline_says_where_hrtc_does_not_win() -> None:
    wins = _outcomes({"hrtc_beta": [1000, 1100, 1200], "sb3_sac": [2000, 5000, None]})
    assert "Headline holds" in "\n".join(headline(wins))
    loses = _outcomes({"hrtc_beta": [3000, 3100, 2900], "sb3_sac": [1000, 1500, 1200], "ppo_beta": [None] * 3})
    text = "\n".join(headline(loses))
    assert "does not fully hold" in text and "SB3 SAC" in text.split("Not against:")[1]
    assert "PPO Beta" in text.split("Not against:")[0]  # faster than the one that never solved
    # Both with infinite IQMs (n=3, one unsolved each) but a better median: faster, yet no spread to compare.
    tie = "\n".join(headline(_outcomes({"hrtc_beta": [1000, 1100, None], "ppo_beta": [5000, None, None]})))
    assert "does not fully hold" in tie and "PPO Beta" in tie.split("Not against:")[1]


def test_a_table_of_one_algorithm_claims_no_headline() -> None:
    text = "\n".join(headline(_outcomes({"hrtc_beta": [1000, None]})))
    assert "no headline" in text and "Headline holds" not in text


def test_headline_names_runs_that_met_the_rule_before_any_update() -> None:
    text = "\n".join(headline(_outcomes({"hrtc_beta": [0, 4000, 0], "ppo_beta": [8000, None, None]})))
    assert "HRTC Beta (PPO): 2 of 3 runs (seeds 1, 3) met the rule at step 0" in text
    assert "PPO Beta:" not in text.split("Headline holds")[-1]
    assert "step 0" not in "\n".join(headline(_outcomes({"hrtc_beta": [1000], "ppo_beta": [2000]})))


# --------------------------------------------------------------------------------------------------- end to end
def _bench(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(ROOT / "scripts" / "benchmark.py"), "task=cartpole_swingup", "budget=400",
           "eval_every=200", "eval_episodes=1", "threshold=50", "cpus=2", "progress=false", "final_episodes=1",
           f"out={tmp_path / 'out'}", f"runs_dir={tmp_path / 'runs'}", *extra]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)


# slow (about 25 s, most of it starting Ray): the default run takes the same harness through a process pool
@pytest.mark.slow
def test_benchmark_end_to_end_through_a_local_ray(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    proc = _bench(tmp_path, "algos=[ppo_beta,sb3_a2c]", "seeds=2", "backend=ray")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "4 to run (ray)" in proc.stdout
    out = tmp_path / "out"
    results = json.loads((out / "results.json").read_text())
    assert sorted(results["runs"]) == ["ppo_beta/seed1", "ppo_beta/seed2", "sb3_a2c/seed1", "sb3_a2c/seed2"]
    for run in results["runs"].values():
        steps = run["curve"]["step"]
        assert steps[0] == 0 and steps[-1] >= 400 and np.all(np.diff(steps) > 0)
        assert np.all(np.isfinite(run["curve"]["episode_reward"]))
        assert len(run["curve"]["episodes"]) == len(steps) and run["curve"]["episodes"][-1] == 0  # 1000-step episodes
        assert run["wall_seconds"] > 0 and Path(run["run_dir"]).exists()
        assert len(run["final_returns"]) == 1 and np.isfinite(run["final_returns"][0])
    # Each seed trained its own policy: the two seeds' curves differ.
    assert results["runs"]["sb3_a2c/seed1"]["curve"] != results["runs"]["sb3_a2c/seed2"]["curve"]
    table = (out / "table.md").read_text()
    assert "| seed | PPO Beta | SB3 A2C |" in table and "IQM [95% CI]" in table and "## Headline" in table
    # The references over the same skills stand beside the learners: each skill alone, the untrained blend, the
    # task's declared hand rule (the switching rule scores far above any skill alone even on one episode).
    refs = results["references"]
    assert {
        "swingup alone",
        "balance alone",
        "tracker alone",
        "hold alone",
        "untrained blend (every weight 0.5)",
    } <= set(refs)
    rule = next(v for k, v in refs.items() if k.startswith("switching rule"))
    assert rule[0] > 850 > refs["swingup alone"][0] + 200
    assert "## References over the same skills (1 episodes each" in table
    assert (out / "curves.png").stat().st_size > 10_000
    summary = json.loads((out / "summary.json").read_text())  # the table's numbers, read back
    assert set(summary["runs"]) == set(results["runs"]) and set(summary["algorithms"]) == {"ppo_beta", "sb3_a2c"}


def test_benchmark_in_a_process_pool_skips_finished_runs(tmp_path: Path) -> None:
    proc = _bench(tmp_path, "algos=[sb3_a2c]", "seeds=2", "backend=process")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2 to run (process)" in proc.stdout
    path = tmp_path / "out" / "results.json"
    results = json.loads(path.read_text())
    assert results["runs"]["sb3_a2c/seed1"]["curve"]["step"][-1] >= 400
    # A killed benchmark continues: drop one finished run, and only that one runs again.
    kept = results["runs"]["sb3_a2c/seed1"]
    del results["runs"]["sb3_a2c/seed2"]
    path.write_text(json.dumps(results))
    proc = _bench(tmp_path, "algos=[sb3_a2c]", "seeds=2", "backend=process", "references=false")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "1 already in" in proc.stdout and "1 to run" in proc.stdout
    again = json.loads(path.read_text())
    assert again["runs"]["sb3_a2c/seed1"] == kept  # skipped, not re-run
    # Run without references, it keeps the stored ones, in the file and in the table.
    assert again["references"] == results["references"] and "swingup alone" in again["references"]
    assert "## References over the same skills" in (tmp_path / "out" / "table.md").read_text()
    commands = (tmp_path / "out" / "command.txt").read_text().splitlines()
    assert len(commands) == 2 and all(c.startswith("python scripts/benchmark.py task=") for c in commands)
    machines = (tmp_path / "out" / "machine.txt").read_text().splitlines()  # where each invocation ran, appended
    assert len(machines) == 2 and all(f"{os.cpu_count()} cores" in m for m in machines)
    assert sorted(again["runs"]) == ["sb3_a2c/seed1", "sb3_a2c/seed2"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_killed_benchmark_takes_its_pool_workers_with_it(tmp_path: Path) -> None:
    """SIGKILL leaves the benchmark no handler to run: the kernel's death signal still ends its pool worker, whose
    run then stops as a stopped run does (a checkpoint saved) instead of running on, orphaned."""
    psutil = pytest.importorskip("psutil")
    cmd = [sys.executable, str(ROOT / "scripts" / "benchmark.py"), "task=cartpole_swingup", "budget=200000",
           "eval_every=100000", "eval_episodes=1", "cpus=1", "progress=false", "algos=[hrtc_beta]", "seeds=1",
           "backend=process", "references=false", f"out={tmp_path / 'out'}",
           f"runs_dir={tmp_path / 'runs'}"]  # fmt: skip
    log = tmp_path / "benchmark.log"  # the worker's lines too (it inherits the file): what a failure shows
    with log.open("w") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)
    workers: list = []
    try:
        deadline = time.monotonic() + 300
        train_csv = tmp_path / "runs" / "hrtc_beta" / "seed1" / "train.csv"
        while not (train_csv.exists() and len(train_csv.read_text().splitlines()) > 1):
            assert proc.poll() is None, f"the benchmark ended before its run started:\n{log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"no train.csv row in 300 s:\n{log.read_text()[-3000:]}"
            time.sleep(0.2)
        workers = [c for c in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(c.cmdline())]
        assert len(workers) == 1
        proc.kill()
        proc.wait(30)
        _, alive = psutil.wait_procs(workers, timeout=60)
        assert not alive, "the pool worker outlived its benchmark"
    finally:
        for process in [*workers, psutil.Process(proc.pid)] if proc.poll() is None else workers:
            if process.is_running():
                process.kill()  # a failed check leaves nothing running
    # SIGTERM in the worker: the trainer's checkpoint on stop
    assert list((tmp_path / "runs").rglob("last.pt")), log.read_text()[-3000:]


def test_machine_line_names_the_cpu_generation_and_its_bfloat16_instructions() -> None:
    """A model name such as "AMD EPYC" covers CPUs whose float results differ: the line adds family and model."""
    from hrtc.benchmark.report import _cpu_model

    two = (
        "processor\t: 0\nmodel name\t: AMD EPYC\ncpu family\t: 26\nmodel\t\t: 2\nflags\t\t: fpu avx512_bf16 avx\n\n"
        "processor\t: 1\nmodel name\t: AMD EPYC\ncpu family\t: 26\nmodel\t\t: 2\nflags\t\t: fpu avx512_bf16\n"
    )
    assert _cpu_model(two).endswith("AMD EPYC (family 26, model 2; avx512_bf16)")
    xeon = "model name\t: Intel(R) Xeon(R)\ncpu family\t: 6\nmodel\t\t: 143\nflags\t\t: amx_bf16 amx_tile avx512_bf16\n"
    assert _cpu_model(xeon).endswith("Intel(R) Xeon(R) (family 6, model 143; amx_bf16 avx512_bf16)")
    assert _cpu_model("model name\t: Some CPU\n").endswith("Some CPU")  # nothing more known: nothing added
    assert "(" not in _cpu_model("")  # no /proc/cpuinfo: the architecture


def test_references_on_every_run_seed_use_the_final_policies_own_episodes() -> None:
    """``reference_seed=runs``: the references' episodes are those the final policies of every run seed are measured
    on (the run's evaluation seeds, or final_seed_base's scheme), seed after seed; an integer: that seed's only."""
    from hrtc.benchmark.main import check, parse, reference_episode_seeds

    assert reference_episode_seeds(None, "runs", [1, 2, 3], 4) == eval_seeds(1, 4) + eval_seeds(2, 4) + eval_seeds(3, 4)
    assert reference_episode_seeds(None, 2, [1, 2, 3], 4) == eval_seeds(2, 4)
    assert reference_episode_seeds(2_000_000, "runs", [1, 2], 2) == [2_001_000, 2_001_001, 2_002_000, 2_002_001]
    assert len(set(reference_episode_seeds(None, "runs", [1, 2, 3, 4, 5], 10))) == 50  # no episode counted twice
    assert check(parse(["benchmark=pendulum_swingup", "reference_seed=runs"]))["reference_seed"] == "runs"
    with pytest.raises(SystemExit):
        check(parse(["benchmark=pendulum_swingup", "reference_seed=all"]))


def test_benchmark_rejects_bad_arguments_in_one_line(tmp_path: Path) -> None:
    proc = _bench(tmp_path, "algos=[hrtc_beta,sac]")
    assert proc.returncode == 2 and proc.stderr.strip() == (
        "error: unknown algorithm 'sac'; valid: hrtc_beta, hrtc_beta_sac, hrtc_normal, ppo_beta, ppo_normal, sb3_ppo, "
        "sb3_sac, sb3_td3, sb3_a2c, sb3_sac_composed"
    )
    proc = _bench(tmp_path, "seedz=3")
    assert proc.returncode == 2 and proc.stderr.startswith("error: unknown key 'seedz'")


def test_sb3_sac_acts_on_the_composed_env_and_counts_env_steps(tmp_path: Path) -> None:
    """An off-the-shelf agent on ComposedEnv: its action is the weight vector; its steps count decision_every env
    steps each (cartpole_swingup: 5)."""
    from hrtc.benchmark.runs import RunSpec, run

    result = run(RunSpec("cartpole_swingup", "sb3_sac_composed", 1, 500, 500, 1, str(tmp_path), final_episodes=1))
    assert result["curve"]["step"] == [0, 500]
    assert len(result["final_returns"]) == 1 and result["final_returns"][0] >= 0


def test_the_episodes_table_reports_each_solve_rule_with_its_episode_and_frames(tmp_path: Path) -> None:
    from hrtc.benchmark.report import SolveRule
    from hrtc.benchmark.studies import episodes_lines

    # 600 episodes of 800 frames: scores climb 0 -> 1000 linearly, gymnasium's returns 100 lower.
    scores = np.linspace(0.0, 1000.0, 600)
    log = {"returns": scores.tolist(), "true_returns": (scores - 100).tolist(), "train_frames": [800] * 600,
           "frames": 600 * 800, "wall_seconds": 600.0, "frames_per_second": 800.0}  # fmt: skip
    curve = {"episodes": [0, 600], "episode_reward": [0.0, 950.0]}
    lines = episodes_lines({"ppo_beta": {1: {"episodes_log": log, "curve": curve}}}, SolveRule(900.0, 10),
                           {"windows": [10]}, tmp_path)  # fmt: skip
    row = next(line for line in lines if line.startswith("| ppo_beta seed 1 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    header = next(line for line in lines if line.startswith("| run |"))
    assert len(cells) == len(header.strip("|").split("|"))
    first_10_mean = int(np.flatnonzero(np.convolve(scores, np.ones(10) / 10, "valid") >= 900)[0]) + 10
    assert f"episode {first_10_mean} ({first_10_mean * 800:,} frames)" in cells
    # The running score lags the scores: it never passes 900 while they climb to 1000.
    assert "not reached" in cells and cells[6] == f"{(scores[-10:] - 100).mean():.0f}"
    assert (tmp_path / "episodes.png").stat().st_size > 5_000
    evaluations = next(line for line in lines if line.lstrip().startswith("Evaluations of ppo_beta seed 1"))
    assert "950 after 600 episodes." in evaluations and "Rule (c)" not in evaluations  # no true return recorded
    # A run that recorded the evaluations' true returns (the first evaluation before the column existed):
    curve["true_reward"] = [None, 880.0]
    lines = episodes_lines({"ppo_beta": {1: {"episodes_log": log, "curve": curve}}}, SolveRule(900.0, 10),
                           {"windows": [10]}, tmp_path)  # fmt: skip
    evaluations = next(line for line in lines if line.lstrip().startswith("Evaluations of ppo_beta seed 1"))
    assert "950 (true 880) after 600 episodes" in evaluations
    assert "true return >= 900: best 880 over the 1 evaluations that recorded it (not reached)" in evaluations
    rule_c = cells[-4]  # the episodes table's rule (c) column (before the paper's and the projections)
    assert rule_c == "not reached"
    # Rule (c) screened twice: 930 failed on all 10 tracks (870), 960 confirmed (915) at the evaluation after 580.
    curve = {"episodes": [0, 500, 580], "episode_reward": [0.0, 1000.0, 1040.0], "true_reward": [None, 930.0, 960.0],
             "true_solve_reward": [None, 870.0, 915.0]}  # fmt: skip
    lines = episodes_lines({"ppo_beta": {1: {"episodes_log": log, "curve": curve}}}, SolveRule(900.0, 10),
                           {"windows": [10]}, tmp_path)  # fmt: skip
    row = next(line for line in lines if line.startswith("| ppo_beta seed 1 |"))
    assert [c.strip() for c in row.strip("|").split("|")][-4] == f"episode 580 ({580 * 800:,} frames)"
    evaluations = next(line for line in lines if line.lstrip().startswith("Evaluations of ppo_beta seed 1"))
    assert "1000 (true 930) [more tracks: true 870] after 500 episodes" in evaluations
    assert "best 960 over the 2 evaluations that recorded it (confirmed after 580 episodes)" in evaluations
    curve["true_solve_reward"] = [None, 870.0, None]  # the screen passed once and failed on all the tracks
    lines = episodes_lines({"ppo_beta": {1: {"episodes_log": log, "curve": curve}}}, SolveRule(900.0, 10),
                           {"windows": [10]}, tmp_path)  # fmt: skip
    evaluations = next(line for line in lines if line.lstrip().startswith("Evaluations of ppo_beta seed 1"))
    assert "(not confirmed on more tracks (best 870))" in evaluations


def test_a_resumed_run_keeps_its_curve_and_episode_log_up_to_its_checkpoint(tmp_path: Path) -> None:
    from hrtc.benchmark.runs import _EvalCollector, keep_logged_episodes
    from hrtc.episodes import eval_seeds

    log = tmp_path / "episodes.csv"
    evaluation = eval_seeds(1, 2)
    # Four training episodes and two evaluation episodes; the checkpoint (saved at 250.0) counted three training
    # episodes: the fourth belongs to a rollout the resumed run redoes, as does the evaluation after it.
    lines = ["100.5,1,-1,12.0,800\n", f"150.0,1,{evaluation[0]},5.0,1000\n", "200.0,2,-1,30.0,900\n",
             "240.0,1,-1,31.0,900\n", "260.0,2,-1,41.0,1000\n", f"270.0,1,{evaluation[1]},6.0,1000\n"]  # fmt: skip
    log.write_text("".join([lines[2], lines[0], *lines[3:], lines[1]]))  # appended out of order by two workers
    keep_logged_episodes(log, 250.0, train_episodes=3, seed=1)
    assert log.read_text() == "".join(lines[:4])
    spec = RunSpec(task="cartpole_swingup", algo="hrtc_beta", seed=1, steps=3000, eval_every=1000, eval_episodes=1,
                   run_dir=str(tmp_path), wall_minutes=10.0)  # fmt: skip
    saved = {k: [0, 1000, 2000] if k == "step" else [1.0, 2.0, 3.0] for k in CURVE_KEYS}
    (tmp_path / "curve.json").write_text(json.dumps(saved))
    collector = _EvalCollector(spec)
    deadline = collector.deadline
    collector.restore(step=1000, wall_before=120.0)  # the checkpoint was saved at step 1000, after 2 minutes
    assert collector.curve["step"] == [0, 1000] and collector.curve["episode_reward"] == [1.0, 2.0]
    assert collector.deadline == pytest.approx(deadline - 120.0)
    # A curve saved before the true return was recorded: its evaluations have none; the next one does.
    (tmp_path / "curve.json").write_text(json.dumps({k: v for k, v in saved.items() if k != "true_reward"}))
    collector = _EvalCollector(spec)
    collector.restore(step=1000, wall_before=0.0)
    assert collector.curve["true_reward"] == [None, None]
    collector.write("eval", 2000, {"episode_reward": 3.0, "episode_reward_std": 0.0, "train_episodes": 9,
                                   "wall_seconds": 5.0, "true_episode_reward": -4.0})  # fmt: skip
    assert collector.curve["true_reward"] == [None, None, -4.0]
    assert json.loads((tmp_path / "curve.json").read_text())["true_reward"] == [None, None, -4.0]


def test_a_run_started_by_train_py_is_adopted_from_its_eval_csv(tmp_path: Path) -> None:
    from hrtc.benchmark.runs import _EvalCollector

    (tmp_path / "eval.csv").write_text(
        "step,episode_reward,episode_reward_std,episodes,train_episodes,wall_seconds\n"
        "0,5.0,1.0,3,0,2.0\n25000,40.0,3.0,3,180,900.0\n50000,80.0,2.0,3,350,1800.0\n"
    )
    spec = RunSpec(task="carracing_paper", algo="ppo_beta", seed=1, steps=100_000, eval_every=25_000,
                   eval_episodes=3, run_dir=str(tmp_path))  # fmt: skip
    collector = _EvalCollector(spec)
    collector.restore(step=25_000, wall_before=900.0)
    assert collector.curve["step"] == [0, 25_000] and collector.curve["episodes"] == [0, 180]
    assert collector.curve["solve_reward"] == [5.0, 40.0] and collector.deadline is None
    assert collector.curve["true_reward"] == [None, None]  # an eval.csv from before the column
    (tmp_path / "eval.csv").write_text(  # after a resumed run widened the header (CsvSink) and wrote on
        "step,episode_reward,episode_reward_std,episodes,train_episodes,wall_seconds,true_episode_reward\n"
        "0,5.0,1.0,3,0,2.0,\n25000,40.0,3.0,3,180,900.0,-60.5\n"
    )
    collector = _EvalCollector(spec)
    collector.restore(step=25_000, wall_before=900.0)
    assert collector.curve["true_reward"] == [None, -60.5]


def test_evaluating_a_checkpoint_never_writes_into_its_training_runs_episode_log(tmp_path: Path) -> None:
    """A benchmark run's env_kwargs carry ``episode_log`` (its solve rules read every training episode there); the
    env that evaluates its checkpoint later is built without it, while the training env writes it."""
    from hrtc.benchmark.metrics import checkpoint_env
    from hrtc.environments import make_env

    log = tmp_path / "episodes.csv"
    kwargs = {"action_repeat": 8, "max_frames": 16, "episode_log": str(log)}
    meta = {"task": "carracing", "algo": "ppo", "skills_cfg": {}, "action_filter": "sum", "env_kwargs": kwargs,
            "decision_every": 1}  # fmt: skip

    def one_episode(env) -> None:
        env.reset(seed=0)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(np.zeros(3, np.float32))
            done = terminated or truncated
        env.close()

    one_episode(checkpoint_env(meta))
    assert not log.exists() and meta["env_kwargs"]["episode_log"] == str(log)  # the saved settings left as they were
    one_episode(make_env("carracing", "ppo", {}, "sum", kwargs, 1))
    assert log.read_text().count("\n") == 1  # the training env's episode
