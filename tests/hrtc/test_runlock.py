"""One writer per run directory: real processes contend for it; a killed holder's lock is taken over."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hrtc.errors import RunLockedError
from hrtc.runlock import RunLock

ROOT = Path(__file__).resolve().parents[2]
TRAIN = [sys.executable, str(ROOT / "scripts" / "train.py")]
# A tiny real run: 1 s episodes, 2 envs x 25 decisions x 5 env steps an update, no recording.
TINY = ["task=cartpole_swingup", "learner=ppo", "ppo.num_steps=25", "eval_episodes=1", "progress=false",
        "logger.mode=off", "+task.env_kwargs.time_limit=1.0"]  # fmt: skip
HOLD = "import sys, time; from hrtc.runlock import RunLock; RunLock(sys.argv[1]).acquire(); print('held', flush=True); "
HOLD += "time.sleep(600)"


def _holder(run_dir: Path) -> subprocess.Popen:
    """A Python process that takes ``run_dir``'s lock and keeps it until killed."""
    child = subprocess.Popen([sys.executable, "-c", HOLD, str(run_dir)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline().strip() == "held"
    return child


def _error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in stderr, stderr
    return lines[0]


def test_the_lock_names_its_holder_and_a_clean_release_empties_it(tmp_path):
    with RunLock(tmp_path / "run") as lock:
        holder = json.loads(lock.path.read_text())
        assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
        assert time.time() - time.mktime(time.strptime(holder["started"], "%Y-%m-%dT%H:%M:%SZ")) < 3600 * 24
        with pytest.raises(RunLockedError, match=f"in use by pid {os.getpid()} on {socket.gethostname()} since"):
            RunLock(tmp_path / "run").acquire()  # another open file description: refused even in this process
    assert lock.path.read_text() == ""
    again = RunLock(tmp_path / "run").acquire()
    assert again.previous is None and not again.created
    again.release()


def test_a_second_training_process_on_the_same_run_directory_is_refused(tmp_path):
    run_dir = tmp_path / "run"
    first = subprocess.Popen([*TRAIN, *TINY, "steps=1000000", f"hydra.run.dir={run_dir}"], cwd=tmp_path,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    try:
        deadline = time.time() + 120
        # The first run is training: the Trainer writes train.csv's header as it is built, launch() the config.yaml
        # right after (under load the two can be seconds apart), so wait for both.
        while not ((run_dir / "train.csv").exists() and (run_dir / "config.yaml").exists()):
            assert first.poll() is None and time.time() < deadline, "the first run did not start"
            time.sleep(0.2)
        hydra_files = lambda: {p: p.stat().st_mtime_ns for p in [*run_dir.glob(".hydra/*"), run_dir / "config.yaml"]}  # noqa: E731
        before = hydra_files()
        second = subprocess.run([*TRAIN, *TINY, "steps=500", "resume=true", f"hydra.run.dir={run_dir}"], cwd=tmp_path,
                                capture_output=True, text=True, timeout=120)  # fmt: skip
        assert second.returncode == 2
        line = _error_line(second.stderr)
        assert f"in use by pid {first.pid} on {socket.gethostname()} since " in line
        # The refused process wrote nothing: the first run's Hydra files, config and lock are untouched.
        assert hydra_files() == before and len(before) == 4
        assert json.loads((run_dir / ".lock").read_text())["pid"] == first.pid
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    # The first run was killed: its lock is gone with it and resume=true just works.
    resumed = subprocess.run([*TRAIN, *TINY, "steps=500", "resume=true", f"hydra.run.dir={run_dir}"], cwd=tmp_path,
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "done:" in resumed.stdout


def test_a_sigkilled_holders_lock_is_taken_over_and_its_holder_reported(tmp_path):
    run_dir = tmp_path / "run"
    child = _holder(run_dir)
    with pytest.raises(RunLockedError, match=f"in use by pid {child.pid} "):
        RunLock(run_dir).acquire()
    child.send_signal(signal.SIGKILL)
    child.wait()
    lock = RunLock(run_dir).acquire()
    try:
        assert lock.previous is not None and lock.previous.pid == child.pid  # taken over, and said whose it was
        assert json.loads(lock.path.read_text())["pid"] == os.getpid()
    finally:
        lock.release()


def test_a_stale_lock_does_not_stop_training(tmp_path):
    run_dir = tmp_path / "run"
    child = _holder(run_dir)
    child.send_signal(signal.SIGKILL)
    child.wait()
    result = subprocess.run([*TRAIN, *TINY, "steps=500", "resume=true", f"hydra.run.dir={run_dir}"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert f"taking over the lock of pid {child.pid}" in (run_dir / "train.log").read_text() + result.stderr
    assert (run_dir / ".lock").read_text() == ""  # the run ended cleanly and released it
