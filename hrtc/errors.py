"""Exceptions raised by hrtc. Every error a user can cause has its own type and a one-line message."""

from __future__ import annotations


class HRTCError(Exception):
    """Base class for every error hrtc raises on purpose."""


class ConfigError(HRTCError, ValueError):
    """A configuration value is missing, malformed or out of range."""


class UnknownNameError(HRTCError, KeyError):
    """A task, skill, algorithm or state key that is not registered.

    The message names what was asked for and every valid choice.
    """

    def __init__(self, kind: str, name: str, choices: list[str] | tuple[str, ...]) -> None:
        self.kind, self.name, self.choices = kind, name, tuple(choices)
        super().__init__(f"unknown {kind} {name!r}; valid {kind}s: {', '.join(sorted(self.choices))}")

    def __str__(self) -> str:  # KeyError would quote the message
        return self.args[0]


class ShapeError(HRTCError, ValueError):
    """An array does not have the shape a component declared."""


class CheckpointError(HRTCError):
    """A checkpoint file is missing, truncated, not a checkpoint, or unsafe to load."""


class SkillError(HRTCError):
    """A skill failed in a way that cannot be recovered (its construction, or repeated faults)."""


class RunLockedError(HRTCError):
    """A run directory is being written by another live process (see :mod:`hrtc.runlock`)."""


class WorkerError(HRTCError):
    """Vector-env workers died more often than allowed (see :class:`hrtc.vector.RestartingVectorEnv`)."""


def interrupt_within(error: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or SIGTERM, which a run turns into one) that a library wrapped in another exception, else None.

    A signal handler raises where the main thread is, which in a skill is mostly inside a solver: CasADi then raises a
    ``RuntimeError`` whose message ends in the ``KeyboardInterrupt`` (the original is not chained), and a C extension
    that returns with the interrupt pending raises a ``SystemError`` caused by it. A skill's fallback for a failing
    solver must not take these for solver failures, or the run would not stop. (A few CasADi swallows whole, returning
    as if none came: the run's signal callback, ``hrtc.callbacks.TerminateAsInterrupt``, raises those again at the end
    of the step.)"""
    seen: BaseException | None = error
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return seen
        seen = seen.__cause__ or seen.__context__
    return KeyboardInterrupt(str(error)) if "KeyboardInterrupt" in str(error) else None
