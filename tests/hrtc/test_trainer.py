"""The trainer on the real cartpole: resuming continues the files, one seed gives one result, configs validate."""

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from hrtc.checkpoint import load_checkpoint
from hrtc.config import ROOT_CONF, RunConfig
from hrtc.errors import CheckpointError, ConfigError, UnknownNameError
from hrtc.ppo import PPOConfig
from hrtc.trainer import Trainer

SKILLS = OmegaConf.to_container(OmegaConf.load(ROOT_CONF / "task" / "cartpole_swingup.yaml"))["task"]["skills"]


def _cfg(steps: int, **kwargs) -> RunConfig:
    base = dict(task="cartpole_swingup", skills=SKILLS, seed=3, steps=steps, num_envs=2, vector="sync",
                eval_every=500, eval_episodes=1, progress=False, decision_every=5,
                ppo=PPOConfig(num_steps=50, learning_rate=1e-3))  # fmt: skip
    return RunConfig(**{**base, **kwargs})


def _eval_rows(run_dir):
    return pd.read_csv(run_dir / "eval.csv").drop(columns=["wall_seconds"])


def test_resume_continues_the_csvs_and_the_step_count(tmp_path):
    Trainer(_cfg(1000), tmp_path).train()
    Trainer(_cfg(2000), tmp_path, resume=True).train()
    assert list(pd.read_csv(tmp_path / "train.csv")["step"]) == [500, 1000, 1500, 2000]
    assert list(_eval_rows(tmp_path)["step"]) == [0, 500, 1000, 1500, 2000]
    assert load_checkpoint(tmp_path / "checkpoints" / "last.pt")["global_step"] == 2000


class _InterruptAsSystemError:
    """What a C extension does when Ctrl-C lands in it: returns with the interrupt pending, which Python raises as a
    SystemError caused by the KeyboardInterrupt."""

    def on_start(self, run):
        pass

    def on_step(self, run, step):
        if run.global_step >= 750:
            try:
                raise KeyboardInterrupt("signal 15")
            except KeyboardInterrupt as interrupt:
                raise SystemError("<built-in method step> returned a result with an exception set") from interrupt

    def on_update(self, run, stats):
        pass

    def on_end(self, run, interrupted):
        pass


def test_an_interrupt_wrapped_in_a_system_error_still_saves_and_stops_the_run(tmp_path):
    trainer = Trainer(_cfg(5000, checkpoint_every=100_000), tmp_path)
    trainer.callbacks.append(_InterruptAsSystemError())
    with pytest.raises(KeyboardInterrupt, match="signal 15"):
        trainer.train()
    # saved as on Ctrl-C: at the last finished update (500 env steps each), before the interrupted one
    assert load_checkpoint(tmp_path / "checkpoints" / "last.pt")["global_step"] == 500


def _draws() -> tuple:
    import random

    import numpy as np
    import torch

    return (random.random(), random.gauss(0, 1), np.random.random(3).tolist(), np.random.normal(size=3).tolist(),  # noqa: NPY002
            torch.rand(3).tolist())  # fmt: skip


def test_restoring_a_checkpoint_restores_every_generator_it_saved(tmp_path):
    """Python's, numpy's (its whole state: key, position and the cached Gaussian) and torch's generators draw the
    same numbers after a save and after a restore of that save."""
    import numpy as np

    trainer = Trainer(_cfg(500), tmp_path)
    np.random.normal()  # noqa: NPY002  (leaves a cached Gaussian and a mid-key position: both must be restored)
    trainer.save()
    after_save = _draws()
    _draws()  # move every generator on
    Trainer(_cfg(500), tmp_path, resume=True)
    assert _draws() == after_save


# sync is slow (about 12 s): the async vector env is the default one
@pytest.mark.parametrize("vector", [pytest.param("sync", marks=pytest.mark.slow), "async"])
def test_same_seed_same_evaluations(tmp_path, vector):
    Trainer(_cfg(1500, vector=vector), tmp_path / "a").train()
    Trainer(_cfg(1500, vector=vector), tmp_path / "b").train()
    pd.testing.assert_frame_equal(_eval_rows(tmp_path / "a"), _eval_rows(tmp_path / "b"))


def test_resume_refuses_a_checkpoint_of_another_skill_set(tmp_path):
    Trainer(_cfg(500), tmp_path).train()
    fewer = {k: v for k, v in SKILLS.items() if k != "hold"}
    with pytest.raises(CheckpointError, match="trained with skills"):
        Trainer(_cfg(1000, skills=fewer), tmp_path, resume=True)


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"algo": "sac"}, UnknownNameError, "valid algos: hrtc, ppo"),
        ({"dist": "gamma"}, UnknownNameError, "valid dists: beta, normal"),
        ({"eval_every": 0}, ConfigError, "eval_every must be a positive integer"),
        ({"num_envs": 2.5}, ConfigError, "num_envs"),
        ({"decision_every": 0}, ConfigError, "decision_every"),
        ({"ppo": PPOConfig(learning_rate=0.0)}, ConfigError, "learning_rate"),
        ({"ppo": PPOConfig(num_steps=2, num_minibatches=8)}, ConfigError, "exceeds the rollout size"),
        ({"skills": {}}, ConfigError, "needs skills"),
    ],
)
def test_run_config_validation(kwargs, error, match):
    with pytest.raises(error, match=match):
        _cfg(1000, **kwargs)


def test_true_rewards_come_from_info_and_an_ended_episodes_final_info():
    """The shaped task's own reward per env: info["true_reward"] for running episodes, final_info's for ended ones
    (gymnasium's same-step autoreset), the reward itself where the task reports none."""
    from hrtc.callbacks import true_rewards

    reward, done = np.array([5.0, 100.0, 7.0]), np.array([False, True, False])
    info = {
        "true_reward": np.array([4.0, 0.0, 0.0]),
        "_true_reward": np.array([True, False, False]),
        "final_info": {"true_reward": np.array([0.0, -0.5, 0.0]), "_true_reward": np.array([False, True, False])},
    }
    np.testing.assert_array_equal(true_rewards(info, reward, done), [4.0, -0.5, 7.0])
    np.testing.assert_array_equal(true_rewards({}, reward, done), reward)
