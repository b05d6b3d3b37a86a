"""Command-line plumbing shared by the scripts: Hydra composition with one-line errors.

Hydra reports a bad override over several lines with a stack-trace hint; a user who typed ``task=cartpol`` wants one
line naming the valid tasks. :func:`check_overrides` composes the config once before ``@hydra.main`` runs and turns
every composition error into ``error: ...`` on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
from collections.abc import Callable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

from hrtc.errors import ConfigError

CONFIG_MODULE = "hrtc.conf"
GROUPS = ("task", "algo", "dist")


def group_choices(group: str) -> list[str]:
    """The option names of a config group shipped in ``hrtc/conf/<group>/``."""
    folder = resources.files(CONFIG_MODULE) / group
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def fail(message: str, status: int = 2) -> NoReturn:
    """Exit with ``error: message`` on stderr, one line, and ``status``."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(status)


def check_overrides(args: Sequence[str], config_name: str = "config") -> None:
    """Exit with one clear line if the command-line overrides cannot make a valid config."""
    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    user = _overrides_only(args)
    try:
        parsed = OverridesParser.create().parse_overrides(user)
    except HydraException as error:
        fail(f"malformed override: {_first_line(error)} (overrides look like key=value, e.g. task=cartpole_swingup)")
    for override in parsed:
        key = override.key_or_group
        if key in GROUPS and not override.is_delete():
            value = override.value()
            if not isinstance(value, str) or value not in group_choices(key):
                fail(f"unknown {key} {value!r}; valid {key}s: {', '.join(group_choices(key))}")
    config_overrides = [a for a, o in zip(user, parsed, strict=True) if not o.key_or_group.startswith("hydra")]
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(CONFIG_MODULE, version_base=None):
            compose(config_name, overrides=config_overrides)
    except (HydraException, OmegaConfBaseException) as error:
        fail(f"{_first_line(error)}")
    finally:
        GlobalHydra.instance().clear()


# Hydra's own flags that take a value (``--cfg job``, ``-cn config``...): their values are not overrides.
_VALUE_FLAGS = {"--cfg", "-c", "--package", "-p", "--config-path", "-cp", "--config-name", "-cn", "--config-dir",
                "-cd", "--experimental-rerun", "--info", "-i"}  # fmt: skip


def _overrides_only(args: Sequence[str]) -> list[str]:
    out, skip = [], False
    for arg in args:
        if skip:
            skip = False
            if "=" not in arg:
                continue
        if arg.startswith("-"):
            skip = arg in _VALUE_FLAGS
            continue
        out.append(arg)
    return out


def _first_line(error: BaseException) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    message = "; ".join(lines[:3]) if lines else type(error).__name__
    return message.replace("Could not override", "cannot set").replace("Key ", "key ")


def task_config(name: str) -> dict:
    """The ``task`` block (``name``, ``skills``, ``env_kwargs``, ``solve_threshold``...) of ``conf/task/<name>.yaml``,
    resolved to plain containers. Raises :class:`~hrtc.errors.UnknownNameError` listing the shipped tasks."""
    from omegaconf import OmegaConf

    from hrtc.errors import UnknownNameError

    if name not in group_choices("task"):
        raise UnknownNameError("task", name, tuple(group_choices("task")))
    text = (resources.files(CONFIG_MODULE) / "task" / f"{name}.yaml").read_text()
    cfg = OmegaConf.to_container(OmegaConf.create(text), resolve=True)
    return dict(cfg["task"])  # type: ignore[index]


def parse_options(args: Sequence[str], defaults: dict, usage: str, checks: Mapping[str, Check] | None = None) -> dict:
    """``key=value`` command-line options over ``defaults``, each parsed as its default's type (str, bool, int; YAML
    when the default is None or a dict: ``weights=[0.5,0.5]``, ``env_kwargs={a: 1}``; a dict default also takes
    ``key.sub=value`` entries); unknown keys and malformed values exit with one clear line. Then each option named in
    ``checks`` goes through its check (:func:`validate`)."""
    import yaml

    options = {k: dict(v) if isinstance(v, dict) else v for k, v in defaults.items()}
    for arg in args:
        if arg in ("-h", "--help"):
            print(usage)
            raise SystemExit(0)
        key, sep, text = arg.partition("=")
        if not sep or not key:
            fail(f"malformed argument {arg!r}: options look like key=value; valid keys: {', '.join(defaults)}")
        head, dot, sub = key.partition(".")
        if key not in defaults and not (dot and sub and isinstance(defaults.get(head), dict)):
            fail(f"unknown option {key!r}; valid keys: {', '.join(defaults)}")
        default = defaults.get(key)
        try:
            if dot and key not in defaults:
                options[head][sub] = yaml.safe_load(text) if text else None
                continue
            if isinstance(default, str):
                value = text
            elif isinstance(default, bool):
                value = {"true": True, "false": False}[text.lower()]
            elif isinstance(default, int):
                value = int(text)
            else:
                value = yaml.safe_load(text) if text else None
        except (KeyError, ValueError, yaml.YAMLError):
            kind = "true or false" if isinstance(default, bool) else type(default).__name__
            shown = "" if default is None or isinstance(default, dict) or dot else f" (expected {kind})"
            fail(f"cannot parse {key}={text!r}{shown}")
        options[key] = value
    return validate(options, checks or {})


class ArgumentParser(argparse.ArgumentParser):
    """``argparse`` for the scripts with ``--flags``: a usage error is one ``error:`` line (status 2), not argparse's
    usage block and message."""

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        fail(f"{message} (see {self.prog} --help)")
        raise AssertionError  # fail() exits


# ------------------------------------------------------------------------------------------------ validation
# A check takes an option's name and value and returns the value as the script uses it, or raises ConfigError with
# the one line the user sees. Scripts declare one per option beside their defaults; validate() runs them all before
# the script reads a file or writes anything.
Check = Callable[[str, Any], Any]


def validate(options: Mapping[str, Any], checks: Mapping[str, Check]) -> dict:
    """``options`` with each one named in ``checks`` replaced by its checked value; the first problem exits with one
    ``error:`` line (status 2)."""
    from hrtc.errors import HRTCError

    out = dict(options)
    try:
        for key, check in checks.items():
            out[key] = check(key, out.get(key))
    except HRTCError as error:
        fail(str(error))
    return out


def integer(low: int | None = None, high: int | None = None) -> Check:
    """An int (not a bool, not a float) in ``[low, high]``."""

    def check(name: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} must be an integer, got {value!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            bounds = f">= {low}" if high is None else f"<= {high}" if low is None else f"in [{low}, {high}]"
            raise ConfigError(f"{name} must be an integer {bounds}, got {value}")
        return value

    return check


def number(low: float | None = None, high: float | None = None) -> Check:
    """A finite real number in ``[low, high]``, as a float."""

    def check(name: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number, got {value!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise ConfigError(f"{name} must be in [{low}, {high}], got {value}")
        return float(value)

    return check


def boolean(name: str, value: Any) -> bool:
    """true or false (YAML's booleans)."""
    if not isinstance(value, bool):
        raise ConfigError(f"{name} must be true or false, got {value!r}")
    return value


def one_of(*choices: Any) -> Check:
    """One of ``choices``."""

    def check(name: str, value: Any) -> Any:
        from hrtc.errors import UnknownNameError

        if value not in choices:
            raise UnknownNameError(name, str(value), tuple(map(str, choices)))
        return value

    return check


def required(inner: Check, example: str) -> Check:
    """What ``inner`` accepts; None (not given) is refused with an ``example`` of the option."""

    def check(name: str, value: Any) -> Any:
        if value is None or value == "":
            raise ConfigError(f"{name}=<{example}> is required")
        return inner(name, value)

    return check


def optional(inner: Check) -> Check:
    """None (the option left at its default), or what ``inner`` accepts."""
    return lambda name, value: None if value is None else inner(name, value)


def numbers(size: int | None = None, low: float | None = None, high: float | None = None) -> Check:
    """A list of ``size`` finite numbers in ``[low, high]``, as a float64 array (``size`` None: any length >= 1)."""

    def check(name: str, value: Any) -> Any:
        import numpy as np

        items = value if isinstance(value, list) else [value]
        what = f"{size} numbers" if size is not None else "a list of numbers"
        if (size is not None and len(items) != size) or not items:
            raise ConfigError(f"{name} must be {what} like [0.5, 1], got {value!r}")
        for item in items:
            number(low, high)(f"every entry of {name}", item)
        return np.asarray(items, dtype=np.float64)

    return check


def mapping(name: str, value: Any) -> dict:
    """A mapping with string keys (YAML ``{a: 1}``, or ``name.a=1`` entries)."""
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{name} must be a mapping like {{key: value}}, got {value!r}")
    return dict(value)


def registered_task(name: str, value: Any) -> str:
    """A task name ``envs.make`` accepts (:func:`envs.names`)."""
    import envs
    from hrtc.errors import UnknownNameError

    if value not in envs.names():
        raise UnknownNameError("task", str(value), envs.names())
    return str(value)


def input_file(name: str, value: Any) -> Path:
    """An existing regular file this process can read (not a directory, a pipe or a device)."""
    if not isinstance(value, str | Path) or not str(value):
        raise ConfigError(f"{name} must be a path, got {value!r}")
    path = Path(value)
    if not path.exists():
        raise ConfigError(f"{name}: no such file {path}")
    if not path.is_file():
        raise ConfigError(f"{name}: {path} is not a regular file ({_kind(path)})")
    if not os.access(path, os.R_OK):
        raise ConfigError(f"{name}: {path} is not readable (permission denied)")
    return path


def output_path(directory: bool = True, suffixes: Sequence[str] = ()) -> Check:
    """A path this process can create or write: a directory (``directory``) or a file with one of ``suffixes``. It
    may exist as that kind; else its nearest existing ancestor must be a writable directory. Nothing is created."""

    def check(name: str, value: Any) -> Path:
        if not isinstance(value, str | Path) or not str(value):
            raise ConfigError(f"{name} must be a path, got {value!r}")
        path = Path(value)
        if path.exists() and path.is_dir() != directory:
            wanted = "a directory" if directory else "a file"
            raise ConfigError(f"{name}: {path} exists and is {_kind(path)}, not {wanted}")
        if suffixes and path.suffix.lower() not in suffixes:
            raise ConfigError(f"{name}: {path} must end in {' or '.join(suffixes)}")
        ancestor = path if path.exists() else next(p for p in path.absolute().parents if p.exists())
        if not ancestor.is_dir():
            raise ConfigError(f"{name}: cannot create {path}: {ancestor} is {_kind(ancestor)}, not a directory")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise ConfigError(f"{name}: cannot write {path}: {ancestor} is not writable")
        return path

    return check


def _kind(path: Path) -> str:
    import stat

    mode = path.stat().st_mode
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISREG, "a file"), (stat.S_ISFIFO, "a named pipe"),
             (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))  # fmt: skip
    return next((text for test, text in kinds if test(mode)), "not a file")


def build_env(task: str, algo: str, skills: Mapping[str, Any], action_filter: str = "sum",
              env_kwargs: Mapping[str, Any] | None = None, decision_every: int = 1, seed: int = 0,
              weight_margin: float = 0.0) -> Any:  # fmt: skip
    """:func:`hrtc.environments.make_env`, reset once with ``seed`` (the skills' first proposals: a wrong action size is
    found now), with a task's refusal of its ``env_kwargs`` as :class:`ConfigError` (one line) instead of a
    ``TypeError`` from deep in its constructor. The caller closes it."""
    import envs
    from hrtc.environments import make_env
    from hrtc.errors import HRTCError, UnknownNameError

    if task not in envs.names():
        raise UnknownNameError("task", task, envs.names())
    try:
        env = make_env(task, algo, skills, action_filter, env_kwargs, decision_every, weight_margin=weight_margin)
    except HRTCError:
        raise
    except (TypeError, ValueError) as error:
        raise ConfigError(f"task {task!r} cannot be built with env_kwargs {dict(env_kwargs or {})}: "
                          f"{_first_line(error)}") from None  # fmt: skip
    try:
        env.reset(seed=seed)
    except BaseException:
        env.close()
        raise
    return env


def launch(cfg: Any, run_dir: str | Path, sinks: Sequence[Any] = (), resume: bool = False) -> Any:
    """The one way a run starts, whoever composed its config (``scripts/train.py`` through Hydra, the benchmark with
    :func:`compose`): the composed config ``cfg`` validated as a :class:`~hrtc.config.RunConfig`, the run's
    :class:`~hrtc.trainer.Trainer` built in ``run_dir`` (``sinks`` get its rows; ``resume`` continues its last
    checkpoint), and the resolved config written beside it as ``config.yaml``. Raises :class:`~hrtc.errors.HRTCError`.
    """
    from omegaconf import OmegaConf

    from hrtc.config import RunConfig
    from hrtc.trainer import Trainer

    run_cfg = RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))  # type: ignore[arg-type]
    trainer = Trainer(run_cfg, run_dir, sinks=sinks, resume=resume)
    (Path(run_dir) / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    return trainer


def start_run(cfg: Any, run_dir: str | Path) -> Any:
    """:func:`launch` for ``scripts/train.py``: any problem exits with one line.

    The run directory's lock (:mod:`hrtc.runlock`) is taken before anything is written and held until the process
    ends: a second process on the same directory is refused, naming the first. A run directory this process created
    is removed again when the trainer cannot be built.
    """
    from omegaconf import OmegaConf

    from hrtc import runlock
    from hrtc.config import RunConfig
    from hrtc.errors import HRTCError

    run_dir = Path(run_dir)
    try:
        RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))  # type: ignore[arg-type]
        lock = runlock.hold(run_dir)
    except HRTCError as error:
        fail(str(error))
    try:
        return launch(cfg, run_dir, resume=bool(cfg.get("resume", False)))
    except HRTCError as error:
        runlock.release(run_dir)
        if lock.created:  # nothing of a run that never started is left behind
            shutil.rmtree(run_dir, ignore_errors=True)
        fail(str(error))


def prepare_run(args: Sequence[str], config_name: str = "config") -> list[str]:
    """Everything ``scripts/train.py`` can check before Hydra writes into the run directory (``.hydra/``, the log):
    the overrides and the values they make (:func:`check_overrides`, :class:`~hrtc.config.RunConfig`), the run
    directory, the checkpoints that ``resume=true`` and ``init_from`` will load. Then takes the run directory's lock
    (a second process is refused here, before Hydra touches the directory) and returns ``args`` with
    ``hydra.run.dir`` pinned (the default's timestamp resolved once), for ``@hydra.main`` to read."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf, open_dict

    from hrtc import runlock
    from hrtc.checkpoint import load_checkpoint
    from hrtc.config import RunConfig
    from hrtc.errors import HRTCError

    args = list(args)
    if any(a.startswith("-") for a in args):  # --help, --cfg job, --multirun...: Hydra's own modes, no run here
        check_overrides(args, config_name)
        return args
    cfg = compose(args, config_name, hydra=True)  # check_overrides first
    given = {o.key_or_group: o.value() for o in OverridesParser.create().parse_overrides(_overrides_only(args))}
    # A run directory given with an interpolation is Hydra's to resolve: start_run checks and locks it then.
    run_dir = None if "${" in str(given.get("hydra.run.dir", "")) else Path(str(given.get("hydra.run.dir") or
                                                                                cfg.hydra.run.dir))  # fmt: skip
    with open_dict(cfg):
        del cfg["hydra"]
    try:
        if cfg.get("resume") not in (True, False):
            raise ConfigError(f"resume must be true or false, got {cfg.get('resume')!r}")
        run = RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))
        if run_dir is not None:
            output_path()("hydra.run.dir", run_dir)
        # The task, its env_kwargs and skills, built and reset once as the trainer will (here, before any write).
        env = build_env(run.task, run.algo, run.skills, run.action_filter, run.env_kwargs, run.decision_every, run.seed,
                        weight_margin=run.weight_margin)  # fmt: skip
        try:
            last = run_dir / "checkpoints" / "last.pt" if run_dir is not None else None
            if cfg.resume and last is not None and last.exists():
                check_checkpoint_fits(load_checkpoint(last)["meta"], env, last)
            if run.init_from:
                from hrtc.checkpoint import resolve_checkpoint

                path = resolve_checkpoint(run.init_from)
                check_checkpoint_fits(load_checkpoint(path)["meta"], env, path)
        finally:
            env.close()
        if run_dir is not None:
            runlock.hold(run_dir)
    except HRTCError as error:
        fail(str(error))
    return args if "hydra.run.dir" in given else [*args, f"hydra.run.dir={run_dir}"]


def check_checkpoint_fits(meta: Mapping[str, Any], env: Any, path: str | Path) -> None:
    """A checkpoint's skills and sizes (its ``meta``) against the environment ``env`` its policy is to act in."""
    mine = {"skills": list(getattr(env, "skill_names", ())), "obs_dim": int(math.prod(env.observation_space.shape)),
            "out_dim": int(env.action_space.shape[0])}  # fmt: skip
    theirs = {key: list(meta.get(key) or []) if key == "skills" else meta.get(key) for key in mine}
    if theirs != mine:
        raise ConfigError(f"{path} was trained with skills {theirs['skills']} (obs {theirs['obs_dim']}, out "
                          f"{theirs['out_dim']}); this environment has {mine['skills']} (obs {mine['obs_dim']}, out "
                          f"{mine['out_dim']})")  # fmt: skip


def compose(overrides: Sequence[str], config_name: str = "config", hydra: bool = False) -> Any:
    """The config ``scripts/train.py`` would run with for ``overrides`` (after :func:`check_overrides`); with
    ``hydra`` the ``hydra`` node too (its ``run.dir``)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    check_overrides(overrides, config_name)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(CONFIG_MODULE, version_base=None):
            overrides = [o for o in _overrides_only(overrides) if not o.startswith("hydra")]
            return hydra_compose(config_name, overrides=overrides, return_hydra_config=hydra)
    finally:
        GlobalHydra.instance().clear()
