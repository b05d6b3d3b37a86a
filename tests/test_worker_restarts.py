"""Chaos: a real `scripts/train.py` run whose vector-env workers are SIGKILLed mid-rollout goes on (the workers are
replaced and counted), and past `max_worker_restarts` stops with one error line, saved."""

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from hrtc.checkpoint import load_checkpoint
from hrtc.cli import compose, start_run
from hrtc.config import ROOT_CONF, RunConfig
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
# 2 envs x 25 decisions x 5 env steps = 250 env steps an update; the default algo (hrtc: workers step the skills).
SMALL = ["task=cartpole_swingup", "learner=ppo", "ppo.num_steps=25", "eval_every=1000", "eval_episodes=1",
         "checkpoint_every=500", "+task.env_kwargs.time_limit=1.0", "progress=false", "logger.frames=false",
         "logger.train_sample_every=0"]  # fmt: skip


def _train(run_dir: Path, steps: int, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), *SMALL, f"steps={steps}", f"hydra.run.dir={run_dir}",
           *extra]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _workers(pid: int) -> set[int]:
    """The vector-env workers of process ``pid``: its children forked from it (same command line)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return set()
    workers = set()
    for child in map(int, children):
        try:
            if Path(f"/proc/{child}/cmdline").read_bytes() == cmdline:
                workers.add(child)
        except OSError:
            pass
    return workers


def _kill_a_worker_mid_rollout(process: subprocess.Popen, run_dir: Path, after_rows: int, spared: set[int]) -> int:
    """Once train.csv has ``after_rows`` rows (its workers are in a rollout then), SIGKILL one worker not in
    ``spared``. Returns its pid."""
    deadline = time.time() + 90
    while True:
        assert process.poll() is None, process.communicate()[1]
        assert time.time() < deadline, "no worker to kill within 90 s"
        csv = run_dir / "train.csv"
        rows = len(csv.read_text().splitlines()) - 1 if csv.exists() else 0
        workers = _workers(process.pid) - spared
        if rows >= after_rows and len(workers) >= 1:
            victim = min(workers)
            os.kill(victim, signal.SIGKILL)
            return victim
        time.sleep(0.05)


def test_workers_killed_mid_rollout_are_replaced_and_the_run_completes(tmp_path):
    process = _train(tmp_path, 1500)
    first = _kill_a_worker_mid_rollout(process, tmp_path, after_rows=1, spared=set())
    second = _kill_a_worker_mid_rollout(process, tmp_path, after_rows=3, spared={first})
    out, err = process.communicate(timeout=300)
    assert process.returncode == 0, err
    warnings = [line for line in out.splitlines() if "was killed by SIGKILL; replaced it" in line]  # Hydra's log
    assert len(warnings) == 2 and f"(pid {first})" in warnings[0] and f"(pid {second})" in warnings[1], out
    train = pd.read_csv(tmp_path / "train.csv")
    assert list(train["step"]) == list(range(250, 1501, 250))
    restarts = train["faults/worker_restarts"].to_numpy()
    assert restarts[0] == 0 and restarts[-1] == 2 and (pd.Series(restarts).diff().dropna() >= 0).all()
    assert load_checkpoint(tmp_path / "checkpoints" / "last.pt")["global_step"] == 1500
    load_checkpoint(tmp_path / "checkpoints" / "best.pt")
    from hrtc.logging.rerun_sink import read_recording, segment_paths

    counts = read_recording(segment_paths(tmp_path), contents="/train/faults/worker_restarts", index="update")
    assert counts["/train/faults/worker_restarts"].dropna().map(lambda v: v[0]).max() == 2


def test_a_worker_death_past_max_worker_restarts_stops_the_run_saved_with_one_line(tmp_path):
    process = _train(tmp_path, 100_000, "max_worker_restarts=0", "logger.mode=off")
    victim = _kill_a_worker_mid_rollout(process, tmp_path, after_rows=1, spared=set())
    _, err = process.communicate(timeout=120)
    assert process.returncode == 1, err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in err, err
    expected = (rf"error: vector-env worker [01] \(pid {victim}\) was killed by SIGKILL, after 0 worker restarts "
                r"already \(max_worker_restarts 0\); the run is saved at step (\d+)")  # fmt: skip
    line = re.fullmatch(expected, errors[0])
    assert line, errors[0]
    saved = load_checkpoint(tmp_path / "checkpoints" / "last.pt")["global_step"]
    assert saved == int(line.group(1)) and saved >= 250 and saved % 250 == 0  # the last finished update


def test_skill_faults_of_a_replaced_worker_stay_counted(tmp_path):
    """A fresh worker's skills count their faults from zero; train.csv's lifetime totals keep the dead one's."""
    skills = OmegaConf.to_container(OmegaConf.load(ROOT_CONF / "task" / "cartpole_swingup.yaml"))["task"]["skills"]
    skills["swingup"] = {"skill": {"_target_": "skills.faulty.FaultInjector", "rate": 0.05, "kinds": ["raise"],
                                   "skill": skills["swingup"]["skill"]}}  # fmt: skip
    cfg = RunConfig(task="cartpole_swingup", skills=skills, seed=2, steps=1500, num_envs=2, vector="async",
                    eval_every=1500, eval_episodes=1, progress=False, decision_every=5, env_kwargs={"time_limit": 1.0},
                    ppo=PPOConfig(num_steps=25), max_skill_fault_rate=0.5)  # fmt: skip
    killed: list[int] = []

    def kill_after_two_rows() -> None:
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            csv = tmp_path / "train.csv"
            workers = _workers(os.getpid())
            if csv.exists() and len(csv.read_text().splitlines()) >= 3 and workers:
                killed.append(min(workers))
                os.kill(killed[0], signal.SIGKILL)
            time.sleep(0.05)

    chaos = threading.Thread(target=kill_after_two_rows, daemon=True)
    chaos.start()
    Trainer(cfg, tmp_path).train()
    chaos.join()
    train = pd.read_csv(tmp_path / "train.csv")
    assert killed and train["faults/worker_restarts"].iloc[-1] == 1
    faults = train["faults/swingup"].to_numpy()
    assert faults[-1] > faults[1] > 0 and np.all(np.diff(faults) >= 0), faults


@pytest.mark.parametrize("value", ["-1", "1.5", "true"])
def test_max_worker_restarts_must_be_a_non_negative_integer(tmp_path, capsys, value):
    with pytest.raises(SystemExit):
        start_run(compose([f"max_worker_restarts={value}"]), tmp_path)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: max_worker_restarts must be a non-negative integer")
