"""The real entry point, run as a user runs it: two PPO iterations, and one-line errors for bad input."""

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from hrtc.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[1]
TRAIN = [sys.executable, str(ROOT / "scripts" / "train.py")]


def _run(args, tmp_path=None, timeout=300):
    return subprocess.run(TRAIN + list(args), capture_output=True, text=True, timeout=timeout, cwd=tmp_path or ROOT)


# HRTC decides every 5 env steps on cartpole_swingup (the task's setting): 50 decisions x 2 envs = 500 env steps.
@pytest.mark.parametrize("algo,num_steps", [("hrtc", 50), ("ppo", 250)])
def test_train_two_iterations_writes_the_run_directory(tmp_path, algo, num_steps):
    run_dir = tmp_path / "run"
    args = [f"algo={algo}", "learner=ppo", "task=cartpole_swingup", "steps=1000", f"ppo.num_steps={num_steps}",
            "eval_every=500"]  # fmt: skip
    result = _run([*args, "eval_episodes=1", "progress=false", f"hydra.run.dir={run_dir}"], tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "done: 1000 steps" in result.stdout
    assert f"the best evaluated policy: {run_dir / 'checkpoints' / 'best.pt'}" in result.stdout
    assert (run_dir / "checkpoints" / "best.pt").exists()
    train = pd.read_csv(run_dir / "train.csv")
    evals = pd.read_csv(run_dir / "eval.csv")
    assert list(train["step"]) == [500, 1000]
    for column in ("losses/approx_kl", "losses/clipfrac", "losses/explained_variance", "charts/SPS"):
        assert column in train and train[column].notna().all()
    assert list(evals["step"]) == [0, 500, 1000]
    assert evals["episode_reward"].between(0, 1000).all()
    state = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert state["global_step"] == 1000 and state["meta"]["algo"] == algo
    if algo == "hrtc":
        assert state["meta"]["skills"] == ["swingup", "balance", "tracker", "hold"]
    assert "name: cartpole_swingup" in (run_dir / "config.yaml").read_text()


def test_train_with_the_sac_learner_saves_its_replay_buffer_and_resumes(tmp_path):
    """learner=sac through the real entry point: losses in train.csv, the replay buffer in last.pt (not in best.pt),
    and a resume that continues the buffer and the step count."""
    run_dir = tmp_path / "run"  # one gradient step per decision (the task's default takes 2): the counts below
    args = ["task=cartpole_swingup", "learner=sac", "sac.learning_starts=100", "sac.log_every=100", "sac.batch_size=32",
            "sac.updates_per_decision=1", "eval_every=500", "eval_episodes=1", "progress=false",
            f"hydra.run.dir={run_dir}"]  # fmt: skip
    result = _run([*args, "steps=1000"], tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    train = pd.read_csv(run_dir / "train.csv")
    assert train["losses/gradient_steps"].sum() > 0 and train["losses/q_loss"].dropna().gt(0).all()
    state = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert state["meta"]["learner"] == "sac" and state["optimizer"]["buffer"]["rewards"].shape[0] == 200
    # 200 decisions; from the vector step that fills the buffer to 100 on (51 steps of 2), one gradient step per
    # decision: 100 taken, the last step's 2 still owed (updates run while the envs step, on what was observed).
    assert state["optimizer"]["counters"]["gradient_steps"] == 100 and state["optimizer"]["counters"]["credit"] == 2
    assert load_checkpoint(run_dir / "checkpoints" / "best.pt")["optimizer"] == {}
    result = _run([*args, "steps=1500", "resume=true"], tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    state = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert state["global_step"] == 1500 and state["optimizer"]["buffer"]["rewards"].shape[0] == 300
    assert state["optimizer"]["counters"]["gradient_steps"] == 200


@pytest.mark.parametrize(
    "args,expected",
    [
        (["task=cartpol"], "unknown task 'cartpol'; valid tasks: "),
        (["algo=sac"], "unknown algo 'sac'; valid algos: hrtc, ppo"),
        (["dist=gamma"], "unknown dist 'gamma'; valid dists: beta, normal"),
        (["steps=[1"], "malformed override"),
        (["stepz=10"], "cannot set 'stepz'"),
        (["steps=-3"], "steps must be a positive integer"),
        (["ppo.learning_rate=2.0"], "ppo.learning_rate must be in (0, 1)"),
        (["algo.action_filter=max"], "unknown action filter mode 'max'"),
        (["algo.init_weights={swing: 1.0}"], "unknown algo.init_weights skill 'swing'"),
    ],
)
def test_bad_input_is_one_clear_line_and_a_nonzero_exit(tmp_path, args, expected):
    result = _run([*args, f"hydra.run.dir={tmp_path / 'run'}"], tmp_path, timeout=120)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert expected in lines[0]
