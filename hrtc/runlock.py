"""One writer per run directory: an exclusive ``fcntl.flock`` on ``<run_dir>/.lock``, held for the run's life.

The kernel drops a ``flock`` when its holder's last file descriptor closes, so a process killed by any signal (even
SIGKILL) releases its run directory: the next ``resume=true`` takes the lock over, and learns from the file whose
lock it was (pid, host, start time) because a killed holder never emptied it. A second process that asks while the
holder lives is refused with :class:`~hrtc.errors.RunLockedError` naming the holder. The lock file is never deleted
(deleting it would let two processes lock two different files of the same name); a clean release empties it.

Local file systems only: ``flock`` over NFS is not reliable on every kernel.
"""

from __future__ import annotations

import atexit
import fcntl
import json
import logging
import os
import socket
import time
from pathlib import Path
from typing import NamedTuple

from hrtc.errors import ConfigError, RunLockedError

log = logging.getLogger(__name__)

LOCK_NAME = ".lock"


class Holder(NamedTuple):
    """Who holds (or held) a run directory: process id, host name and start time (UTC, ISO 8601, s)."""

    pid: int
    host: str
    started: str

    def __str__(self) -> str:
        return f"pid {self.pid} on {self.host} since {self.started}"


class RunLock:
    """The lock of ``run_dir`` (see the module doc). :meth:`acquire` creates the directory if it is missing
    (``created`` says so) and takes the lock or raises; :meth:`release` gives it back. ``previous`` is the holder of a
    lock that was taken over (a process that ended without releasing it), else None."""

    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / LOCK_NAME
        self.created = False
        self.previous: Holder | None = None
        self._fd: int | None = None
        self._pid = 0  # the acquiring process: a forked child (a vector-env worker) shares the lock, never releases it

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> RunLock:
        if self._fd is not None:
            return self
        if self.run_dir.exists() and not self.run_dir.is_dir():
            raise ConfigError(f"run directory {self.run_dir} exists and is not a directory")
        try:
            self.created = not self.run_dir.exists()
            self.run_dir.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as error:
            raise ConfigError(f"cannot create the run directory's lock {self.path}: {error.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read(fd)
            os.close(fd)
            who = str(holder) if holder else "another process (it has not written its pid yet)"
            raise RunLockedError(
                f"run directory {self.run_dir} is in use by {who}; one process writes a run "
                f"directory at a time: wait for it to end, or use another directory"
            ) from None
        self.previous = _read(fd)
        if self.previous is not None:
            log.warning("run directory %s: taking over the lock of %s, which ended without releasing it",
                        self.run_dir, self.previous)  # fmt: skip
        me = Holder(os.getpid(), socket.gethostname(), time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me._asdict()) + "\n").encode(), 0)
        os.fsync(fd)
        self._fd, self._pid = fd, me.pid
        return self

    def release(self) -> None:
        """Empty the lock file (a clean end) and unlock it; a no-op when not held."""
        if self._fd is None or os.getpid() != self._pid:
            return
        fd, self._fd = self._fd, None
        try:
            os.ftruncate(fd, 0)
        finally:
            os.close(fd)  # closing the last descriptor drops the flock

    def holder(self) -> Holder | None:
        """Who the lock file names now (None when empty or unreadable)."""
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            return None
        try:
            return _read(fd)
        finally:
            os.close(fd)

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


_HELD: dict[Path, RunLock] = {}


def hold(run_dir: str | Path) -> RunLock:
    """This process's lock of ``run_dir``, acquired on the first call and kept until :func:`release` or exit (a
    second ``flock`` on the same file from the same process would refuse it, so callers share one)."""
    key = Path(run_dir).absolute()
    lock = _HELD.get(key)
    if lock is None or not lock.held:
        lock = RunLock(run_dir).acquire()
        if not _HELD:
            atexit.register(_release_all)  # a clean exit empties the files; a killed process leaves its name there
        _HELD[key] = lock
    return lock


def release(run_dir: str | Path) -> None:
    """Give back this process's lock of ``run_dir`` (if it holds one)."""
    lock = _HELD.pop(Path(run_dir).absolute(), None)
    if lock is not None:
        lock.release()


def _release_all() -> None:
    for run_dir in list(_HELD):
        release(run_dir)


def _read(fd: int) -> Holder | None:
    try:
        data = json.loads(os.pread(fd, 4096, 0).decode() or "null")
        return Holder(int(data["pid"]), str(data["host"]), str(data["started"])) if data else None
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return None
