"""RestartingVectorEnv: real worker processes of a real task, SIGKILLed between steps and in the middle of one."""

import os
import signal
import time

import gymnasium as gym
import numpy as np
import pytest

import envs
from hrtc.errors import WorkerError
from hrtc.vector import RestartingVectorEnv


class _Clock(gym.Wrapper):
    """The task with its step count since reset in ``info["t"]``; its 4th step takes ``delay`` seconds (a step to be
    killed in the middle of)."""

    def __init__(self, env: gym.Env, delay: float = 0.0) -> None:
        super().__init__(env)
        self.delay, self.t = delay, 0

    def reset(self, **kwargs):
        self.t = 0
        return self.env.reset(**kwargs)

    def step(self, action):
        self.t += 1
        time.sleep(self.delay if self.t == 4 else 0.0)
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "t": self.t}


def _task(delay: float = 0.0) -> gym.Env:
    return _Clock(envs.make("cartpole_swingup", time_limit=10.0), delay)


def _vec(max_restarts: int = 5, delay: float = 0.0) -> RestartingVectorEnv:
    return RestartingVectorEnv([lambda: _task(delay)] * 2, max_restarts, context="fork")


def _kill(vec: RestartingVectorEnv, index: int) -> int:
    pid = vec.processes[index].pid
    os.kill(pid, signal.SIGKILL)
    return pid


def _assert_replaced(vec, old_pid: int, out, index: int = 0) -> None:
    obs, reward, terminated, truncated, info = out
    other = 1 - index
    assert truncated[index] and not terminated[index] and reward[index] == 0.0
    assert info["_worker_restarted"][index] and not info["_worker_restarted"][other]
    assert vec.single_observation_space.contains(obs[index].astype(np.float32))
    assert info["final_obs"][index] is not None and info["final_obs"][index].shape == obs[index].shape
    assert not truncated[other] and info["t"][other] == 4  # the other env's episode goes on: its 4th step
    assert vec.processes[index].pid != old_pid and vec.processes[index].is_alive()
    assert vec.restarts == 1


def test_a_worker_killed_between_steps_is_replaced_and_its_episode_truncated(caplog):
    vec = _vec()
    try:
        vec.reset(seed=[3, 4])
        for _ in range(3):
            vec.step(np.zeros((2, 1), np.float32))
        old_pid = _kill(vec, 0)
        time.sleep(0.2)  # dead before the next step is sent
        with caplog.at_level("WARNING", logger="hrtc.vector"):
            out = vec.step(np.zeros((2, 1), np.float32))
        _assert_replaced(vec, old_pid, out)
        lines = [r.getMessage() for r in caplog.records]
        assert len(lines) == 1 and f"worker 0 (pid {old_pid}) was killed by SIGKILL; replaced it" in lines[0]
        for t in range(1, 4):  # later steps are ordinary steps of both envs
            _, _, terminated, truncated, info = vec.step(np.zeros((2, 1), np.float32))
            assert not (terminated | truncated).any() and "worker_restarted" not in info
            assert list(info["t"]) == [t, 4 + t]
    finally:
        vec.close()


def test_a_worker_killed_in_the_middle_of_a_step_is_replaced():
    vec = _vec(delay=1.0)
    try:
        vec.reset(seed=[3, 4])
        for _ in range(3):
            vec.step(np.zeros((2, 1), np.float32))
        vec.step_async(np.zeros((2, 1), np.float32))
        time.sleep(0.3)  # both workers are inside their 1 s step
        old_pid = _kill(vec, 0)
        tic = time.perf_counter()
        _assert_replaced(vec, old_pid, vec.step_wait())
        assert time.perf_counter() - tic < 2.0  # the wait ends with the other env's step, not later
    finally:
        vec.close()


def test_a_worker_dead_at_reset_is_replaced_and_reset_with_its_seed():
    vec = _vec()
    try:
        reference, _ = vec.reset(seed=[3, 4])
        old_pid = _kill(vec, 1)
        time.sleep(0.2)
        obs, info = vec.reset(seed=[3, 4])
        assert info["_worker_restarted"][1] and not info["_worker_restarted"][0]
        np.testing.assert_array_equal(obs, reference)  # the fresh env is reset with the seed asked for
        assert vec.processes[1].pid != old_pid and vec.restarts == 1
    finally:
        vec.close()


def test_past_max_restarts_a_death_raises_and_the_env_still_closes():
    vec = _vec(max_restarts=1)
    try:
        vec.reset(seed=1)
        _kill(vec, 0)
        vec.step(np.zeros((2, 1), np.float32))
        pid = _kill(vec, 1)
        with pytest.raises(WorkerError, match=rf"worker 1 \(pid {pid}\) was killed by SIGKILL, after 1 worker "
                                              r"restarts already \(max_worker_restarts 1\)"):  # fmt: skip
            vec.step(np.zeros((2, 1), np.float32))
    finally:
        vec.close()
    assert not any(p.is_alive() for p in vec.processes)


def test_a_worker_that_died_after_its_last_step_does_not_break_close():
    vec = _vec()
    vec.reset(seed=1)
    _kill(vec, 0)
    time.sleep(0.2)
    vec.close()
    assert not any(p.is_alive() for p in vec.processes)


def _segfaulting() -> gym.Env:
    class Segfaults(gym.Wrapper):
        def step(self, action):
            import ctypes
            import faulthandler

            faulthandler.disable()  # no dump of the crash into the test output
            ctypes.string_at(0)  # reads address 0: SIGSEGV, as a solver's bug would

    return Segfaults(_task())


def test_a_worker_that_segfaults_is_replaced(caplog):
    vec = RestartingVectorEnv([_task, _segfaulting], max_restarts=1, context="fork")
    try:
        vec.reset(seed=1)
        with caplog.at_level("WARNING", logger="hrtc.vector"):
            _, _, _, truncated, info = vec.step(np.zeros((2, 1), np.float32))
        assert list(truncated) == [False, True] and list(info["_worker_restarted"]) == [False, True]
        assert "worker 1" in caplog.text and "was killed by SIGSEGV" in caplog.text
        with pytest.raises(WorkerError, match="SIGSEGV"):  # its replacement segfaults too: past max_restarts 1
            vec.step(np.zeros((2, 1), np.float32))
    finally:
        vec.close()


def _raising() -> gym.Env:
    class Raises(gym.Wrapper):
        def step(self, action):
            raise RuntimeError("the env's own bug")

    return Raises(_task())


@pytest.mark.filterwarnings("ignore:.*ERROR:")  # gymnasium's report of the worker's exception
def test_an_env_that_raises_is_an_error_not_a_restart():
    vec = RestartingVectorEnv([_task, _raising], context="fork")
    try:
        vec.reset(seed=1)
        with pytest.raises(RuntimeError, match="the env's own bug"):
            vec.step(np.zeros((2, 1), np.float32))
        assert vec.restarts == 0
    finally:
        vec.close()
