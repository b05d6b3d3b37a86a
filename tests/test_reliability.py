"""Reliability: a run killed at any moment resumes to the same end, skill faults are isolated and counted, bad input
is one clear line, a loss that stays NaN stops the run."""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

import envs
from hrtc.checkpoint import load_checkpoint
from hrtc.cli import compose, start_run
from hrtc.config import ROOT_CONF, RunConfig
from hrtc.errors import HRTCError, SkillError
from hrtc.logging.rerun_sink import read_recording, segment_paths
from hrtc.logging.trace import RecordingConfig
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
SKILLS = OmegaConf.to_container(OmegaConf.load(ROOT_CONF / "task" / "cartpole_swingup.yaml"))["task"]["skills"]

# A small real run: 2 envs x 25 decisions x 5 env steps = 250 env steps an update, 1 s episodes.
SMALL = ["task=cartpole_swingup", "learner=ppo", "ppo.num_steps=25", "eval_every=500", "eval_episodes=1",
         "checkpoint_every=250", "+task.env_kwargs.time_limit=1.0", "progress=false",
         "logger.frames=false"]  # fmt: skip


def _train(run_dir: Path, steps: int, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), *SMALL, f"steps={steps}", f"hydra.run.dir={run_dir}",
           *extra]  # fmt: skip
    # SIGINT back to its default in the child: under a parent started as a background job (nohup cmd &) it arrives
    # ignored, and Python would then never raise the KeyboardInterrupt that makes the trainer save and stop.
    restore = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # noqa: E731
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=restore)  # fmt: skip


def _kill_at_random_moments(run_dir: Path, steps: int, kills: int, seed: int) -> int:
    """Start, SIGKILL after a random delay, resume, ... ``kills`` times, then let the run finish. Returns how many
    kills landed on a running process."""
    rng = random.Random(seed)
    landed = 0
    for attempt in range(kills + 1):
        process = _train(run_dir, steps, f"resume={'true' if attempt else 'false'}")
        if attempt == kills:
            _, err = process.communicate(timeout=600)
            assert process.returncode == 0, err
            break
        time.sleep(rng.uniform(3.0, 12.0))  # start-up (imports) takes about 3 s: moments before and after it
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            landed += 1
        process.wait()
        for name in ("last.pt", "best.pt"):  # whatever exists is loadable at every moment
            path = run_dir / "checkpoints" / name
            if path.exists():
                load_checkpoint(path)
    return landed


def _assert_consistent(run_dir: Path, steps: int) -> None:
    train = pd.read_csv(run_dir / "train.csv")
    assert list(train["step"]) == list(range(250, steps + 1, 250)), "train.csv rows lost or duplicated"
    evals = pd.read_csv(run_dir / "eval.csv")
    # Every 500 steps, and always at the end (a Ctrl-C can land so that the resumed run ends between two of them).
    assert list(evals["step"]) == sorted({*range(0, steps + 1, 500), steps}), "eval.csv rows lost or duplicated"
    assert load_checkpoint(run_dir / "checkpoints" / "last.pt")["global_step"] == steps
    load_checkpoint(run_dir / "checkpoints" / "best.pt")


def test_sigkill_at_random_moments_then_resume_ends_like_an_uninterrupted_run(tmp_path):
    landed = _kill_at_random_moments(tmp_path, 2500, kills=3, seed=11)
    assert landed >= 1
    _assert_consistent(tmp_path, 2500)
    from hrtc import review

    assert len(review.load(tmp_path).episodes) >= 6  # every evaluation's episode, across the segments


@pytest.mark.slow
def test_sigkill_at_ten_random_moments(tmp_path):
    landed = _kill_at_random_moments(tmp_path, 5000, kills=10, seed=7)
    assert landed >= 5
    _assert_consistent(tmp_path, 5000)


def test_ctrl_c_saves_a_checkpoint_and_the_resumed_run_ends_on_the_same_step(tmp_path):
    process = _train(tmp_path, 200_000)
    deadline = time.time() + 120
    while not (tmp_path / "eval.csv").exists() or len((tmp_path / "eval.csv").read_text().splitlines()) < 3:
        assert time.time() < deadline and process.poll() is None, "no evaluation within 120 s"
        time.sleep(0.3)
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130 and "resume=true" in err, err
    saved = load_checkpoint(tmp_path / "checkpoints" / "last.pt")["global_step"]
    assert saved % 250 == 0 and saved >= 500  # the last finished update, not a step inside a rollout
    resumed = _train(tmp_path, saved + 500, "resume=true")
    _, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, err
    _assert_consistent(tmp_path, saved + 500)


# ------------------------------------------------------------------------------------------ fault isolation
def _faulty(rate: float, kinds: list[str]) -> dict:
    skills = dict(SKILLS)
    skills["swingup"] = {
        "time_budget_ms": 20,
        "skill": {"_target_": "skills.faulty.FaultInjector", "rate": rate, "kinds": kinds, "slow_ms": 30,
                  "skill": SKILLS["swingup"]["skill"]},
    }  # fmt: skip
    return skills


def _cfg(steps: int, skills: dict, **kwargs) -> RunConfig:
    base = dict(task="cartpole_swingup", skills=skills, seed=2, steps=steps, num_envs=2, vector="sync",
                eval_every=1000, eval_episodes=1, progress=False, decision_every=5, env_kwargs={"time_limit": 2.0},
                ppo=PPOConfig(num_steps=50, learning_rate=1e-3))  # fmt: skip
    return RunConfig(**{**base, **kwargs})


def test_injected_faults_at_one_percent_leave_training_running_and_counted(tmp_path):
    cfg = _cfg(2000, _faulty(0.01, ["raise", "nan", "inf", "shape", "slow"]),
               logger=RecordingConfig(frames=False, train_sample_every=0))  # fmt: skip
    result = Trainer(cfg, tmp_path).train()
    assert result["steps"] == 2000 and np.isfinite(result["final_eval"])
    train = pd.read_csv(tmp_path / "train.csv")
    faults = train["faults/swingup"].to_numpy()
    assert faults[-1] >= 5 and np.all(np.diff(faults) >= 0)  # about 1% of 2000 calls, counted as they happen
    assert (train[[f"faults/{n}" for n in SKILLS if n != "swingup"]] == 0).all().all()
    # The recording flags the evaluation steps whose proposal was replaced.
    flags = read_recording(segment_paths(tmp_path), contents="/skills/swingup/fault", index="env_step")
    flags = np.stack(flags["/skills/swingup/fault"].dropna())[:, 0]
    assert set(np.unique(flags)) <= {0.0, 1.0} and flags.sum() >= 1


def test_a_skill_faulting_past_the_allowed_rate_stops_the_run_naming_it(tmp_path):
    cfg = _cfg(5000, _faulty(0.3, ["raise"]), max_skill_fault_rate=0.1)
    with pytest.raises(SkillError, match=r"skill 'swingup' faulted in \d+ of \d+ calls"):
        Trainer(cfg, tmp_path).train()
    assert (tmp_path / "checkpoints" / "last.pt").exists()  # saved before stopping


@envs.register("test_nan_reward")
def _nan_reward(**kwargs) -> gym.Env:
    class NaNReward(gym.Wrapper):
        def step(self, action):
            obs, _, terminated, truncated, info = self.env.step(action)
            return obs, float("nan"), terminated, truncated, info

    return NaNReward(envs.make("cartpole_swingup", **kwargs))


def test_a_loss_that_stays_non_finite_stops_the_run(tmp_path):
    cfg = _cfg(10_000, {}, task="test_nan_reward", algo="ppo", max_skipped_updates=2)
    with pytest.raises(HRTCError, match="not finite in 2 updates in a row"):
        Trainer(cfg, tmp_path).train()
    train = pd.read_csv(tmp_path / "train.csv")
    assert len(train) == 2 and (train["losses/skipped"] > 0).all()


# ------------------------------------------------------------------------------------------ validated input
def _other_skills_checkpoint(run_dir: Path) -> None:
    fewer = {k: v for k, v in SKILLS.items() if k != "hold"}
    Trainer(_cfg(250, fewer, ppo=PPOConfig(num_steps=25)), run_dir).save()


BAD_INPUTS = [
    (["task=cartpol"], "unknown task 'cartpol'; valid tasks: "),
    (["algo=sac"], "unknown algo 'sac'; valid algos: hrtc, ppo"),
    (["dist=gamma"], "unknown dist 'gamma'; valid dists: beta, normal"),
    (["steps=[1"], "malformed override"),
    (["stepz=10"], "cannot set 'stepz'"),
    (["ppo.clip=0.1"], "cannot set 'ppo.clip'"),
    (["steps=-3"], "steps must be a positive integer"),
    (["steps=0"], "steps must be a positive integer"),
    (["seed=-1"], "seed must be a non-negative integer"),
    (["num_envs=0"], "num_envs must be a positive integer"),
    (["eval_episodes=0"], "eval_episodes must be a positive integer"),
    (["ppo.learning_rate=2.0"], "ppo.learning_rate must be in (0, 1)"),
    (["ppo.learning_rate=0"], "ppo.learning_rate must be in (0, 1)"),
    (["ppo.gamma=1.5"], "ppo.gamma must be in [0, 1]"),
    (["ppo.num_minibatches=100000"], "exceeds the rollout size"),
    (["algo.action_filter=max"], "unknown action filter mode 'max'"),
    (["algo.decision_every=0"], "algo.decision_every must be a positive integer"),
    (["algo.weight_margin=-0.5"], "algo.weight_margin must be a number in [0, 10)"),
    (["vector=threads"], "unknown vector mode 'threads'"),
    (["hidden=[]"], "hidden must list positive layer widths"),
    (["logger.mode=disk"], "unknown logger mode 'disk'"),
    (["logger.frame_every=0"], "logger.frame_every must be >= 1"),
    (["max_skill_fault_rate=2"], "max_skill_fault_rate must be in [0, 1]"),
    (["task.skills.hold.skill._target_=skills.static.Nope"], "skill 'hold' could not be built"),
    (["task.skills.hold.skill.action=[0.0,0.0]"], "skill 'hold' proposed an action of shape (2,); the task's is (1,)"),
    (["+task.skills.hold.state=[cart_acceleration]"], "unknown state key 'cart_acceleration'"),
    (["task.skills.tracker.every=0"], "skill 'tracker': every must be >= 1"),
    (["+task.skills.hold.time_budget_ms=-1"], "time_budget_ms must be > 0"),
    (["+task.skills.hold.colour=red"], "skill 'hold': expected keys skill (required)"),
    (["resume=true", "<other-skills>"], "was trained with skills ['swingup', 'balance', 'tracker']"),
    (["resume=true", "<corrupt>"], "last.pt"),
]


@pytest.mark.parametrize("args,expected", BAD_INPUTS, ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_is_one_clear_line_before_training(tmp_path, capsys, args, expected):
    assert len(BAD_INPUTS) >= 20
    run_dir = tmp_path / "run"
    if "<other-skills>" in args:
        _other_skills_checkpoint(run_dir)
    if "<corrupt>" in args:
        (run_dir / "checkpoints").mkdir(parents=True)
        (run_dir / "checkpoints" / "last.pt").write_bytes(b"\x80\x04not a checkpoint at all")
    overrides = [a for a in args if not a.startswith("<")]
    with pytest.raises(SystemExit) as exit_info:
        start_run(compose(overrides), run_dir)
    assert exit_info.value.code == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert expected in lines[0]


def test_a_good_config_starts(tmp_path):
    trainer = start_run(compose(["steps=1000"]), tmp_path)
    assert trainer.cfg.steps == 1000 and trainer.skill_names == tuple(SKILLS)


def test_a_malicious_checkpoint_is_refused_without_running_its_code(tmp_path):
    import pickle

    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path = tmp_path / "last.pt"
    path.write_bytes(pickle.dumps({"format": "hrtc-checkpoint-v1", "policy": Evil()}))
    with pytest.raises(HRTCError):
        load_checkpoint(path)
    assert not marker.exists()
