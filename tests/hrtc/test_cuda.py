"""The GPU path (``device=cuda``): the same PPO update as on the CPU, and a real training run on the GPU whose
checkpoint acts the same on the CPU. Skipped where torch sees no GPU (CI); run on a GPU machine with
``pytest tests/hrtc/test_cuda.py``."""

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from hrtc.learner import Step

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no GPU")
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def exact_float32():
    """TF32 off for the comparison (cuDNN's convolutions may use it by default), restored afterwards."""
    saved = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved


def test_a_pixel_ppo_update_on_the_gpu_matches_the_cpu(exact_float32):
    from tests.hrtc.test_ppo import _pixel_learner

    gpu, cpu = _pixel_learner(), _pixel_learner()
    gpu.policy.to("cuda")
    assert gpu.device.type == "cuda" and cpu.device.type == "cpu"
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (5, 2, 2 * 96 * 96)).astype(np.uint8)
    for t in range(4):
        u, _ = gpu.act(frames[t])
        assert isinstance(u, np.ndarray) and np.all((u > 0) & (u < 1))  # Beta samples, back on the CPU
        gpu.observe(Step(frames[t], u, np.array([1.0, -0.5]), frames[t + 1], np.array([t == 1, False]),
                         np.zeros(2, bool)))  # fmt: skip
    # The CPU learner updates on the very rollout the GPU one collected (its samples, log-probabilities and values).
    cpu.rollout, cpu._next_obs = copy.deepcopy(gpu.rollout), gpu._next_obs
    stats_gpu, stats_cpu = gpu.update(), cpu.update()
    assert stats_gpu is not None and stats_cpu is not None
    for key, value in stats_cpu.items():
        assert stats_gpu[key] == pytest.approx(value, rel=1e-3, abs=1e-5, nan_ok=True), key
    for a, b in zip(gpu.policy.parameters(), cpu.policy.parameters(), strict=True):
        assert a.device.type == "cuda"
        torch.testing.assert_close(a.cpu(), b, rtol=1e-4, atol=1e-5)


def test_a_run_trained_on_the_gpu_acts_the_same_on_the_cpu(tmp_path, exact_float32):
    """``scripts/train.py device=cuda`` on the CarRacing task (conv encoder, HRTC over its five intents): the run
    finishes, and its checkpoint, loaded on the CPU, gives the GPU's Beta parameters on real frames
    (up to float rounding)."""
    from hrtc.checkpoint import load_policy
    from hrtc.environments import make_env

    run = tmp_path / "run"
    args = ["task=carracing_paper", "algo=hrtc", "device=cuda", "seed=3", "steps=192", "ppo.num_steps=48",
            "ppo.num_minibatches=2", "ppo.update_epochs=2", "eval_every=100000", "eval_episodes=1",
            "progress=false", "logger.mode=off", f"hydra.run.dir={run}"]  # fmt: skip
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "train.py"), *args], cwd=ROOT,
                            capture_output=True, text=True, timeout=600)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    train_rows = (run / "train.csv").read_text().splitlines()
    assert len(train_rows) >= 2  # the updates ran on the GPU (192 decisions of 2 envs: 2 updates of 48 x 2)
    loaded = load_policy(run / "checkpoints" / "last.pt")
    assert next(loaded.policy.parameters()).device.type == "cpu"
    env = make_env("carracing_paper", "hrtc", loaded.meta["skills_cfg"])
    obs, _ = env.reset(seed=11)
    frames = [obs]
    for _ in range(20):
        obs, *_ = env.step(np.full(env.action_space.shape, 0.5, np.float32))
        frames.append(obs)
    batch = torch.as_tensor(np.stack(frames))
    with torch.no_grad():
        on_cpu = loaded.policy.distribution(batch)
        on_gpu = copy.deepcopy(loaded.policy).to("cuda").distribution(batch.to("cuda"))
    for name in ("alpha", "beta"):
        torch.testing.assert_close(getattr(on_gpu, name).cpu(), getattr(on_cpu, name), rtol=1e-4, atol=1e-5)
