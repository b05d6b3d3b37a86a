"""A vector env whose dead workers are replaced: a worker process that exits abnormally (SIGKILL, a segfault in a
solver, the OOM killer) costs its episode, not the run.

:class:`RestartingVectorEnv` is gymnasium's :class:`~gymnasium.vector.AsyncVectorEnv` (same-step autoreset) that,
when a worker's pipe reaches end-of-file on ``step`` or ``reset``, starts a fresh worker for that index from the same
env function and resets it; the other envs keep their episodes. On ``step`` the replaced index returns the fresh
reset's observation with ``reward=0``, ``terminated=False``, ``truncated=True``, ``info["final_obs"]`` its last
observation before the death (what a learner bootstraps from), and ``info["worker_restarted"]`` True (with its mask
``info["_worker_restarted"]``); ``reset`` reports a replacement the same way. Each replacement is one warning line
and counts in :attr:`~RestartingVectorEnv.restarts`; a death past ``max_restarts`` raises :class:`WorkerError`.

An env that *raises* is not a dead worker: its exception reaches the caller as in gymnasium.
"""

from __future__ import annotations

import logging
import multiprocessing
import signal
from collections.abc import Callable, Sequence
from copy import deepcopy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.error import NoAsyncCallError
from gymnasium.vector.async_vector_env import AsyncState, _async_worker
from gymnasium.vector.utils import CloudpickleWrapper, clear_mpi_env_vars, concatenate, iterate
from gymnasium.vector.vector_env import AutoresetMode

from hrtc.errors import WorkerError

log = logging.getLogger(__name__)

_DEAD = (EOFError, OSError)  # what reading or writing the pipe of a dead worker raises


class RestartingVectorEnv(gym.vector.AsyncVectorEnv):
    """``len(env_fns)`` envs in worker processes, each dead worker replaced by a fresh one for the same index.

    Args:
        env_fns: functions building the envs (picklable with ``context="spawn"``).
        max_restarts: replacements allowed over the env's life; the death after them raises :class:`WorkerError`.
        context: the ``multiprocessing`` start method (``None``: the platform's default).
        daemon: workers end with this process.

    Observations travel through the pipes (``shared_memory=False``): a fresh worker needs the buffer the others
    write, which :class:`~gymnasium.vector.AsyncVectorEnv` does not keep. Only ``step`` and ``reset`` replace dead
    workers; ``call``, ``get_attr`` and ``set_attr`` on one raise ``EOFError`` as in gymnasium.
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], max_restarts: int = 5, *,
                 context: str | None = None, daemon: bool = True) -> None:  # fmt: skip
        if not isinstance(max_restarts, int) or isinstance(max_restarts, bool) or max_restarts < 0:
            raise ValueError(f"max_restarts must be a non-negative integer, got {max_restarts!r}")
        super().__init__(env_fns, shared_memory=False, context=context, daemon=daemon, worker=_worker,
                         autoreset_mode=AutoresetMode.SAME_STEP)  # fmt: skip
        self.max_restarts = max_restarts
        self.restarts = 0  # replacements so far, all indices together
        self._ctx = multiprocessing.get_context(context)
        self._reset_seeds: list[int | None] = [None] * self.num_envs  # of the last reset, for a replaced worker's
        self._lives = [0] * self.num_envs  # replacements of each index
        self.parent_pipes = [_Pipe(pipe) for pipe in self.parent_pipes]

    # ------------------------------------------------------------------ reset
    def reset_async(self, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None) -> None:
        seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else seed
        self._reset_seeds = list(seeds) if seeds is not None else [None] * self.num_envs
        super().reset_async(seed=seed, options=options)

    def reset_wait(self, timeout: float | None = None) -> tuple[Any, dict[str, Any]]:
        self._expect(AsyncState.WAITING_RESET, "reset_wait", timeout)
        results, successes, dead = self._receive()
        fresh = {i: self._replace(i, self._reset_seeds[i]) for i in dead}
        self._raise_if_errors(successes)
        infos: dict[str, Any] = {}
        observations = []
        for i, result in enumerate(results):
            obs, info = fresh[i] if i in dead else result
            if i in dead:
                info = {**info, "worker_restarted": True}
            observations.append(obs)
            infos = self._add_info(infos, info, i)
        return self._finish(observations), infos

    # ------------------------------------------------------------------ step
    def step_wait(self, timeout: float | None = None) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict]:
        self._expect(AsyncState.WAITING_STEP, "step_wait", timeout)
        results, successes, dead = self._receive()
        # The last observation of a dead worker's episode (self.observations still holds the previous step's).
        previous = list(iterate(self.observation_space, self.observations))
        last = {i: deepcopy(previous[i]) for i in dead}
        fresh = {i: self._replace(i, self._fresh_seed(i)) for i in dead}
        self._raise_if_errors(successes)
        observations, rewards, terminations, truncations, infos = [], [], [], [], {}
        for i, result in enumerate(results):
            if i in dead:
                obs, reset_info = fresh[i]
                result = (obs, 0.0, False, True, {"final_obs": last[i], "final_info": {"worker_restarted": True},
                                                  "worker_restarted": True, **reset_info})  # fmt: skip
            observations.append(result[0])
            rewards.append(result[1])
            terminations.append(result[2])
            truncations.append(result[3])
            infos = self._add_info(infos, result[4], i)
        return (self._finish(observations), np.array(rewards, dtype=np.float64), np.array(terminations, dtype=np.bool_),
                np.array(truncations, dtype=np.bool_), infos)  # fmt: skip

    # ------------------------------------------------------------------ close
    def close_extras(self, timeout: float | None = None, terminate: bool = False) -> None:
        """Close as gymnasium does; a worker that died since the last step cannot answer ``close``, so on a dead pipe
        the remaining workers are terminated instead."""
        for i, process in enumerate(self.processes):
            pipe = self.parent_pipes[i]
            if not process.is_alive() and pipe is not None and not pipe.closed:
                pipe.close()
        try:
            super().close_extras(timeout, terminate)
        except _DEAD:
            for process in self.processes:
                if process.is_alive():
                    process.terminate()
            for pipe in self.parent_pipes:
                if pipe is not None:
                    pipe.close()
            for process in self.processes:
                process.join()

    # ------------------------------------------------------------------ internals
    def _expect(self, state: AsyncState, name: str, timeout: float | None) -> None:
        self._assert_is_running()
        if self._state != state:
            raise NoAsyncCallError(f"Calling `{name}` without any prior call to `{state.value}_async`.", state.value)
        if not self._poll_pipe_envs(timeout):
            self._state = AsyncState.DEFAULT
            raise multiprocessing.TimeoutError(f"The call to `{name}` has timed out after {timeout} second(s).")

    def _receive(self) -> tuple[list[Any], list[bool], list[int]]:
        """Every worker's answer: (results, successes, indices of dead workers). A dead worker counts as a success
        for :meth:`_raise_if_errors` (it raised nothing; it is replaced)."""
        results: list[Any] = []
        successes, dead = [], []
        for i, pipe in enumerate(self.parent_pipes):
            try:
                result, success = pipe.recv()
            except _DEAD:
                result, success = None, True
                dead.append(i)
            results.append(result)
            successes.append(success)
        self._state = AsyncState.DEFAULT
        return results, successes, dead

    def _finish(self, observations: list[Any]) -> Any:
        self.observations = concatenate(self.single_observation_space, observations, self.observations)
        return deepcopy(self.observations) if self.copy else self.observations

    def _fresh_seed(self, index: int) -> int | None:
        """The reset seed of a replaced worker's env: derived from its last reset seed and its replacements so far,
        so a run that loses the same worker at the same step continues the same way."""
        seed = self._reset_seeds[index]
        if seed is None:
            return None
        return int(np.random.SeedSequence([seed, self._lives[index]]).generate_state(1)[0])

    def _replace(self, index: int, seed: int | None) -> tuple[Any, dict[str, Any]]:
        """Replace the dead worker ``index`` and reset its env with ``seed``: (observation, info)."""
        while True:  # a fresh worker that dies too (its env function crashes) is replaced again, up to the limit
            self._restart(index)
            pipe = self.parent_pipes[index]
            try:
                pipe.send(("reset", {"seed": seed, "options": None}))
                result, success = pipe.recv()
            except _DEAD:
                continue
            if not success:  # its env raised: as any env error
                self._raise_if_errors([i != index for i in range(self.num_envs)])
            return result

    def _restart(self, index: int) -> None:
        old, pipe = self.processes[index], self.parent_pipes[index]
        if pipe is not None:
            pipe.close()
        old.join(timeout=5.0)
        cause = _exit_cause(old.exitcode)
        if old.is_alive():  # its end of the pipe is closed but it lingers: end it
            old.kill()
            old.join()
        if self.restarts >= self.max_restarts:
            raise WorkerError(f"vector-env worker {index} (pid {old.pid}) {cause}, after {self.restarts} worker "
                              f"restarts already (max_worker_restarts {self.max_restarts})")  # fmt: skip
        parent_pipe, child_pipe = self._ctx.Pipe()
        # gymnasium's worker arguments: no shared observation buffer, no concurrency semaphore.
        args = (index, CloudpickleWrapper(self.env_fns[index]), child_pipe, parent_pipe, None, self.error_queue)
        name = f"Worker<{type(self).__name__}>-{index}"
        with clear_mpi_env_vars():
            process = self._ctx.Process(target=_worker, name=name, args=(*args, self.autoreset_mode, None))
            process.daemon = self.daemon
            process.start()
        child_pipe.close()
        self.processes[index], self.parent_pipes[index] = process, _Pipe(parent_pipe)
        self.restarts += 1
        self._lives[index] += 1
        log.warning("vector-env worker %d (pid %d) %s; replaced it (pid %d), its episode counted as truncated "
                    "(restart %d of at most %d)", index, old.pid, cause, process.pid, self.restarts,
                    self.max_restarts)  # fmt: skip


class _Pipe:
    """A worker's pipe whose ``send`` to a dead worker does nothing (the ``recv`` that follows finds it dead), so
    that gymnasium's ``step_async``, ``reset_async`` and ``close`` send to every worker whatever state each is in."""

    def __init__(self, connection: Any) -> None:
        self.connection = connection

    def send(self, message: Any) -> None:
        try:
            self.connection.send(message)
        except OSError:  # BrokenPipeError, ConnectionResetError: the worker is gone
            pass

    def __getattr__(self, name: str) -> Any:  # recv, poll, close, closed, fileno
        return getattr(self.connection, name)


def _exit_cause(exitcode: int | None) -> str:
    """How a worker ended, in words: ``killed by SIGKILL``, ``exited with status 1``."""
    if exitcode is None:
        return "closed its pipe without exiting"
    if exitcode < 0:
        try:
            return f"was killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"was killed by signal {-exitcode}"
    return f"exited with status {exitcode}"


def _worker(*args: Any) -> None:
    """gymnasium's worker, with SIGTERM at its default: a worker forked after the trainer made SIGTERM save the run
    would otherwise take that handler along."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _async_worker(*args)
